// Residual effect diagnostics (effects.hpp) on pairs with one planted effect (effect_planting.hpp).
// Small grey images, G only, given kernel (the effects tested here are not about blur): each case < 1 s.
#include <algorithm>

#include <gtest/gtest.h>

#include "crfcal/effect_planting.hpp"
#include "crfcal/error.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/pair_calibration.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

using test::levinImage;
using test::levinKernel;
using test::samples;

struct Case {
  PairCalibrationResult result;
  ResponseModel truth;
  double rmse = 0, rmse_base = 0;
  std::vector<std::string> detected;
};

cv::Mat photo(int index) {
  cv::Mat u = levinImage(index), out;
  u.convertTo(out, CV_8U, 255.0);
  return out;
}

Case runCase(const std::string& effect, double strength, std::uint64_t seed, int image = 1, int kernel = 2,
             const std::string& camera = "NikonD70") {
  Case c;
  c.truth = TableModel{io::readCurveTable(samples() / "camera_curves" / (camera + ".csv"))};
  PlantingOptions po;
  po.effect = effect;
  po.strength = strength;
  po.ratio = 1.2;
  po.seed = seed;
  const PlantedPair pair = plantEffect(photo(image), c.truth, levinKernel(kernel), po);
  PairCalibrationOptions options;
  options.register_pair = false;
  options.rgb = false;
  options.given_kernel = levinKernel(kernel);
  options.fit.initial_ratio = pair.exif_ratio;
  c.result = calibratePair(pair.sharp, pair.blurred, options);
  c.detected = c.result.effects.detected();
  c.rmse = curveRmse(c.result.fits.at("G").inverse_crf, sampleInverse(c.truth));
  const auto& base = c.result.base_fits.empty() ? c.result.fits : c.result.base_fits;
  c.rmse_base = curveRmse(base.at("G").inverse_crf, sampleInverse(c.truth));
  return c;
}

// signal_dependent_noise is excluded from "no other effect": its false-alarm rate on clean pairs is measured in
// docs/results-parts/effects.md and is not yet under 5 % (camera noise is signal-dependent in intensity too).
std::vector<std::string> withoutNoise(std::vector<std::string> names) {
  names.erase(std::remove(names.begin(), names.end(), "signal_dependent_noise"), names.end());
  return names;
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
}

TEST(Effects, ReportListsEveryEffect) {
  const Case c = runCase("none", 0, 3);
  ASSERT_EQ(c.result.effects.entries.size(), effectNames().size());
  for (const auto& e : c.result.effects.entries) {
    EXPECT_FALSE(e.name.empty());
    EXPECT_FALSE(e.detail.empty()) << e.name;
  }
  EXPECT_TRUE(withoutNoise(c.detected).empty()) << c.result.effects.summary();
  EXPECT_TRUE(c.result.base_fits.empty() || !c.detected.empty());
  EXPECT_LT(c.rmse, 0.02);
}

TEST(Effects, ExposureRatioMismatchIsNamed) {
  for (std::uint64_t seed : {1u, 2u}) {
    const double strength = plantingThreshold("exposure_ratio_mismatch") * (1.0 + 0.3 * seed);
    const Case c = runCase("exposure_ratio_mismatch", strength, seed, 1 + seed % 4);
    const auto names = withoutNoise(c.detected);
    ASSERT_EQ(names.size(), 1u) << c.result.effects.summary();
    EXPECT_EQ(names[0], "exposure_ratio_mismatch");
    EXPECT_LT(c.rmse, 0.02) << "phi must stay within the clean-case accuracy";
  }
}

TEST(Effects, VignettingIsNamedAndCorrected) {
  const Case c = runCase("vignetting", 0.35, 4, 3, 3);
  const EffectEntry* e = c.result.effects.find("vignetting");
  ASSERT_NE(e, nullptr);
  EXPECT_TRUE(e->detected) << c.result.effects.summary();
  EXPECT_LT(e->parameters.at("corner_gain"), 0.9);
  // The extended model's phi is reported and is better than the base model's.
  EXPECT_FALSE(c.result.base_fits.empty());
  EXPECT_LT(c.rmse, c.rmse_base);
  // Not yet within the clean-case accuracy for this strong case (0.056 vs base 0.11; see effects.md).
  EXPECT_LT(c.rmse, 0.08);
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

}  // namespace
}  // namespace crfcal
