// `crfcal study pairs` (issue 17, item 2): the measurements it makes on the real phone pairs, each checked on
// synthetic inputs with a planted cause (noise reduction, sharpening halos, separate kernel blobs), plus the CLI's
// error without ../shared. No test needs ../shared.
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/curve_shape_spread.hpp"
#include "crfcal/edge_profile.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel_shape.hpp"
#include "crfcal/noise_law_comparison.hpp"
#include "crfcal/shot_imitation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A scene of random rectangles (straight, isolated steps of various contrasts), blurred by `sigma`.
cv::Mat rectangles(double sigma, std::uint64_t seed = 3) {
  cv::Mat img(240, 320, CV_64F, cv::Scalar(0.3));
  cv::RNG rng(seed);
  for (int i = 0; i < 14; ++i) {
    const int x = rng.uniform(10, 260), y = rng.uniform(10, 180);
    cv::rectangle(img, cv::Rect(x, y, rng.uniform(25, 55), rng.uniform(25, 55)), cv::Scalar(rng.uniform(0.1, 0.9)), cv::FILLED);
  }
  if (sigma > 0) cv::GaussianBlur(img, img, cv::Size(), sigma);
  return img;
}

// Unsharp masking, the usual camera sharpening: img + amount·(img − img ⊗ G_radius).
cv::Mat unsharpMask(const cv::Mat& img, double radius, double amount) {
  cv::Mat smooth;
  cv::GaussianBlur(img, smooth, cv::Size(), radius);
  return img + amount * (img - smooth);
}

TEST(EdgeProfile, PlantedSharpeningHaloIsMeasured) {
  const cv::Mat plain = rectangles(1.0);
  const EdgeProfile without = measureEdgeProfile(plain);
  const EdgeProfile with = measureEdgeProfile(unsharpMask(plain, 1.5, 1.0));
  EXPECT_GT(without.edges, 100);
  EXPECT_LT(without.halo(), 0.01);
  EXPECT_GT(with.halo(), 0.05) << "overshoot " << with.overshoot << " undershoot " << with.undershoot;
  EXPECT_GT(with.overshoot, 0.03);
  EXPECT_GT(with.undershoot, 0.03);
}

TEST(EdgeProfile, WidthGrowsWithTheBlur) {
  const double narrow = measureEdgeProfile(rectangles(0.8)).width;
  const double wide = measureEdgeProfile(rectangles(1.6)).width;
  // a Gaussian edge's 10–90 % width is 2.56 σ (plus the pixel grid's share)
  EXPECT_NEAR(wide, 2.56 * 1.6, 0.6);
  EXPECT_GT(wide, 1.5 * narrow);
}

TEST(EdgeProfile, FlatImageIsRefused) {
  EXPECT_THROW(measureEdgeProfile(cv::Mat(64, 64, CV_64F, cv::Scalar(0.5))), InvalidInput);
}

// A horizontal ramp 0.05 → 0.95 with noise σ(v) = √(a v + b) (a known law).
cv::Mat noisyRamp(const std::function<double(double)>& law, std::uint64_t seed = 5) {
  cv::Mat img(240, 320, CV_64F);
  cv::RNG rng(seed);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      const double v = 0.05 + 0.9 * x / (img.cols - 1.0);
      img.at<double>(y, x) = v + law(v) * rng.gaussian(1.0);
    }
  return img;
}

TEST(NoiseLaw, NoiseAtItsLawIsNotReduced) {
  const auto law = [](double v) { return std::sqrt(4e-4 * v + 1e-5); };
  const NoiseLawComparison c = compareNoiseToLaw(noisyRamp(law), law);
  ASSERT_GE(c.ratio.size(), 5u);
  EXPECT_NEAR(c.median_ratio, 1.0, 0.12);
  EXPECT_FALSE(c.reduced);
  EXPECT_FALSE(c.noisier);
}

TEST(NoiseLaw, PlantedNoiseReductionIsDetected) {
  const auto law = [](double v) { return std::sqrt(4e-4 * v + 1e-5); };
  cv::Mat smoothed;
  cv::GaussianBlur(noisyRamp(law), smoothed, cv::Size(), 1.0);  // NR: a 1 px Gaussian (σ of white noise × ≈ 0.28)
  const NoiseLawComparison c = compareNoiseToLaw(smoothed, law);
  ASSERT_GE(c.ratio.size(), 5u);
  EXPECT_LT(c.median_ratio, 0.5);
  EXPECT_TRUE(c.reduced);
}

TEST(NoiseLaw, MeasuredLawIsLinearBetweenBinsAndUnknownOutside) {
  const auto law = noiseLawFromBins({{0.2, 0.01, 100}, {0.6, 0.03, 100}});
  EXPECT_NEAR(law(0.4), 0.02, 1e-12);
  EXPECT_TRUE(std::isnan(law(0.1)));
  EXPECT_TRUE(std::isnan(law(0.7)));
}

TEST(ShotImitation, TakesTheTargetsHistogramAndNoise) {
  const cv::Mat reference = rectangles(1.0);
  cv::Mat target = 0.25 * rectangles(1.0, 9);  // another, darker scene: only its histogram is used
  const double sigma = 0.01;
  const cv::Mat imitation = imitateShot(reference, target, {{0.1, sigma, 1000}}, {.seed = 2, .levels = 0});
  cv::Scalar mean_t, sd_t, mean_i, sd_i;
  cv::meanStdDev(target, mean_t, sd_t);
  cv::meanStdDev(imitation, mean_i, sd_i);
  EXPECT_NEAR(mean_i[0], mean_t[0], 0.01);
  EXPECT_NEAR(sd_i[0], std::sqrt(sd_t[0] * sd_t[0] + sigma * sigma), 0.01);
  const auto bins = measureNoiseLevels(imitation);
  ASSERT_FALSE(bins.empty());
  EXPECT_NEAR(bins.front().sigma, sigma, 0.002);
}

TEST(KernelShape, SeparateBlobsAreMultimodalAndAPathIsNot) {
  cv::Mat blobs = cv::Mat::zeros(21, 21, CV_64F);
  cv::circle(blobs, {5, 10}, 1, cv::Scalar(1.0), cv::FILLED);
  cv::circle(blobs, {15, 10}, 1, cv::Scalar(0.6), cv::FILLED);
  const KernelShape two = describeKernelShape(blobs);
  EXPECT_EQ(two.components, 2);
  EXPECT_TRUE(two.multimodal());
  cv::Mat path = cv::Mat::zeros(21, 21, CV_64F);
  cv::line(path, {5, 10}, {15, 10}, cv::Scalar(1.0));
  path.at<double>(10, 5) = 0.02;  // a faint speck inside the path's support: one component anyway
  const KernelShape one = describeKernelShape(path);
  EXPECT_EQ(one.components, 1);
  EXPECT_GT(one.elongation, 3);
  EXPECT_THROW(describeKernelShape(cv::Mat::zeros(5, 5, CV_64F)), InvalidInput);
}

TEST(CurveShapeSpread, ScaleIsIgnoredAndExponentIsNot) {
  std::vector<double> a(1024), b(1024), c(1024);
  for (int i = 0; i < 1024; ++i) {
    const double x = i / 1023.0;
    a[static_cast<std::size_t>(i)] = std::pow(x, 2.2);
    b[static_cast<std::size_t>(i)] = 3.0 * std::pow(x, 2.2);
    c[static_cast<std::size_t>(i)] = std::pow(x, 1.5);
  }
  EXPECT_NEAR(curveShapeSpread({a, b}, {0.05, 0.5}), 0.0, 1e-12);
  EXPECT_GT(curveShapeSpread({a, c}, {0.05, 0.5}), 0.05);
  EXPECT_THROW(curveShapeSpread({a, c}, {0.5, 0.5}), InvalidInput);
  const auto common = commonRange({{0.01, 0.7}, {0.02, 0.47}, {0.0, 0.9}});
  EXPECT_DOUBLE_EQ(common.first, 0.02);
  EXPECT_DOUBLE_EQ(common.second, 0.47);
}

TEST(StudyPairsCli, MissingDataDirectoryIsOneErrorLine) {
  test::TempDir dir;
  const auto r = test::run(test::crfcalBinary().string() + " study pairs --data " + (dir / "nope").string() + " -o " +
                           (dir / "out").string() + " -q");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("shared data directory not found"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir / "out"));
}

TEST(StudyPairsCli, MissingPairsFolderIsNamed) {
  test::TempDir dir;
  std::filesystem::create_directories(dir / "data" / "pairs");
  const auto r = test::run(test::crfcalBinary().string() + " study pairs --data " + (dir / "data").string() + " -o " +
                           (dir / "out").string() + " -q");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("vivo_x6s"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir / "out"));
}

}  // namespace
}  // namespace crfcal
