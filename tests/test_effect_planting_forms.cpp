// The held-out planting forms (effect_planting.hpp, form = "held_out"): each plants the effect it names, in a form
// other than the detector's model, and two effects can be planted at once.
#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/effect_planting.hpp"
#include "crfcal/error.hpp"
#include "crfcal/sensor_noise.hpp"

namespace crfcal {
namespace {

// A flat mid-grey photo, no noise, a 1-px kernel and a linear curve: what is planted is all that differs.
PlantingOptions quiet(const std::string& effect, double strength, std::uint64_t seed) {
  PlantingOptions o;
  o.effect = effect;
  o.strength = strength;
  o.form = "held_out";
  o.sharp_sigma = 0;
  o.noise_gain_blurred = 0;
  o.read_noise_blurred = 0;
  o.seed = seed;
  return o;
}

const cv::Mat kDelta = cv::Mat::ones(1, 1, CV_64F);

TEST(PlantingForms, HeldOutVignettingLosesTheStrengthAtTheCornersOfOneShot) {
  const cv::Mat flat(120, 160, CV_8UC1, cv::Scalar(200));
  for (std::uint64_t seed = 1; seed <= 4; ++seed) {
    const PlantedPair p = plantEffect(flat, GammaModel{1.0}, kDelta, quiet("vignetting", 0.3, seed));
    const double centre_i = p.sharp.at<uchar>(60, 80), corner_i = p.sharp.at<uchar>(0, 0);
    const double centre_b = p.blurred.at<uchar>(60, 80), corner_b = p.blurred.at<uchar>(0, 0);
    const double loss = 1 - std::min(corner_i / centre_i, corner_b / centre_b);
    EXPECT_NEAR(loss, 0.3, 0.02) << p.detail;
    EXPECT_NE(p.detail.find("cos^4"), std::string::npos);
  }
}

// The sharp shot's std over the inner part of one half of a two-level photo.
double halfStd(const cv::Mat& sharp, bool left) {
  const cv::Rect half(left ? 10 : sharp.cols / 2 + 10, 10, sharp.cols / 2 - 20, sharp.rows - 20);
  cv::Scalar mean, sd;
  cv::meanStdDev(sharp(half), mean, sd);
  return sd[0];
}

TEST(PlantingForms, SensorNoiseOfTheSharpShotIsAddedBeforeTheCurve) {
  // A camera adds its noise to the irradiance, before the curve (sensor_noise.hpp): through a gamma-2.2 curve each
  // level gets σ_I = √(a·φ + b) / φ' — here the darks 1.4× the brights' — where the seed's intensity noise is the
  // same everywhere.
  cv::Mat photo(200, 200, CV_8UC1, cv::Scalar(40));
  photo.colRange(100, 200).setTo(200);
  PlantingOptions o = quiet("none", 0, 3);
  o.form = "detector";
  const ResponseModel phi = GammaModel{2.2};
  SensorNoise noise;
  noise.green = {2e-4, 2e-6};
  o.sharp_sensor_noise = SensorNoise{};  // a noise-free law first: the clean levels of the two halves
  const PlantedPair clean = plantEffect(photo, phi, kDelta, o);
  o.sharp_sensor_noise = noise;
  const PlantedPair noisy = plantEffect(photo, phi, kDelta, o);
  const std::vector<double> law = intensityNoisePerLevel(noise.green, phi, 256);
  for (const bool left : {true, false}) {
    const int level = clean.sharp.at<uchar>(100, left ? 50 : 150);
    const double expected = 255 * law[static_cast<std::size_t>(level)];
    EXPECT_NEAR(halfStd(noisy.sharp, left), std::sqrt(expected * expected + 1.0 / 12), 0.12 * expected)
        << (left ? "dark" : "bright") << " half at level " << level;
  }
  EXPECT_GT(halfStd(noisy.sharp, true), 1.25 * halfStd(noisy.sharp, false));
  o.sharp_sensor_noise.reset();  // the seed's way: one σ in the intensity
  o.sharp_sigma = 0.01;
  const PlantedPair seed = plantEffect(photo, phi, kDelta, o);
  EXPECT_NEAR(halfStd(seed.sharp, true) / halfStd(seed.sharp, false), 1.0, 0.1);
}

TEST(PlantingForms, HeldOutClippingIsAKneeWithoutAPlateau) {
  cv::Mat ramp(64, 256, CV_8UC1);
  for (int x = 0; x < 256; ++x) ramp.col(x).setTo(x);
  auto topCount = [](const cv::Mat& b) {
    double max_value = 0;
    cv::minMaxLoc(b, nullptr, &max_value);
    return cv::countNonZero(b == max_value);
  };
  PlantingOptions knee = quiet("clipping", 0.2, 1);
  knee.exposure = 0.2;  // no column of the ramp saturates before the effect
  PlantingOptions plateau = knee;
  plateau.form = "detector";
  const PlantedPair k = plantEffect(ramp, GammaModel{2.2}, kDelta, knee);
  const PlantedPair p = plantEffect(ramp, GammaModel{2.2}, kDelta, plateau);
  EXPECT_GT(topCount(p.blurred), 64 * 30);  // the plateau: a fifth of the informative columns on one level
  EXPECT_LT(topCount(k.blurred), 64 * 12);  // the knee: compressed, still rising
  EXPECT_NE(k.detail.find("knee"), std::string::npos);
}

TEST(PlantingForms, HeldOutCameraMixingKeepsGreyGreyAndMixesColour) {
  const cv::Mat grey(40, 40, CV_8UC3, cv::Scalar(120, 120, 120));
  const PlantedPair g = plantEffect(grey, GammaModel{2.2}, kDelta, quiet("channel_mixing", 0.2, 1));
  cv::Scalar m = cv::mean(g.blurred);
  EXPECT_NEAR(m[0], m[1], 1.0);  // camera matrix rows sum to 1: white (and grey) stays put
  EXPECT_NEAR(m[2], m[1], 1.0);
  const cv::Mat red(40, 40, CV_8UC3, cv::Scalar(0, 0, 200));
  PlantingOptions o = quiet("channel_mixing", 0.2, 1);
  o.exposure = 0.2;
  const PlantedPair r = plantEffect(red, GammaModel{2.2}, kDelta, o);
  m = cv::mean(r.blurred);
  const cv::Scalar sharp = cv::mean(r.sharp);
  EXPECT_NEAR(sharp[1], 0.0, 0.5);
  EXPECT_GT(m[1] + m[0], 5.0) << "red leaks into G or B of the blurred shot through the camera matrix";
}

TEST(PlantingForms, TwoEffectsArePlantedTogetherAndMustDiffer) {
  const cv::Mat flat(120, 160, CV_8UC1, cv::Scalar(120));
  PlantingOptions o = quiet("vignetting", 0.3, 2);
  o.second_effect = "black_level_offset";
  o.second_strength = 0.01;
  const PlantedPair p = plantEffect(flat, GammaModel{1.0}, kDelta, o);
  EXPECT_EQ(p.effect, "vignetting+black_level_offset");
  EXPECT_NE(p.detail.find("cos^4"), std::string::npos);
  EXPECT_TRUE(p.detail.find("offset") != std::string::npos || p.detail.find("veil") != std::string::npos) << p.detail;
  o.second_effect = "vignetting";
  EXPECT_THROW(plantEffect(flat, GammaModel{1.0}, kDelta, o), InvalidInput);
  o.second_effect = "none";
  o.form = "sideways";
  EXPECT_THROW(plantEffect(flat, GammaModel{1.0}, kDelta, o), InvalidInput);
}

}  // namespace
}  // namespace crfcal
