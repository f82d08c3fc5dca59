// Kernel estimation (Yuan et al. 2007 style, sparse, coarse-to-fine, FFT normal equations).
#include <cstdio>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel_estimation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

cv::Mat mosaic() {
  cv::Mat top, bottom, out;
  cv::hconcat(test::levinImage(1), test::levinImage(2), top);
  cv::hconcat(test::levinImage(3), test::levinImage(4), bottom);
  cv::vconcat(top, bottom, out);
  return out;
}

TEST(KernelEstimation, RecoversLevinKernelsWithGainAndNoise) {
  const cv::Mat sharp_clean = mosaic();
  for (int index : {1, 3, 8}) {
    const cv::Mat truth = test::levinKernel(index);
    cv::Mat blurred = 0.8 * convolve(sharp_clean, truth);
    blurred = quantize(blurred, 8);
    const cv::Mat sharp = quantize(addGaussianNoise(sharp_clean, 0.0001, index), 8);
    KernelEstimationOptions options;
    options.kernel_size = 31;
    const KernelEstimate k = estimateKernel(sharp, blurred, options);
    std::printf("levin %d: err %.3f shape %.3f %s\n", index, kernelRelativeError(k.kernel, truth), kernelShapeError(k.kernel, truth), k.summary().c_str());
    EXPECT_NEAR(k.gain, 0.8, 0.15) << index;
    const double err = kernelRelativeError(k.kernel, truth);
    EXPECT_LT(err, 0.45) << "levin " << index << ": " << k.summary();
    EXPECT_FALSE(k.hit_size_limit);
    EXPECT_NEAR(cv::sum(k.kernel)[0], 1.0, 1e-9);
  }
}

TEST(KernelEstimation, AbsorbsResidualShift) {
  const cv::Mat sharp = mosaic();
  const cv::Mat truth = test::levinKernel(1);
  cv::Mat shifted;
  const cv::Mat A = (cv::Mat_<double>(2, 3) << 1, 0, 3, 0, 1, -2);
  cv::warpAffine(convolve(sharp, truth), shifted, A, sharp.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  KernelEstimationOptions options;
  options.kernel_size = 31;
  const KernelEstimate k = estimateKernel(sharp, shifted, options);
  cv::Point2d truth_centroid;
  for (int y = 0; y < truth.rows; ++y)
    for (int x = 0; x < truth.cols; ++x) {
      truth_centroid.x += truth.at<double>(y, x) * (x - truth.cols / 2);
      truth_centroid.y += truth.at<double>(y, x) * (y - truth.rows / 2);
    }
  EXPECT_NEAR(k.centroid.x - truth_centroid.x, 3.0, 0.5) << k.summary();
  EXPECT_NEAR(k.centroid.y - truth_centroid.y, -2.0, 0.5) << k.summary();
  EXPECT_LT(kernelShapeError(k.kernel, truth), 0.45);
}

TEST(KernelEstimation, SizeLimitIsReportedWithAHint) {
  const cv::Mat sharp = mosaic();
  const cv::Mat blurred = convolve(sharp, test::levinKernel(4));  // 27x27 kernel
  KernelEstimationOptions options;
  options.kernel_size = 11;
  try {
    estimateKernel(sharp, blurred, options);
    FAIL() << "expected InvalidInput";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("--kernel-size"), std::string::npos) << e.what();
  }
}

TEST(KernelEstimation, FlatImagesHaveNoEdges) {
  const cv::Mat flat(200, 200, CV_64F, cv::Scalar(0.5));
  EXPECT_THROW(estimateKernel(flat, flat), InvalidInput);
}

}  // namespace
}  // namespace crfcal
