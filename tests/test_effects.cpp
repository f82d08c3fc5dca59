// Residual effect diagnostics (effects.hpp) on pairs with one hidden effect (effect_planting.hpp): a real photo
// (Levin et al., grey; the bundled window photo for colour) through a real camera curve and a real kernel, one
// effect planted at a seeded random strength in [threshold, 2·threshold]; calibratePair must name that effect and
// no other, and report a φ within the clean-case accuracy (the same pair without the effect, + 0.005 RMSE).
// Detection and false-alarm RATES are measured by `crfcal bench effects` (docs/RESULTS.md#effects).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/effect_planting.hpp"
#include "crfcal/error.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/noise_profiles.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/sensor_noise.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

using test::levinImage;
using test::levinKernel;
using test::samples;

constexpr double kPhiTolerance = 0.005;  // as in `crfcal bench effects`

cv::Mat photo(int index) {
  cv::Mat u = levinImage(index), out;
  u.convertTo(out, CV_8U, 255.0);
  return out;
}

// Two Levin photos side by side (510 × 255): enough blocks for the localised effects, still ~1 s per run.
cv::Mat pairOfPhotos(int a, int b) {
  cv::Mat out;
  cv::hconcat(photo(a), photo(b), out);
  return out;
}

struct PairSetup {
  cv::Mat photo;
  std::string camera = "NikonD70";
  int kernel = 2;
  double ratio = 1.2;
  bool estimate_kernel = false;
  std::optional<SensorNoise> sensor = std::nullopt;  // the sharp shot's noise on its irradiance (sharp_sensor_noise)
};

struct Case {
  PairCalibrationResult result;
  PlantedPair pair;
  double strength = 0;
  double rmse = 0;        // reported φ_G (extended model when an effect was detected)
  double rmse_clean = 0;  // the clean twin's φ_G (same pair without the effect), same range
  std::vector<std::string> detected;
};

PairCalibrationOptions calibrationOptions(const PairSetup& s, const PlantedPair& pair) {
  PairCalibrationOptions options;
  options.register_pair = false;
  options.rgb = s.photo.channels() == 3;
  if (s.estimate_kernel) {
    options.kernel.kernel_size = 31;
    options.tiles.whole_image_below = 4096;
    options.rounds = 1;
  } else {
    options.given_kernel = levinKernel(s.kernel);
  }
  options.fit.nominal_ratio = pair.exif_ratio;
  return options;
}

// Plants `effect` at a strength drawn (seeded) uniformly in [threshold, 2·threshold] and calibrates.
Case runCase(const std::string& effect, const PairSetup& s, std::uint64_t seed) {
  Case c;
  const ResponseModel truth = TableModel{io::readCurveTable(samples() / "camera_curves" / (s.camera + ".csv"))};
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(1.0, 2.0);
  PlantingOptions po;
  po.effect = effect;
  po.strength = effect == "none" ? 0.0 : plantingThreshold(effect) * u(rng);
  po.ratio = s.ratio;
  po.seed = seed;
  po.sharp_sensor_noise = s.sensor;
  c.strength = po.strength;
  c.pair = plantEffect(s.photo, truth, levinKernel(s.kernel), po);
  c.result = calibratePair(c.pair.sharp, c.pair.blurred, calibrationOptions(s, c.pair));
  c.detected = c.result.effects.detected();
  // φ where the pair measures it: up to B's plateau when there is one.
  const auto t = sampleInverse(truth);
  const std::size_t top = static_cast<std::size_t>(std::lround(c.pair.plateau_intensity * (t.size() - 1)));
  auto rmse = [&](const std::vector<double>& phi) {
    return curveRmse(std::vector<double>(phi.begin(), phi.begin() + top + 1),
                     std::vector<double>(t.begin(), t.begin() + top + 1));
  };
  c.rmse = rmse(c.result.fits.at("G").inverse_crf);
  PlantingOptions clean = po;
  clean.effect = "none";
  const PlantedPair twin = plantEffect(s.photo, truth, levinKernel(s.kernel), clean);
  PairCalibrationOptions twin_options = calibrationOptions(s, twin);
  twin_options.effects.enabled = false;
  twin_options.fit.saturation_high = std::min(twin_options.fit.saturation_high, c.pair.plateau_intensity - 0.5 / 255);
  c.rmse_clean = rmse(calibratePair(twin.sharp, twin.blurred, twin_options).fits.at("G").inverse_crf);
  return c;
}

std::string names(const std::vector<std::string>& v) {
  std::string out;
  for (const auto& n : v) out += (out.empty() ? "" : ",") + n;
  return "[" + out + "]";
}

// The hidden effect is named, nothing else is, and the reported φ is within the clean-case accuracy. A sensor's noise
// is signal-dependent, so with s.sensor signal_dependent_noise may be named beside the effect (it is true).
void expectFound(const std::string& effect, const PairSetup& s, std::uint64_t seed) {
  Case c = runCase(effect, s, seed);
  if (s.sensor)
    c.detected.erase(std::remove(c.detected.begin(), c.detected.end(), "signal_dependent_noise"), c.detected.end());
  ASSERT_EQ(c.detected, std::vector<std::string>{effect})
      << effect << " at strength " << c.strength << " detected " << names(c.detected) << "\n"
      << c.result.effects.summary();
  EXPECT_LE(c.rmse, c.rmse_clean + kPhiTolerance)
      << effect << ": reported phi RMSE " << c.rmse << " vs clean twin " << c.rmse_clean;
}

TEST(EffectPlanting, DeterministicAndEveryEffect) {
  const ResponseModel phi = GammaModel{2.2};
  cv::Mat small = photo(2)(cv::Rect(0, 0, 96, 96)).clone();
  cv::Mat colour;
  cv::Mat flipped, transposed;
  cv::flip(small, flipped, 1);
  cv::transpose(small, transposed);
  cv::merge(std::vector<cv::Mat>{small, flipped, transposed}, colour);  // three different channels
  for (const auto& name : effectNames()) {
    PlantingOptions po;
    po.effect = name;
    po.strength = plantingThreshold(name);
    EXPECT_FALSE(thresholdReason(name).empty()) << name;
    const PlantedPair a = plantEffect(colour, phi, levinKernel(1), po), b = plantEffect(colour, phi, levinKernel(1), po);
    EXPECT_EQ(cv::norm(a.sharp, b.sharp, cv::NORM_INF), 0) << name;
    EXPECT_EQ(cv::norm(a.blurred, b.blurred, cv::NORM_INF), 0) << name;
    PlantingOptions none = po;
    none.effect = "none";
    const PlantedPair clean = plantEffect(colour, phi, levinKernel(1), none);
    const bool changed = cv::norm(a.sharp, clean.sharp, cv::NORM_INF) > 0 ||
                         cv::norm(a.blurred, clean.blurred, cv::NORM_INF) > 0 || a.exif_ratio != clean.exif_ratio;
    EXPECT_TRUE(changed) << name;
  }
  PlantingOptions bad;
  bad.effect = "lens_flare";
  EXPECT_THROW(plantEffect(small, phi, levinKernel(1), bad), InvalidInput);
  bad.effect = "signal_dependent_noise";
  bad.strength = 0.5;  // a variance ratio below 1
  EXPECT_THROW(plantEffect(small, phi, levinKernel(1), bad), InvalidInput);
}

TEST(Effects, CleanPairsYieldNoEffect) {
  // Two clean pairs (different photos, curves, kernels, ratios): every effect tested, none reported, φ untouched.
  for (const auto& [setup, seed] :
       {std::pair<PairSetup, std::uint64_t>{{pairOfPhotos(1, 2), "NikonD70", 2, 1.2, false}, 3},
        {{pairOfPhotos(3, 4), "CanonPowerShotG9", 5, 0.9, false}, 4}}) {
    const Case c = runCase("none", setup, seed);
    ASSERT_EQ(c.result.effects.entries.size(), effectNames().size());
    int tested = 0;
    for (const auto& e : c.result.effects.entries) {
      EXPECT_FALSE(e.detail.empty()) << e.name;
      tested += e.tested;
    }
    EXPECT_GE(tested, 5) << c.result.effects.summary();  // all but channel_mixing (grey) and the blur (given kernel)
    EXPECT_TRUE(c.detected.empty()) << names(c.detected) << "\n" << c.result.effects.summary();
    EXPECT_TRUE(c.result.base_fits.empty());
    EXPECT_LT(c.rmse, 0.02);
  }
}

TEST(Effects, ExposureRatioMismatchIsFound) {
  expectFound("exposure_ratio_mismatch", {pairOfPhotos(1, 3), "SonyDSLR-A100", 4, 1.1, false}, 11);
}

TEST(Effects, SignalDependentNoiseIsFound) {
  expectFound("signal_dependent_noise", {pairOfPhotos(2, 4), "CanonPowerShotS50", 3, 1.3, false}, 12);
}

// The size of the level dependence is read over the levels the sharp shot covers (the fit's levels), not extrapolated
// to 0.1–0.9: in a dark shot the bins span a small part of [0, 1], and the planted law's variance ratio across that
// span is s^(span/0.8). (Extrapolated, the phone's pair 2, σ 0.2 → 0.5 of a level over levels 0.01–0.06, read as a
// contrast of 5·10¹³.)
TEST(EffectsNoise, ContrastIsTheVarianceRatioAcrossTheCoveredLevels) {
  const ResponseModel truth = TableModel{io::readCurveTable(samples() / "camera_curves" / "CanonPowerShotS50.csv")};
  PlantingOptions po;
  po.effect = "signal_dependent_noise";
  po.strength = 6;
  po.ratio = 6;
  po.exposure /= 40;  // a dark short shot (the phone's pair 2 is darker still: its levels reach 0.06)
  po.seed = 12;
  const PlantedPair pair = plantEffect(pairOfPhotos(2, 4), truth, levinKernel(3), po);
  PairCalibrationOptions options = calibrationOptions({pairOfPhotos(2, 4), "CanonPowerShotS50", 3, 6, false}, pair);
  const PairCalibrationResult result = calibratePair(pair.sharp, pair.blurred, options);
  const EffectEntry* noise = result.effects.find("signal_dependent_noise");
  ASSERT_TRUE(noise != nullptr && noise->tested) << result.effects.summary();
  double lowest = 1, highest = 0;
  for (const auto& [key, value] : noise->parameters)
    if (key.rfind("level_", 0) == 0) lowest = std::min(lowest, value), highest = std::max(highest, value);
  const double span = highest - lowest;
  const double contrast = noise->parameters.at("contrast");
  const double law = std::pow(po.strength, span / 0.8);
  std::printf("span %.3f contrast %.3f law %.3f\n", span, contrast, law);
  ASSERT_LT(span, 0.6) << "the underexposed shot covers little of [0, 1]";
  EXPECT_NEAR(std::log(contrast), std::log(law), 0.35) << result.effects.summary();
}

TEST(Effects, ClippingIsFound) {
  expectFound("clipping", {pairOfPhotos(1, 2), "OlympusE500", 2, 1.2, false}, 13);
}

TEST(Effects, VignettingIsFound) {
  expectFound("vignetting", {pairOfPhotos(3, 1), "NikonD70", 6, 1.0, false}, 14);
}

// The sharp shot's noise as a camera makes it: the bundled phone's measured raw noise at ISO 800 on its irradiance.
TEST(Effects, BlackLevelOffsetIsFound) {
  PairSetup s{pairOfPhotos(4, 2), "CanonPowerShotG9", 1, 1.25, false};
  s.sensor = io::readCameraNoiseProfile(samples() / "noise_profiles" / "noiseprofiles.json", "LGE Nexus 5").atIso(800);
  expectFound("black_level_offset", s, 15);
}

// The same pair with the seed's Gaussian noise on I (Sec. 5) instead: still named alone, but its refit's φ is 0.0167
// against the clean twin's 0.0068. The effect search reads I's noise as the base fit does (no debias): right for a
// sensor's noise, which enters before the curve, not for this intensity-domain law, whose clip at black the fit
// leaves in φ (docs/RESULTS.md#effects-debias). So φ is not asserted here.
TEST(Effects, BlackLevelOffsetIsNamedAloneUnderTheSeedsIntensityNoise) {
  const Case c = runCase("black_level_offset", {pairOfPhotos(4, 2), "CanonPowerShotG9", 1, 1.25, false}, 15);
  EXPECT_EQ(c.detected, std::vector<std::string>{"black_level_offset"}) << c.result.effects.summary();
}

// One configuration without a companion: after the mix is corrected a small offset-like remainder still fires
// black_level_offset in many colour cases (the companion rate is measured by the bench, docs/RESULTS.md#effects).
TEST(Effects, ChannelMixingIsFound) {
  cv::Mat window = io::readImage(samples() / "effects" / "window.jpg");
  cv::resize(window, window, cv::Size(), 0.5, 0.5, cv::INTER_AREA);  // 320×240: colour edges, a few seconds
  expectFound("channel_mixing", {window, "CanonPowerShotS60", 4, 1.0, false}, 21);
}

TEST(Effects, SpatiallyVaryingBlurIsFound) {
  // The kernel must be estimated for this one (a given kernel is taken as the truth). Named alone, and the reported
  // φ (the per-tile refit where the refit guard adopts it, else the base fit, whose φ then explains the held-back
  // pixels better under the check's varying kernel) is not worse than ignoring the effect. (Within the clean twin's
  // accuracy is not asserted here: since the irradiance-domain kernel rounds were weighted, the clean estimated-kernel
  // twins improved — bench median 0.0286 → 0.0117 — and the varying-blur fits did not follow; met in 14 of 20 bench
  // pairs, docs/RESULTS.md#effects-blur-guard.)
  const Case c = runCase("spatially_varying_blur", {pairOfPhotos(2, 3), "OlympusE10", 1, 1.0, true}, 17);
  ASSERT_EQ(c.detected, std::vector<std::string>{"spatially_varying_blur"})
      << "detected " << names(c.detected) << "\n" << c.result.effects.summary();
  const auto truth = sampleInverse(TableModel{io::readCurveTable(samples() / "camera_curves" / "OlympusE10.csv")});
  const auto& base_fits = c.result.base_fits.empty() ? c.result.fits : c.result.base_fits;  // empty: no refit kept
  ASSERT_EQ(base_fits.count("G"), 1u) << c.result.effects.summary();
  const double base = curveRmse(base_fits.at("G").inverse_crf, truth);
  EXPECT_LE(c.rmse, base + kPhiTolerance) << "reported phi RMSE " << c.rmse << " vs the base fit's " << base;
}

TEST(Effects, DisabledDiagnosticsReportNothing) {
  const ResponseModel phi = GammaModel{2.2};
  PlantingOptions po;
  const PlantedPair pair = plantEffect(photo(1), phi, levinKernel(1), po);
  PairCalibrationOptions options;
  options.register_pair = false;
  options.rgb = false;
  options.given_kernel = levinKernel(1);
  options.effects.enabled = false;
  const PairCalibrationResult r = calibratePair(pair.sharp, pair.blurred, options);
  EXPECT_TRUE(r.effects.entries.empty());
  EXPECT_TRUE(r.base_fits.empty());
}

TEST(Effects, OptionsAreChecked) {
  EffectOptions o;
  o.min_noise_contrast = 0.5;
  EXPECT_THROW(o.check(), InvalidInput);
  o = EffectOptions{};
  o.phi_terms = 11;
  EXPECT_THROW(o.check(), InvalidInput);
  EXPECT_NO_THROW(EffectOptions{}.check());
}

}  // namespace
}  // namespace crfcal
