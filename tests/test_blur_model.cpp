// Blur kernels and the forward blur models of Sec. 3 (blur_model.hpp, kernel.hpp, simulation.hpp).
#include <algorithm>
#include <cmath>
#include <utility>
#include <limits>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

cv::Mat randomImage(int rows, int cols, std::uint64_t seed) {
  cv::Mat image(rows, cols, CV_64F);
  cv::RNG rng(seed);
  rng.fill(image, cv::RNG::UNIFORM, 0.0, 1.0);
  return image;
}

// Direct reference of crfcal's convolution: (I ⊗ K)(p) = Σ_q K(q) I(p − q + c), borders replicated.
cv::Mat directConvolve(const cv::Mat& image, const cv::Mat& kernel) {
  cv::Mat out(image.size(), CV_64F, cv::Scalar(0));
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  for (int y = 0; y < image.rows; ++y)
    for (int x = 0; x < image.cols; ++x) {
      double sum = 0;
      for (int qy = 0; qy < kernel.rows; ++qy)
        for (int qx = 0; qx < kernel.cols; ++qx) {
          const int sy = std::clamp(y - qy + cy, 0, image.rows - 1), sx = std::clamp(x - qx + cx, 0, image.cols - 1);
          sum += kernel.at<double>(qy, qx) * image.at<double>(sy, sx);
        }
      out.at<double>(y, x) = sum;
    }
  return out;
}

TEST(KernelLoading, LevinKernelsAreNormalised) {
  ASSERT_TRUE(std::filesystem::exists(test::samples() / "levin09" / "kernel01.txt")) << "bundled samples missing";
  for (int k = 1; k <= 8; ++k) {
    const cv::Mat kernel = test::levinKernel(k);
    ASSERT_EQ(kernel.type(), CV_64F) << k;
    EXPECT_TRUE(checkKernel(kernel, 1e-12)) << k << ": " << checkKernel(kernel).reason;
    double lo = 0, hi = 0;
    cv::minMaxLoc(kernel, &lo, &hi);
    EXPECT_GE(lo, 0.0) << k;
    EXPECT_GT(hi, 0.0) << k;
    EXPECT_NEAR(cv::sum(kernel)[0], 1.0, 1e-12) << k;
    EXPECT_GE(kernel.rows, 13) << k;  // the Levin kernels are 13 … 27 px
    EXPECT_LE(kernel.rows, 27) << k;
  }
}

TEST(KernelValidation, NormalizeAndRejectBadKernels) {
  const cv::Mat unnormalised = (cv::Mat_<double>(1, 3) << 1, 2, 1);
  EXPECT_FALSE(checkKernel(unnormalised));
  const cv::Mat normalised = normalizeKernel(unnormalised);
  EXPECT_TRUE(checkKernel(normalised));
  EXPECT_DOUBLE_EQ(normalised.at<double>(0, 1), 0.5);

  EXPECT_THROW(normalizeKernel((cv::Mat_<double>(1, 3) << 1, -0.5, 1)), InvalidInput);  // real negative mass
  EXPECT_THROW(normalizeKernel(cv::Mat::zeros(3, 3, CV_64F)), InvalidInput);             // zero sum
  EXPECT_THROW(normalizeKernel((cv::Mat_<double>(1, 2) << 1, std::numeric_limits<double>::quiet_NaN())), InvalidInput);
  EXPECT_THROW(normalizeKernel((cv::Mat_<double>(1, 2) << 1, std::numeric_limits<double>::infinity())), InvalidInput);
  EXPECT_THROW(normalizeKernel(cv::Mat()), InvalidInput);
  EXPECT_FALSE(checkKernel((cv::Mat_<double>(1, 2) << 1.5, -0.5)));
  EXPECT_FALSE(checkKernel((cv::Mat_<double>(1, 2) << 0.5, std::numeric_limits<double>::quiet_NaN())));
  // tiny negatives (interpolation noise, ≤ 1e-6 of the peak) are clamped, not rejected
  const cv::Mat tiny = normalizeKernel((cv::Mat_<double>(1, 3) << 1, -1e-9, 1));
  EXPECT_EQ(tiny.at<double>(0, 1), 0.0);
  EXPECT_DOUBLE_EQ(tiny.at<double>(0, 0), 0.5);
  // convolve refuses an unnormalised kernel
  EXPECT_THROW(convolve(cv::Mat::ones(4, 4, CV_64F), unnormalised), InvalidInput);
}

TEST(KernelValidation, BoxKernel) {
  const cv::Mat box = boxKernel(20);
  EXPECT_EQ(box.rows, 1);
  EXPECT_EQ(box.cols, 20);
  EXPECT_NEAR(cv::sum(box)[0], 1.0, 1e-15);
  EXPECT_THROW(boxKernel(0), InvalidInput);
}

TEST(KernelValidation, CentroidIsTheShiftTheKernelApplies) {
  cv::Mat k(7, 9, CV_64F, cv::Scalar(0));
  k.at<double>(3, 4) = 0.5;  // the centre
  k.at<double>(5, 8) = 0.5;  // 2 rows down, 4 columns right
  const cv::Point2d c = kernelCentroid(k);
  EXPECT_NEAR(c.x, 2.0, 1e-12);
  EXPECT_NEAR(c.y, 1.0, 1e-12);
  // convolving a delta moves it by the centroid
  cv::Mat delta(31, 31, CV_64F, cv::Scalar(0));
  delta.at<double>(15, 15) = 1.0;
  const cv::Moments m = cv::moments(convolve(delta, k));
  EXPECT_NEAR(m.m10 / m.m00 - 15, c.x, 1e-9);
  EXPECT_NEAR(m.m01 / m.m00 - 15, c.y, 1e-9);
  EXPECT_EQ(kernelCentroid(cv::Mat::zeros(3, 3, CV_64F)), cv::Point2d(0, 0));
}

TEST(KernelValidation, RmsRadiusIsTheSpreadAboutTheCentroid) {
  cv::Mat delta(5, 5, CV_64F, cv::Scalar(0));
  delta.at<double>(1, 3) = 1;  // off-centre: a shift is no blur
  EXPECT_NEAR(kernelRmsRadius(delta), 0, 1e-12);
  EXPECT_NEAR(kernelRmsRadius(boxKernel(3)), std::sqrt(2.0 / 3), 1e-12);  // offsets −1, 0, 1
  EXPECT_NEAR(kernelRmsRadius(2 * boxKernel(2)), 0.5, 1e-12);              // scale-free; offsets ±½
  EXPECT_EQ(kernelRmsRadius(cv::Mat::zeros(3, 3, CV_64F)), 0);
}

TEST(BlurModel, DeltaConvolvedWithAsymmetricKernelReproducesKernelCentred) {
  cv::Mat delta(31, 33, CV_64F, cv::Scalar(0));
  delta.at<double>(15, 16) = 1.0;
  // 3 rows × 5 columns, all entries distinct, heavier towards the bottom right.
  cv::Mat kernel = (cv::Mat_<double>(3, 5) << 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  kernel = normalizeKernel(kernel);
  const cv::Mat out = convolve(delta, kernel);
  // out(centre + q − c) = K(q), c = (cols/2, rows/2) = (2, 1)
  for (int y = 0; y < out.rows; ++y)
    for (int x = 0; x < out.cols; ++x) {
      const int qy = y - 15 + 1, qx = x - 16 + 2;
      const double expected = qy >= 0 && qy < 3 && qx >= 0 && qx < 5 ? kernel.at<double>(qy, qx) : 0.0;
      EXPECT_NEAR(out.at<double>(y, x), expected, 1e-15) << x << "," << y;
    }
  EXPECT_GT(out.at<double>(16, 18), out.at<double>(14, 14));  // the kernel is not flipped
}

TEST(BlurModel, ConvolveMatchesDirectSum) {
  const cv::Mat image = randomImage(40, 37, 7);
  // small kernel (direct filter2D path), large Levin-size kernel (DFT path), even-sized and 1-row kernels
  std::vector<cv::Mat> kernels{normalizeKernel(randomImage(3, 3, 1)), normalizeKernel(randomImage(27, 25, 2)),
                               normalizeKernel(randomImage(4, 6, 3)), boxKernel(10)};
  if (std::filesystem::exists(test::samples() / "levin09" / "kernel04.txt")) kernels.push_back(test::levinKernel(4));
  for (const auto& kernel : kernels) {
    const cv::Mat fast = convolve(image, kernel);
    const cv::Mat reference = directConvolve(image, kernel);
    EXPECT_LT(cv::norm(fast - reference, cv::NORM_INF), 1e-12) << kernel.size();
  }
}

// Imin / Imax over the kernel's support, pixel by pixel, compared to the bit with localRange.
void expectDirectMinMaxOverSupport(const cv::Mat& image, const cv::Mat& kernel) {
  const LocalRange range = localRange(image, kernel);
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  for (int y = 0; y < image.rows; ++y)
    for (int x = 0; x < image.cols; ++x) {
      double lo = 1e300, hi = -1e300;
      for (int qy = 0; qy < kernel.rows; ++qy)
        for (int qx = 0; qx < kernel.cols; ++qx) {
          if (kernel.at<double>(qy, qx) <= 0) continue;
          const double v = image.at<double>(std::clamp(y - qy + cy, 0, image.rows - 1),
                                             std::clamp(x - qx + cx, 0, image.cols - 1));
          lo = std::min(lo, v);
          hi = std::max(hi, v);
        }
      ASSERT_EQ(range.min.at<double>(y, x), lo) << x << "," << y;
      ASSERT_EQ(range.max.at<double>(y, x), hi) << x << "," << y;
    }
}

cv::Mat sparseKernel(int rows, int cols, std::uint64_t seed) {
  cv::Mat kernel = randomImage(rows, cols, seed);
  kernel.setTo(0.0, kernel < 0.5);  // a sparse support, like a motion kernel
  return normalizeKernel(kernel);
}

TEST(BlurModel, LocalRangeMatchesDirectMinMaxOverSupport) {
  expectDirectMinMaxOverSupport(randomImage(30, 28, 11), sparseKernel(5, 7, 12));
}

// Images of 8- and 16-bit codes (as toUnitGray makes them) take localRange's integer path: the same doubles.
TEST(BlurModel, LocalRangeOfEightAndSixteenBitCodesMatchesDirectMinMaxOverSupport) {
  const cv::Mat kernel = sparseKernel(15, 11, 14);
  for (const auto& [depth, top] : {std::pair{CV_8U, 255.0}, std::pair{CV_16U, 65535.0}}) {
    cv::Mat codes(40, 36, depth), unit;
    cv::RNG rng(15);
    rng.fill(codes, cv::RNG::UNIFORM, 0.0, top + 1);
    codes.convertTo(unit, CV_64F, 1.0 / top);
    expectDirectMinMaxOverSupport(unit, kernel);
    // and a value off the code grid: the double path
    unit.at<double>(3, 4) += 1e-9;
    expectDirectMinMaxOverSupport(unit, kernel);
  }
}

TEST(BlurModel, Quantize) {
  const cv::Mat values = (cv::Mat_<double>(1, 6) << -0.2, 0.0, 0.5, 1.0 / 255 * 0.49, 0.999, 1.7);
  const cv::Mat q8 = quantize(values, 8);
  EXPECT_EQ(q8.at<double>(0, 0), 0.0);
  EXPECT_EQ(q8.at<double>(0, 1), 0.0);
  EXPECT_DOUBLE_EQ(q8.at<double>(0, 2), 128.0 / 255);
  EXPECT_EQ(q8.at<double>(0, 3), 0.0);
  EXPECT_DOUBLE_EQ(q8.at<double>(0, 4), 1.0);
  EXPECT_EQ(q8.at<double>(0, 5), 1.0);
  const cv::Mat q16 = quantize(values, 16);
  EXPECT_DOUBLE_EQ(q16.at<double>(0, 2), 32768.0 / 65535);
  const cv::Mat random = randomImage(20, 20, 3);
  EXPECT_LE(cv::norm(quantize(random, 8) - random, cv::NORM_INF), 0.5 / 255 + 1e-15);
  EXPECT_THROW(quantize(values, 12), InvalidInput);
}

TEST(BlurModel, GaussianNoiseVarianceAndDeterminism) {
  const cv::Mat grey(256, 256, CV_64F, cv::Scalar(0.5));
  const double variance = 0.001;  // σ ≈ 0.032: no clipping at 0.5
  const cv::Mat a = addGaussianNoise(grey, variance, 42);
  cv::Scalar mean, stddev;
  cv::meanStdDev(a - grey, mean, stddev);
  EXPECT_NEAR(mean[0], 0.0, 0.001);
  EXPECT_NEAR(stddev[0] * stddev[0], variance, 0.05 * variance);
  EXPECT_EQ(cv::norm(a, addGaussianNoise(grey, variance, 42), cv::NORM_INF), 0.0);  // same seed, same noise
  EXPECT_GT(cv::norm(a, addGaussianNoise(grey, variance, 43), cv::NORM_INF), 0.01);
  EXPECT_EQ(cv::norm(addGaussianNoise(grey, 0.0, 1), grey, cv::NORM_INF), 0.0);
  const cv::Mat clipped = addGaussianNoise(cv::Mat(64, 64, CV_64F, cv::Scalar(0.99)), 0.01, 5);
  double lo = 0, hi = 0;
  cv::minMaxLoc(clipped, &lo, &hi);
  EXPECT_LE(hi, 1.0);
  EXPECT_GE(lo, 0.0);
  EXPECT_THROW(addGaussianNoise(grey, -1.0, 1), InvalidInput);
}

TEST(BlurModel, IrradianceBlurWithLinearResponseIsIntensityBlur) {
  const cv::Mat image = randomImage(32, 32, 9);
  const cv::Mat kernel = normalizeKernel(randomImage(7, 7, 10));
  EXPECT_LT(cv::norm(irradianceBlur(image, ResponseCurve(), kernel) - intensityBlur(image, kernel), cv::NORM_INF), 1e-14);
  // …and with a gamma curve it differs (the two models of Sec. 3 are not the same)
  EXPECT_GT(cv::norm(irradianceBlur(image, ResponseCurve(GammaModel{2.2}), kernel) - intensityBlur(image, kernel),
                     cv::NORM_INF),
            0.01);
}

TEST(BlurModel, SimulatePairIsConsistentWithEq4) {
  ASSERT_TRUE(std::filesystem::exists(test::samples() / "levin09" / "im1.png")) << "bundled samples missing";
  const cv::Mat image = test::levinImage(1);
  const cv::Mat kernel = test::levinKernel(2);
  const ResponseModel model = GammaModel{2.2};
  const ResponseCurve curve(model);
  for (bool irradiance : {true, false}) {
    SimulationOptions options;
    options.image_is_irradiance = irradiance;
    const SimulationResult pair = simulatePair(image, model, kernel, options);
    // I = ψ(Ĩ) or I = the input; Ĩ = φ(I)
    if (irradiance) {
      EXPECT_LT(cv::norm(pair.irradiance - image, cv::NORM_INF), 1e-15);
      EXPECT_LT(cv::norm(pair.sharp_clean - curve.forward(image), cv::NORM_INF), 1e-12);
    } else {
      EXPECT_LT(cv::norm(pair.sharp_clean - image, cv::NORM_INF), 1e-15);
      EXPECT_LT(cv::norm(pair.irradiance - curve.inverse(image), cv::NORM_INF), 1e-12);
    }
    // B = ψ(φ(I) ⊗ K) before quantisation, within half an 8-bit level after
    const cv::Mat expected = curve.forward(convolve(curve.inverse(pair.sharp_clean), kernel));
    EXPECT_LE(cv::norm(pair.blurred - expected, cv::NORM_INF), 0.5 / 255 + 1e-9);
    EXPECT_LE(cv::norm(pair.blurred - irradianceBlur(pair.sharp_clean, curve, kernel), cv::NORM_INF), 0.5 / 255 + 1e-9);
    EXPECT_LT(cv::norm(pair.intensity_blurred - intensityBlur(pair.sharp_clean, kernel), cv::NORM_INF), 1e-15);
    // no noise: I is the quantised clean image
    EXPECT_EQ(cv::norm(pair.sharp - quantize(pair.sharp_clean, 8), cv::NORM_INF), 0.0);
    EXPECT_EQ(pair.clipped_pixels, 0);
  }
  // r > 1 saturates
  SimulationOptions bright;
  bright.ratio = 4.0;
  const SimulationResult saturated = simulatePair(image, model, kernel, bright);
  EXPECT_GT(saturated.clipped_pixels, 0);
  double hi = 0;
  cv::minMaxLoc(saturated.blurred, nullptr, &hi);
  EXPECT_LE(hi, 1.0);
}

}  // namespace
}  // namespace crfcal
