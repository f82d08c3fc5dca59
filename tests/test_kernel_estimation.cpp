// Kernel estimation (Yuan et al. 2007 style, sparse, coarse-to-fine, FFT normal equations).
#include <cmath>
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

// A validity mask full of holes (saturated highlights, registration borders) must not change the answer: the
// normal equations are built only from equations whose whole window is valid. (The former FFT shortcut
// approximated the masked Gram matrix by an auto-correlation, which over-counts pixels near every hole: the
// kernel shrank — gain ≈ 0.3 — and smeared into a streak that hit the size limit.)
TEST(KernelEstimation, HolesInTheMaskDoNotShrinkOrSmearTheKernel) {
  const cv::Mat sharp = mosaic();
  const cv::Mat truth = test::levinKernel(3);
  const cv::Mat blurred = quantize(0.9 * convolve(sharp, truth), 8);
  cv::Mat valid(sharp.size(), CV_8U, cv::Scalar(255));
  cv::RNG rng(7);
  for (int i = 0; i < 60; ++i)
    cv::circle(valid, cv::Point(rng.uniform(0, sharp.cols), rng.uniform(0, sharp.rows)), rng.uniform(3, 25), cv::Scalar(0), -1);
  KernelEstimationOptions options;
  options.kernel_size = 35;
  const KernelEstimate k = estimateKernel(quantize(sharp, 8), blurred, {}, valid, options);
  EXPECT_FALSE(k.hit_size_limit) << k.summary();
  EXPECT_NEAR(k.gain, 0.9, 0.1) << k.summary();  // the priors shrink it a little (was ≈ 0.3)
  EXPECT_LT(kernelShapeError(k.kernel, truth), 0.45) << k.summary();
  EXPECT_LT(std::hypot(k.centroid.x, k.centroid.y), 3.0) << k.summary();  // Levin 3's centroid is ≈ (1.1, 0.6)
}

// A coarse level sees a pixel only where its whole block is usable and a kernel window only where all its blocks are:
// a mask whose holes are spaced just wide enough for the full-resolution window (here one unusable pixel every 18 px
// for a 15 px kernel, as interleaved clipped highlights of B and black of a dark sharp shot leave it) empties the
// half-resolution level. The estimate then starts at the full resolution instead of failing with "no edges".
TEST(KernelEstimation, CoarseLevelWithoutEquationsStartsAtTheNextFinerLevel) {
  const cv::Mat sharp = mosaic();
  const cv::Mat truth = test::levinKernel(5);  // 13×13
  const cv::Mat blurred = quantize(0.9 * convolve(sharp, truth), 8);
  cv::Mat valid(sharp.size(), CV_8U, cv::Scalar(255));
  for (int y = 0; y < valid.rows; y += 18)
    for (int x = 0; x < valid.cols; x += 18) valid.at<uchar>(y, x) = 0;
  KernelEstimationOptions options;
  options.kernel_size = 15;
  const KernelEstimate k = estimateKernel(quantize(sharp, 8), blurred, {}, valid, options);
  ASSERT_EQ(k.levels.size(), 1u) << "the half-resolution level has no equations in this mask";
  EXPECT_EQ(k.levels.front().level, 0);
  // Exactly the estimate made with one level from the start.
  KernelEstimationOptions one_level = options;
  one_level.pyramid_levels = 1;
  const KernelEstimate direct = estimateKernel(quantize(sharp, 8), blurred, {}, valid, one_level);
  EXPECT_EQ(cv::norm(k.kernel, direct.kernel, cv::NORM_INF), 0.0);
  EXPECT_FALSE(k.hit_size_limit) << k.summary();
  EXPECT_GT(k.gain, 0.7) << k.summary();  // the sparse prior from a whole-window start shrinks it (0.78)
  EXPECT_LT(kernelShapeError(k.kernel, truth), 0.45) << k.summary();
}

// Weighted equations (the irradiance-domain rounds weight by 1/φ'(B)): a constant weight changes nothing (the priors
// are relative to the data terms), and down-weighting the pixels whose errors are large keeps those errors out of
// the kernel — here a quarter of B carries a strong error correlated with the image (like the amplified JPEG/chroma
// errors of bright edges in the irradiance domain), which unweighted shrinks and smears the kernel.
TEST(KernelEstimation, WeightsScaleOutAndDiscountNoisyEquations) {
  const cv::Mat sharp = mosaic();
  const cv::Mat truth = test::levinKernel(3);
  const cv::Mat clean = convolve(sharp, truth);
  KernelEstimationOptions options;
  options.kernel_size = 31;
  const KernelEstimate plain = estimateKernel(sharp, clean, {}, {}, options);
  const KernelEstimate constant =
      estimateKernel(sharp, clean, {}, {}, options, cv::Mat(sharp.size(), CV_64F, cv::Scalar(7.0)));
  // (single-precision accumulation of the normal equations: agreement to float rounding)
  EXPECT_LT(kernelRelativeError(constant.kernel, plain.kernel), 1e-4);
  EXPECT_NEAR(constant.gain, plain.gain, 1e-4 * plain.gain);

  // The corrupted quadrant: B there is the sharp image itself (no blur) scaled up — a large error, not noise.
  cv::Mat corrupted = clean.clone();
  const cv::Rect bad(0, 0, sharp.cols / 2, sharp.rows / 2);
  cv::Mat(3.0 * sharp(bad)).copyTo(corrupted(bad));
  cv::Mat weights(sharp.size(), CV_64F, cv::Scalar(1.0));
  weights(bad).setTo(0.01);
  const KernelEstimate unweighted = estimateKernel(sharp, corrupted, {}, {}, options);
  const KernelEstimate weighted = estimateKernel(sharp, corrupted, {}, {}, options, weights);
  const double e_unweighted = kernelShapeError(unweighted.kernel, truth), e_weighted = kernelShapeError(weighted.kernel, truth);
  std::printf("corrupted quadrant: shape error unweighted %.3f, weighted %.3f\n", e_unweighted, e_weighted);
  EXPECT_LT(e_weighted, 0.45) << weighted.summary();
  EXPECT_LT(e_weighted, 0.6 * e_unweighted) << unweighted.summary() << " vs " << weighted.summary();
  EXPECT_NEAR(weighted.gain, 1.0, 0.15) << weighted.summary();

  EXPECT_THROW(estimateKernel(sharp, clean, {}, {}, options, cv::Mat(3, 3, CV_64F, cv::Scalar(1))), InvalidInput);
}

// Regions of a larger frame are estimated in their own crops: the same pixels give the same kernel.
TEST(KernelEstimation, RegionOfAFrameEqualsTheCroppedImage) {
  const cv::Mat sharp = mosaic();
  const cv::Mat blurred = convolve(sharp, test::levinKernel(1));
  const cv::Rect region(60, 60, 300, 300);
  KernelEstimationOptions options;
  options.kernel_size = 25;
  const KernelEstimate a = estimateKernel(sharp, blurred, {region}, {}, options);
  const cv::Rect crop(region.x - 27, region.y - 27, region.width + 54, region.height + 54);
  const KernelEstimate b = estimateKernel(sharp(crop), blurred(crop), {region - crop.tl()}, {}, options);
  EXPECT_LT(kernelRelativeError(a.kernel, b.kernel), 1e-6);
}

TEST(KernelEstimation, ShapeErrorIgnoresSubPixelShifts) {
  const cv::Mat truth = test::levinKernel(3);
  cv::Mat padded, shifted;
  cv::copyMakeBorder(truth, padded, 6, 6, 6, 6, cv::BORDER_CONSTANT, cv::Scalar(0));
  const cv::Mat A = (cv::Mat_<double>(2, 3) << 1, 0, 2.5, 0, 1, -1.5);
  cv::warpAffine(padded, shifted, A, padded.size(), cv::INTER_LINEAR);
  // What remains is the smoothing of the two half-pixel resamplings (an integer-only search leaves ≈ 0.5).
  EXPECT_GT(kernelRelativeError(shifted, truth), 0.5);
  EXPECT_LT(kernelShapeError(shifted, truth), 0.38);
}

// A 27 px blur in an 11 px window: cut off, its mass piled on the border (more than an even spread would put
// there), so the message sends the user to a larger window.
TEST(KernelEstimation, ABlurCutOffByTheWindowIsReportedAsReachingItsSizeLimit) {
  const cv::Mat sharp = mosaic();
  const cv::Mat blurred = convolve(sharp, test::levinKernel(4));  // 27x27 kernel
  KernelEstimationOptions options;
  options.kernel_size = 11;
  try {
    estimateKernel(sharp, blurred, options);
    FAIL() << "expected InvalidInput";
  } catch (const InvalidInput& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("reaches its size limit (11x11 px"), std::string::npos) << message;
    EXPECT_NE(message.find("try a larger --max-kernel-size"), std::string::npos) << message;
  }
}

TEST(KernelEstimation, FlatImagesHaveNoEdges) {
  const cv::Mat flat(200, 200, CV_64F, cv::Scalar(0.5));
  EXPECT_THROW(estimateKernel(flat, flat), InvalidInput);
}

}  // namespace
}  // namespace crfcal
