// Attribution between competing explanations (calib/src/effect_attribution.cpp, issue 18).
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "crfcal/crf_fitter.hpp"
#include "crfcal/effect_planting.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/io/jpeg_roundtrip.hpp"
#include "crfcal/io/response_io.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

using test::levinImage;
using test::levinKernel;
using test::samples;

cv::Mat photoPair(int a_index, int b_index) {
  cv::Mat a, b, out;
  levinImage(a_index).convertTo(a, CV_8U, 255.0);
  levinImage(b_index).convertTo(b, CV_8U, 255.0);
  cv::hconcat(a, b, out);
  return out;
}

// jpeg_quality > 0: both shots through a 4:2:0 JPEG of that quality.
EffectReport diagnose(const PlantingOptions& po, const std::string& camera, int kernel, int a, int b,
                      double* ratio_out = nullptr, int jpeg_quality = 0) {
  const ResponseModel truth = TableModel{io::readCurveTable(samples() / "camera_curves" / (camera + ".csv"))};
  const cv::Mat K = levinKernel(kernel);
  PlantedPair pair = plantEffect(photoPair(a, b), truth, K, po);
  if (jpeg_quality > 0) {
    pair.sharp = io::jpegRoundTrip(pair.sharp, jpeg_quality);
    pair.blurred = io::jpegRoundTrip(pair.blurred, jpeg_quality);
  }
  CrfFitOptions fo;
  fo.nominal_ratio = pair.exif_ratio;
  const EffectInputs in = test::greenEffectInputs(pair.sharp, pair.blurred, K, fo);
  if (ratio_out) *ratio_out = in.fits.at("G").ratio;
  return diagnoseEffects(in);
}

// An offset in one shot of a real-regime pair (r = 4, the sharp shot underexposed by r; per-channel offsets, a form
// the detector does not assume) bends the base fit's φ and moves its free r 21 % from EXIF's: a free r "explains"
// the misfit, but so does the offset with r at EXIF's value. Before attribution this pair was named
// exposure_ratio_mismatch (and not black_level_offset); EXIF's r is good to a few per cent, so the offset is named.
TEST(EffectAttribution, OffsetInOneShotIsNamedAsAnOffsetNotAsARatioMismatch) {
  PlantingOptions po;
  po.effect = "black_level_offset";
  po.form = "held_out";
  po.strength = 8 * plantingThreshold("black_level_offset");
  po.ratio = 4.0;
  po.exposure /= po.ratio;
  po.seed = 3;
  const EffectReport report = diagnose(po, "SonyDSLR-A100", 4, 4, 1);
  const auto detected = report.detected();
  EXPECT_NE(std::find(detected.begin(), detected.end(), "black_level_offset"), detected.end()) << report.summary();
  EXPECT_EQ(std::find(detected.begin(), detected.end(), "exposure_ratio_mismatch"), detected.end())
      << report.summary();
  const EffectEntry* ratio = report.find("exposure_ratio_mismatch");
  ASSERT_NE(ratio, nullptr);
  EXPECT_GT(std::abs(ratio->parameters.at("relative_difference")), 0.10) << "the free r must be off EXIF here";
  EXPECT_EQ(ratio->explained_by, "black_level_offset") << report.summary();
  EXPECT_EQ(report.find("black_level_offset")->runner_up, "exposure_ratio_mismatch") << report.summary();
}

// With r held at EXIF because the blur is too small to fix it (the pipeline's small-blur rule), a free r that leaves
// EXIF is the φ^γ, r^γ ambiguity, not evidence: the same planted mismatch that is named with r free is not named with
// the hold, and its entry says why (bundled data: the vivo pair behind the rule is checked in test_calibrate_cli.cpp).
TEST(EffectAttribution, RatioHeldForASmallBlurIsNotNamedAMismatch) {
  PlantingOptions po;
  po.effect = "exposure_ratio_mismatch";
  po.strength = 2 * plantingThreshold("exposure_ratio_mismatch");
  po.seed = 1;
  const ResponseModel truth = TableModel{io::readCurveTable(samples() / "camera_curves" / "SonyDSLR-A100.csv")};
  const cv::Mat K = levinKernel(4);
  const PlantedPair pair = plantEffect(photoPair(1, 3), truth, K, po);
  CrfFitOptions fo;
  fo.nominal_ratio = pair.exif_ratio;
  EffectInputs in = test::greenEffectInputs(pair.sharp, pair.blurred, K, fo);
  const auto named = [](const EffectReport& report) {
    const auto detected = report.detected();
    return std::find(detected.begin(), detected.end(), "exposure_ratio_mismatch") != detected.end();
  };
  const EffectReport free_ratio = diagnoseEffects(in);
  ASSERT_TRUE(named(free_ratio)) << free_ratio.summary();
  in.ratio_held_for_small_blur = true;
  const EffectReport held = diagnoseEffects(in);
  EXPECT_FALSE(named(held)) << held.summary();
  EXPECT_NE(held.find("exposure_ratio_mismatch")->detail.find("blur is too small"), std::string::npos)
      << held.summary();
}

// A named effect carries its evidence against the runner-up: the competing explanation with the smallest held-out
// error, and the held-out drop from the runner-up's model to the named one's (which, chosen by the smaller held-out
// error, is not negative).
TEST(EffectAttribution, NamedEffectCarriesItsEvidenceAgainstTheRunnerUp) {
  PlantingOptions po;
  po.effect = "vignetting";
  po.strength = 2 * plantingThreshold("vignetting");
  po.ratio = 1.0;
  po.seed = 14;
  const EffectReport report = diagnose(po, "NikonD70", 6, 3, 1);
  ASSERT_EQ(report.detected(), std::vector<std::string>{"vignetting"}) << report.summary();
  const EffectEntry* e = report.find("vignetting");
  EXPECT_FALSE(e->runner_up.empty());
  EXPECT_NE(e->runner_up, "vignetting");
  EXPECT_GE(e->evidence_gain, 0) << report.summary();
  EXPECT_GE(e->evidence_z, 3.0) << "a planted vignetting at twice the threshold is told apart from its runner-up\n"
                                << report.summary();
  EXPECT_NE(report.summary().find("runner-up " + e->runner_up), std::string::npos) << report.summary();
}

// The real regime (r = 6, the sharp shot underexposed by r, both shots through a 4:2:0 JPEG) with cos⁴ vignetting in
// one shot, a form the detector does not assume. JPEG rings a small clipped highlight of B a few levels below full
// scale, where the seed's model predicts it far above: before B's code 254 (within twice its rounding of full scale) was
// treated as saturated (effect_problem.cpp, fullScaleMargin), this pair was named "clipping + vignetting" (a
// "plateau" at 254/255 held by one block); the same happened on a clean pair of the bench.
TEST(EffectAttribution, VignettingInAnUnderexposedJpegPairIsNotNamedClipping) {
  PlantingOptions po;
  po.effect = "vignetting";
  po.form = "held_out";
  po.strength = 1.5 * plantingThreshold("vignetting");
  po.ratio = 6.0;
  po.exposure /= po.ratio;
  po.seed = 4;
  const EffectReport report = diagnose(po, "CasioEX-Z55", 5, 1, 2, nullptr, 90);
  EXPECT_EQ(report.detected(), std::vector<std::string>{"vignetting"}) << report.summary();
  const EffectEntry* clipping = report.find("clipping");
  ASSERT_NE(clipping, nullptr);
  // 8-bit: twice the rounding's σ, so that the code 254 counts as saturated (effect_problem.cpp, fullScaleMargin)
  EXPECT_GT(clipping->parameters.at("full_scale_margin"), 0.5 / 255) << report.summary();
}

// The same regime without a planted effect: before, a "plateau" of B at 254/255 held by a few blocks (a small clipped
// highlight that JPEG decoded below full scale) was named clipping.
TEST(EffectAttribution, CleanUnderexposedJpegPairNamesNoEffect) {
  PlantingOptions po;
  po.ratio = 6.0;
  po.exposure /= po.ratio;
  po.seed = 4;
  const EffectReport report = diagnose(po, "CasioEX-Z55", 5, 1, 2, nullptr, 90);
  std::vector<std::string> named = report.detected();
  // signal-dependent noise is what the noise of an underexposed JPEG shot may really be (issue 18 leaves it aside)
  named.erase(std::remove(named.begin(), named.end(), "signal_dependent_noise"), named.end());
  EXPECT_TRUE(named.empty()) << report.summary();
}

// A clean real-regime pair (r = 8, the sharp shot underexposed by r with the bundled phone's ISO 800 noise, added to
// its irradiance before the curve as a sensor does; Sony A100 curve, Levin kernel 3, handheld, 4:2:0 JPEG; EXIF 4 %
// off the truth as every bench pair's). The effect search used to debias I's level functions with one intensity-domain
// σ although the base fit it tests does not: K ⊗ φ(I) fell where the sharp shot holds its darkest codes and this pair
// was named black_level_offset (its refit traded the offset for the exponent, r 3.05, and was rejected; before the
// full fit had to confirm it, exposure_ratio_mismatch too). The search now reads I's noise as the fit does
// (docs/RESULTS.md#effects-debias).
TEST(EffectAttribution, CleanRealRegimePairsDarkestCodesAreNotNamedAnOffset) {
  namespace fs = std::filesystem;
  test::TempDir dir;
  const std::string bin = test::crfcalBinary().string();
  const fs::path curves = samples() / "camera_curves";
  // Case 5 of this six-case bench (each case's noise and shift are seeded by its index).
  const auto made = test::run("'" + bin + "' bench pairs --pairs-only --regime real --ratio 8 --image '" +
                              (samples() / "effects" / "window.jpg").string() +
                              "' --kernel levin:1 --kernel levin:3 --kernel levin:8 --crf 'table:" +
                              (curves / "CanonPowerShotG9.csv").string() + "' --crf 'table:" +
                              (curves / "SonyDSLR-A100.csv").string() + "' --noise-profiles '" +
                              (samples() / "noise_profiles" / "noiseprofiles.json").string() + "' -o '" +
                              (dir / "pairs").string() + "'");
  ASSERT_EQ(made.exit_code, 0) << made.output;
  const fs::path pair = dir / "pairs" / "case5";
  const auto calibrated = test::run("'" + bin + "' calibrate '" + (pair / "sharp.jpg").string() + "' '" +
                                    (pair / "blurred.jpg").string() + "' --channels g --band-replicates 0 -o '" +
                                    (dir / "out").string() + "'");
  ASSERT_EQ(calibrated.exit_code, 0) << calibrated.output;
  std::ifstream truth_file(pair / "truth.json"), report_file(dir / "out" / "report.json");
  const nlohmann::json truth = nlohmann::json::parse(truth_file), report = nlohmann::json::parse(report_file);
  const double true_ratio = truth.at("exposure_ratio").get<double>();
  for (const auto& e : report.at("effects")) {
    const bool testable = e.at("name") != "channel_mixing" && e.at("name") != "spatially_varying_blur";  // G, kernel
    ASSERT_TRUE(e.at("tested").get<bool>() || !testable) << e.at("name");
    if (e.at("name") != "signal_dependent_noise") {
      EXPECT_FALSE(e.at("detected").get<bool>()) << e.dump();
    }
  }
  EXPECT_LE(std::abs(report.at("exposure_ratio").at("fitted").get<double>() / true_ratio - 1), 0.05)
      << calibrated.output;
}

// A camera colour matrix planted in the blurred shot (the held-out form) of a real-regime pair (r = 6, the seed's
// intensity noise in the sharp shot, 4:2:0 JPEG): the linearised model's scale a lies 47 % above EXIF and wins its
// held-out test, but the full fit of the seed's model started from a returns an r on EXIF's other side. Named, the
// mismatch would set EXIF aside and its refit would report a ratio the full fit does not support; it is withdrawn
// (docs/RESULTS.md#ratio-confirmed).
TEST(EffectAttribution, RatioMismatchOfTheLinearisedModelIsNotNamedWhenTheFullFitDisagrees) {
  cv::Mat photo = cv::imread((samples() / "effects" / "window.jpg").string());
  ASSERT_FALSE(photo.empty());
  PlantingOptions po;
  po.effect = "channel_mixing";
  po.strength = 1.5 * plantingThreshold("channel_mixing");
  po.form = "held_out";
  po.ratio = 6;
  po.exposure /= po.ratio;
  po.seed = 2;
  const ResponseModel truth = TableModel{io::readCurveTable(samples() / "camera_curves" / "NikonD70.csv")};
  const cv::Mat K = levinKernel(3);
  PlantedPair pair = plantEffect(photo, truth, K, po);
  pair.sharp = io::jpegRoundTrip(pair.sharp, 90);
  pair.blurred = io::jpegRoundTrip(pair.blurred, 90);
  CrfFitOptions fo;
  fo.nominal_ratio = pair.exif_ratio;
  EffectInputs in;
  in.channels = {"R", "G", "B"};
  std::vector<cv::Mat> sharp, blurred;
  cv::split(pair.sharp, sharp);
  cv::split(pair.blurred, blurred);
  for (int c = 0; c < 3; ++c) {  // BGR
    in.sharp[in.channels[c]] = sharp[2 - c];
    in.blurred[in.channels[c]] = blurred[2 - c];
    in.fits[in.channels[c]] = fitInverseCrf(sharp[2 - c], blurred[2 - c], K, fo);
  }
  in.kernel = K;
  in.kernel_estimated = false;
  in.nominal_ratio = pair.exif_ratio;
  in.fit = fo;
  const EffectReport report = diagnoseEffects(in);
  const auto ratio = std::find_if(report.entries.begin(), report.entries.end(),
                                  [](const EffectEntry& e) { return e.name == "exposure_ratio_mismatch"; });
  ASSERT_NE(ratio, report.entries.end());
  ASSERT_TRUE(ratio->tested) << report.summary();
  EXPECT_GT(std::abs(ratio->parameters.at("relative_difference")), 0.10)
      << "the linearised model's a must be off EXIF here, or the pair does not test the rule\n" << report.summary();
  EXPECT_FALSE(ratio->detected) << report.summary();
  ASSERT_EQ(ratio->parameters.count("full_fit_ratio"), 1u) << report.summary();
  const double full = ratio->parameters.at("full_fit_ratio") / pair.exif_ratio - 1;
  EXPECT_TRUE(std::abs(full) <= 0.10 || full * ratio->parameters.at("relative_difference") < 0) << report.summary();
  EXPECT_EQ(ratio->parameters.count("not_confirmed_by_full_fit"), 1u);
}

}  // namespace
}  // namespace crfcal
