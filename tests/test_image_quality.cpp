// SSIM, the edge-band error (image_quality.hpp) and the perturbed response (curve_perturbation.hpp) used by
// `crfcal bench deblur`.
#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "crfcal/curve_perturbation.hpp"
#include "crfcal/error.hpp"
#include "crfcal/image_quality.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

cv::Mat withNoise(const cv::Mat& image, double sigma) {
  cv::Mat noise(image.size(), CV_64F);
  cv::RNG rng(7);
  rng.fill(noise, cv::RNG::NORMAL, 0, sigma);
  return image + noise;
}

TEST(ImageQuality, SsimIsOneForIdenticalImagesAndDropsWithNoise) {
  const cv::Mat sharp = test::levinImage(1);
  EXPECT_NEAR(ssim(sharp, sharp), 1.0, 1e-12);
  const double light = ssim(withNoise(sharp, 0.01), sharp), heavy = ssim(withNoise(sharp, 0.05), sharp);
  EXPECT_LT(light, 0.99);
  EXPECT_LT(heavy, light - 0.1);
  EXPECT_NEAR(ssim(withNoise(sharp, 0.05), sharp), ssim(sharp, withNoise(sharp, 0.05)), 1e-12);  // symmetric
  // colour: the mean over channels
  cv::Mat colour, noisy;
  cv::merge(std::vector<cv::Mat>{sharp, sharp, withNoise(sharp, 0.05)}, colour);
  cv::merge(std::vector<cv::Mat>{sharp, sharp, sharp}, noisy);
  EXPECT_NEAR(ssim(colour, noisy), (2 + heavy) / 3, 1e-9);
  EXPECT_THROW(ssim(sharp, sharp(cv::Rect(0, 0, 100, 100))), InvalidInput);
}

TEST(ImageQuality, EdgeBandErrorCountsOnlyErrorsNearEdges) {
  cv::Mat step(64, 64, CV_64F, cv::Scalar(0.1));
  step.colRange(32, 64).setTo(0.9);
  EXPECT_EQ(edgeBandError(step, step).rmse, 0.0);
  EXPECT_EQ(edgeBandError(step, step).pixels, 64 * (2 * 4 + 2));  // columns 27..36: 4 px either side of the step
  cv::Mat far = step.clone(), near = step.clone();
  far.colRange(0, 10) += 0.2;   // an error away from the edge: not counted
  near.colRange(30, 34) += 0.2;  // an error at the edge
  EXPECT_EQ(edgeBandError(far, step).rmse, 0.0);
  EXPECT_NEAR(edgeBandError(near, step).rmse, 0.2 * std::sqrt(4.0 / 10), 1e-12);
  const cv::Mat flat(64, 64, CV_64F, cv::Scalar(0.5));
  EXPECT_EQ(edgeBandError(flat, flat).pixels, 0);  // no edge of contrast 0.3
}

TEST(CurvePerturbation, PowerPerturbationHitsTheTargetRmseBothWays) {
  const ResponseCurve curve(GammaModel{2.2});
  for (bool steeper : {true, false}) {
    const ResponseCurve off = powerPerturbedCurve(curve, 0.02, steeper);
    EXPECT_NEAR(curveRmse(off, curve), 0.02, 1e-6);
    EXPECT_EQ(off.inverse(0.5) > curve.inverse(0.5), !steeper);  // φ^a with a > 1 lies below φ
    EXPECT_NEAR(off.inverse(1.0), 1.0, 1e-12);
  }
  EXPECT_THROW(powerPerturbedCurve(curve, 0.0), InvalidInput);
}

}  // namespace
}  // namespace crfcal
