// Issue 20: JPEG chroma subsampling in the pair model (chroma_subsampling.hpp, CrfFitOptions::sharp_error_bound).
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "crfcal/chroma_subsampling.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// Left half grey 60, right half grey 200 (a luma edge), except rows 40..79 where a red | blue edge runs through the
// middle of a 2×2 block (column 33).
cv::Mat edgesImage() {
  cv::Mat bgr(80, 64, CV_8UC3, cv::Scalar(60, 60, 60));
  bgr(cv::Rect(32, 0, 32, 40)).setTo(cv::Scalar(200, 200, 200));
  bgr(cv::Rect(0, 40, 33, 40)).setTo(cv::Scalar(40, 40, 200));   // red (BGR)
  bgr(cv::Rect(33, 40, 31, 40)).setTo(cv::Scalar(200, 40, 40));  // blue
  return bgr;
}

TEST(ChromaErrorBound, ZeroWithoutSubsamplingAndOnLumaEdges) {
  const cv::Mat bgr = edgesImage();
  for (const char* channel : {"R", "G", "B"}) EXPECT_EQ(cv::countNonZero(chromaErrorBound(bgr, {1, 1}, channel)), 0);
  const cv::Mat bound = chromaErrorBound(bgr, {2, 2}, "B");
  double grey_max = 0, colour_max = 0;
  cv::minMaxLoc(bound(cv::Rect(0, 0, 64, 30)), nullptr, &grey_max);      // the grey edge, away from the colours
  cv::minMaxLoc(bound(cv::Rect(28, 50, 10, 20)), nullptr, &colour_max);  // the red | blue edge
  EXPECT_LT(grey_max, 1e-6);  // grey: no chroma at all (float rounding only)
  EXPECT_GT(colour_max, 100.0 / 255);  // B jumps by 160 levels there
  EXPECT_THROW(chromaErrorBound(bgr, {2, 2}, "X"), InvalidInput);
}

// A level bin the bound empties (fewer than 5 % kept) keeps the 25 % of its candidates with the smallest bound; a
// bin keeping more keeps the plain threshold; non-candidates are never marked.
TEST(ChromaExclusion, EmptiedLevelBinKeepsLeastAffectedPixels) {
  cv::Mat level(10, 20, CV_64F), bound(10, 20, CV_64F);
  for (int y = 0; y < 10; ++y)
    for (int x = 0; x < 20; ++x) {
      level.at<double>(y, x) = x < 10 ? 0.2 : 0.9;  // two level bins
      // left: half the bin under the threshold; right: every pixel above it, all bounds distinct
      bound.at<double>(y, x) = x < 10 ? (x < 5 ? 0.0 : 1.0) : 0.5 + 0.01 * (x - 10) + 0.001 * y;
    }
  cv::Mat candidates(10, 20, CV_8U, cv::Scalar(255));
  candidates(cv::Rect(0, 0, 20, 1)).setTo(0);  // row 0: not usable
  const cv::Mat plain = excludedByErrorBound(bound, level, candidates, 0.1, LevelFloor{16, 0.0, 0.25});
  EXPECT_EQ(cv::countNonZero(plain), 9 * 5 + 9 * 10);  // no floor: every candidate above 0.1
  const cv::Mat floored = excludedByErrorBound(bound, level, candidates, 0.1);
  EXPECT_EQ(cv::countNonZero(floored(cv::Rect(0, 0, 10, 10))), 9 * 5);  // left bin not emptied: plain threshold
  const int kept_right = 90 - cv::countNonZero(floored(cv::Rect(10, 0, 10, 10)));
  EXPECT_EQ(kept_right, 23);                        // ceil(0.25 × 90)
  EXPECT_EQ(floored.at<std::uint8_t>(1, 10), 0);    // the smallest bound of the bin is kept
  EXPECT_EQ(floored.at<std::uint8_t>(9, 19), 255);  // the largest is not
  EXPECT_EQ(cv::countNonZero(floored.row(0)), 0);
  EXPECT_THROW(excludedByErrorBound(bound, level, candidates, 0.1, LevelFloor{16, 0.05, 1.5}), InvalidInput);
}

// The choice between the chroma model's fit and the pointwise one compares them by their best scale over the range
// both cover: outside it the curves may differ arbitrarily; no common range or different samplings throw.
TEST(ChromaChoice, RelativeScaleOverTheCommonRangeOnly) {
  std::vector<double> pointwise(1024), modelled(1024);
  for (int i = 0; i < 1024; ++i) {
    pointwise[i] = std::pow(i / 1023.0, 2.2);
    modelled[i] = i < 100 || i > 900 ? 1.0 : 1.2 * pointwise[i];  // 1.2× inside, anything outside
  }
  EXPECT_NEAR(relativeCurveScale(modelled, {100, 950}, pointwise, {50, 900}), 1.2, 1e-12);
  EXPECT_GT(std::abs(relativeCurveScale(modelled, {0, 1023}, pointwise, {0, 1023}) - 1.2), 0.01);  // outside counted
  EXPECT_NEAR(relativeCurveScale(pointwise, {0, 1023}, pointwise, {0, 1023}), 1.0, 1e-12);
  EXPECT_THROW(relativeCurveScale(modelled, {600, 900}, pointwise, {100, 500}), InvalidInput);  // nothing in common
  EXPECT_THROW(relativeCurveScale(modelled, {0, 0}, pointwise, {0, 0}), InvalidInput);          // φ(0) = 0 only
  EXPECT_THROW(relativeCurveScale(std::vector<double>(512, 0.5), {0, 511}, pointwise, {0, 1023}), InvalidInput);
  EXPECT_THROW((ChromaModelChoice{true, 0.0}.check()), InvalidInput);
}

std::vector<double> demoTruth() {
  std::ifstream in(test::samples() / "pairs" / "truth.json");
  return nlohmann::json::parse(in).at("inverse_crf").get<std::vector<double>>();
}

PairCalibrationResult calibrateDemo(const io::LoadedPair& pair, ChromaSubsampling sharp_chroma,
                                    ChromaModelChoice choice = {}) {
  PairCalibrationOptions options;
  options.chroma_choice = choice;
  options.fit.nominal_ratio = pair.exif_ratio->ratio();
  options.effects.enabled = false;
  options.sharp_chroma = sharp_chroma;
  return calibratePair(pair.sharp.image, pair.blurred.image, options);
}

// The demo pair (OpenCV JPEG 4:2:0, one true curve for all channels): with the chroma model, read from the file, B's
// curve is much closer to the truth than with the pointwise model; 4:4:4 keeps the pointwise model exactly.
TEST(ChromaModel, SubsampledSharpShotBlueCurveCloserToTruth) {
  const io::LoadedPair pair = io::loadPair(test::samples() / "pairs" / "sharp.jpg", test::samples() / "pairs" / "blurred.jpg");
  ASSERT_EQ(pair.sharp.chroma_block_h, 2);
  ASSERT_EQ(pair.sharp.chroma_block_v, 2);
  const std::vector<double> truth = demoTruth();
  const PairCalibrationResult pointwise = calibrateDemo(pair, {1, 1});
  const PairCalibrationResult modelled = calibrateDemo(pair, {pair.sharp.chroma_block_h, pair.sharp.chroma_block_v});
  EXPECT_TRUE(pointwise.chroma_model_channels.empty());
  for (const auto& [name, fit] : pointwise.fits) EXPECT_EQ(fit.pixels.unmodelled, 0) << name;
  EXPECT_EQ(modelled.chroma_model_channels, (std::vector<std::string>{"R", "B"}));
  // G is fitted as before
  EXPECT_EQ(modelled.fits.at("G").inverse_crf, pointwise.fits.at("G").inverse_crf);
  const double b_pointwise = curveRmse(pointwise.fits.at("B").inverse_crf, truth);
  const double b_modelled = curveRmse(modelled.fits.at("B").inverse_crf, truth);
  const double g = curveRmse(modelled.fits.at("G").inverse_crf, truth);
  EXPECT_GT(b_pointwise, 0.08);  // the misfit the model removes (0.133 measured)
  EXPECT_LT(b_modelled, 0.04);   // 0.024 measured; JPEG 4:4:4 of the same pair gives 0.023
  EXPECT_LT(g, 0.01);
  EXPECT_GT(modelled.fits.at("B").pixels.unmodelled, 0);
  // The choice: both channels' modelled fits lie above their pointwise ones (measured R 1.01, B 1.55), so both keep
  // the model; asked for more than B's scale, both fall back to exactly the pointwise fits.
  EXPECT_TRUE(pointwise.chroma_model_scale.empty());
  ASSERT_EQ(modelled.chroma_model_scale.size(), 2u);
  EXPECT_GT(modelled.chroma_model_scale.at("B"), 1.3);
  EXPECT_GT(modelled.chroma_model_scale.at("R"), 1.0);
  const PairCalibrationResult refused =
      calibrateDemo(pair, {pair.sharp.chroma_block_h, pair.sharp.chroma_block_v}, ChromaModelChoice{true, 5.0});
  EXPECT_TRUE(refused.chroma_model_channels.empty());
  for (const char* name : {"R", "G", "B"})
    EXPECT_EQ(refused.fits.at(name).inverse_crf, pointwise.fits.at(name).inverse_crf) << name;
  EXPECT_EQ(refused.chroma_model_scale.at("B"), modelled.chroma_model_scale.at("B"));
}

// The chroma check's replacement (PairCalibrationOptions::replace_chroma_biased_fits, docs/RESULTS.md#chroma-replace)
// on the demo pair, fitted pointwise with its stored 4:2:0 sampling known: B's pointwise fit differs in shape from its
// fit where the chroma is flat and lies below it, so that fit is reported (close to the truth); R's does not differ,
// so R stays pointwise; G is untouched. Off, or asked for more than the flat fit's ambiguity rise, B stays pointwise
// and its verdict says why.
TEST(ChromaCheck, BiasedBlueIsReplacedByItsFlatChromaFitUnlessOffOrItsExponentIsFree) {
  const std::filesystem::path pairs = test::samples() / "pairs";
  const io::LoadedPair pair = io::loadPair(pairs / "sharp.jpg", pairs / "blurred.jpg");
  const std::vector<double> truth = demoTruth();
  const auto run = [&pair](bool replace, double min_rise) {
    PairCalibrationOptions options;
    options.fit.nominal_ratio = pair.exif_ratio->ratio();
    options.effects.enabled = false;
    options.sharp_stored_chroma = {pair.sharp.chroma_block_h, pair.sharp.chroma_block_v};
    options.replace_chroma_biased_fits = replace;
    options.chroma_replacement_min_ambiguity_rise = min_rise;
    return calibratePair(pair.sharp.image, pair.blurred.image, options);
  };
  const double default_rise = PairCalibrationOptions{}.chroma_replacement_min_ambiguity_rise;
  const PairCalibrationResult replaced = run(true, default_rise);
  const PairCalibrationResult off = run(false, default_rise);
  const PairCalibrationResult refused = run(true, 1e6);
  EXPECT_EQ(replaced.chroma_model_channels, (std::vector<std::string>{"B"}));
  EXPECT_TRUE(off.chroma_model_channels.empty());
  EXPECT_TRUE(refused.chroma_model_channels.empty());
  EXPECT_GT(replaced.fits.at("B").pixels.unmodelled, 0);
  for (const char* name : {"R", "G"})
    EXPECT_EQ(replaced.fits.at(name).inverse_crf, off.fits.at(name).inverse_crf) << name;
  EXPECT_EQ(refused.fits.at("B").inverse_crf, off.fits.at("B").inverse_crf);
  const double b_off = curveRmse(off.fits.at("B").inverse_crf, truth);
  const double b_replaced = curveRmse(replaced.fits.at("B").inverse_crf, truth);
  EXPECT_GT(b_off, 0.08);       // 0.133 measured
  EXPECT_LT(b_replaced, 0.04);  // 0.024 measured
  const auto reasons = [](const PairCalibrationResult& r) {
    std::string all;
    for (const auto& s : r.verdicts.at("B").reasons) all += s + "\n";
    return all;
  };
  EXPECT_NE(reasons(replaced).find("fitted where the sharp shot's subsampled chroma is flat"), std::string::npos)
      << reasons(replaced);
  EXPECT_EQ(off.verdicts.at("B").level, VerdictLevel::weak);
  EXPECT_EQ(reasons(off).find("does not fix the curve's exponent"), std::string::npos) << reasons(off);
  EXPECT_EQ(refused.verdicts.at("B").level, VerdictLevel::weak);
  EXPECT_NE(reasons(refused).find("does not fix the curve's exponent by itself"), std::string::npos)
      << reasons(refused);
  PairCalibrationOptions bad;
  bad.chroma_replacement_min_ambiguity_rise = -1;
  EXPECT_THROW(bad.check(), InvalidInput);
}

}  // namespace
}  // namespace crfcal
