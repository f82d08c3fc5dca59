// The pointwise band of φ (curve_band.hpp): its coverage, the report's keys, compare's band statistic and export's
// --band option.
#include <cmath>
#include <fstream>
#include <random>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "crfcal/curve_band.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/band_report.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/response_model.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

namespace fs = std::filesystem;

std::vector<double> gammaCurve(double gamma, int n = kCurveSamples) {
  std::vector<double> v(n);
  for (int i = 0; i < n; ++i) v[i] = std::pow(double(i) / (n - 1), gamma);
  return v;
}

// A smooth random error of the estimator: a few low-frequency sines of standard deviation `sigma` each.
std::vector<double> smoothError(std::mt19937_64& rng, double sigma, int n = kCurveSamples) {
  std::normal_distribution<double> normal(0, sigma);
  std::vector<double> e(n, 0.0);
  for (int k = 1; k <= 3; ++k) {
    const double a = normal(rng);
    for (int i = 0; i < n; ++i) e[i] += a * std::sin(k * M_PI * double(i) / (n - 1)) / std::sqrt(3.0);
  }
  return e;
}

// Coverage of the shape band when the estimator's error and the half-samples' deviations have the spread the band
// assumes: about the nominal 90 %; when the replicates understate the spread threefold, far below it (the test
// can fail).
double shapeCoverage(double replicate_spread_factor) {
  std::mt19937_64 rng(7);
  const std::vector<double> truth = gammaCurve(2.2);
  CurveBandOptions options;
  options.include_model_spread = false;
  int hits = 0, samples = 0;
  for (int trial = 0; trial < 200; ++trial) {
    std::vector<double> fit = truth;
    const auto error = smoothError(rng, 0.004);
    for (int i = 0; i < kCurveSamples; ++i) fit[i] += error[i];
    std::vector<std::vector<double>> replicates;
    for (int r = 0; r < 8; ++r) {  // Var(half − full) = Var(full) for half-samples
      auto rep = fit;
      const auto e = smoothError(rng, 0.004 * replicate_spread_factor);
      for (int i = 0; i < kCurveSamples; ++i) rep[i] += e[i];
      replicates.push_back(rep);
    }
    const CurveBand band = bandFromReplicates(fit, replicates, {0.1, 0.9}, options);
    const BandScore score = scoreBand(band, fit, truth);
    hits += score.shape_hits;
    samples += score.inside;
  }
  return double(hits) / samples;
}

TEST(CurveBand, ShapeBandCoversAtTheNominalRateAndFailsWhenTheSpreadIsUnderstated) {
  const double nominal = shapeCoverage(1.0);
  EXPECT_GT(nominal, 0.84);
  EXPECT_LT(nominal, 0.97);
  EXPECT_LT(shapeCoverage(1.0 / 3), 0.6);
}

// The verdict's reading of a band (medianShapeSigma): the median half-width over the covered range divided by the
// band's t quantile, so it scales with the replicates' spread and is 0 without one; the benches' median width is
// twice the same median.
CurveBand bandWithSpread(double amplitude) {
  const std::vector<double> fit = gammaCurve(2.2);
  CurveBandOptions options;
  options.include_model_spread = false;
  std::vector<std::vector<double>> replicates;
  for (int r = 0; r < 8; ++r) {
    auto rep = fit;
    const double sign = r % 2 ? 1.0 : -1.0, k = 1 + r / 2;  // four shapes, each with both signs
    for (int i = 0; i < kCurveSamples; ++i) rep[i] += sign * amplitude * std::sin(k * M_PI * i / (kCurveSamples - 1));
    replicates.push_back(rep);
  }
  return bandFromReplicates(fit, replicates, {0.25, 0.75}, options);
}

TEST(CurveBand, MedianShapeSigmaScalesWithTheReplicatesSpread) {
  const CurveBand narrow = bandWithSpread(0.003), wide = bandWithSpread(0.012);
  EXPECT_GT(medianShapeSigma(narrow), 0.0005);
  EXPECT_LT(medianShapeSigma(narrow), 0.003);
  EXPECT_NEAR(medianShapeSigma(wide) / medianShapeSigma(narrow), 4.0, 0.1);
  EXPECT_NEAR(medianShapeHalfWidth(wide) / medianShapeSigma(wide), studentQuantile(0.95, 8), 1e-12);
  const std::vector<double> fit = gammaCurve(2.2);
  EXPECT_DOUBLE_EQ(scoreBand(wide, fit, fit).median_shape_width_inside, 2 * medianShapeHalfWidth(wide));
  EXPECT_EQ(medianShapeSigma(bandWithSpread(0)), 0.0);
  // With the images-alone spread (r combined with EXIF), the verdict reads that one; the band keeps its own width.
  CurveBand combined = narrow;
  combined.images_ratio_half_width = wide.shape_half_width;
  EXPECT_DOUBLE_EQ(medianShapeSigma(combined), medianShapeSigma(wide));
  EXPECT_DOUBLE_EQ(medianShapeHalfWidth(combined), medianShapeHalfWidth(narrow));
  EXPECT_EQ(medianShapeSigma(CurveBand{}), 0.0);
}

TEST(CurveBand, AboveTheDataTheBandBoundsTheExponentAndHoldsTheFit) {
  const std::vector<double> phi = gammaCurve(2.2);
  const CurveBand band = bandFromReplicates(phi, {}, {0.05, 0.6});
  ASSERT_EQ(band.lower.size(), 1024u);
  for (int i = 0; i < 1024; ++i) {
    EXPECT_LE(band.lower[i], phi[i] + 1e-12) << i;
    EXPECT_GE(band.upper[i], phi[i] - 1e-12) << i;
    if (i > 0) {
      EXPECT_GE(band.lower[i], band.lower[i - 1]) << i;
    }
  }
  EXPECT_EQ(band.lower[1023], 1.0);
  // x = 0.8 above the data: between x^g_hi and x^g_lo, with g_lo = 1 (straightening) and g_hi = 4.4 (2 × 2.2).
  const int i = 818;
  const double x = i / 1023.0;
  EXPECT_NEAR(band.upper[i], x, 0.02);
  EXPECT_NEAR(band.lower[i], std::pow(x, 4.4), 0.02);
  // The scale inside the covered range: the truth may be anywhere between those extrapolations.
  EXPECT_LT(band.scale_range.first, 1.0);
  EXPECT_GT(band.scale_range.second, 1.0);
  // A curve with data up to x = 1 has no scale freedom.
  EXPECT_EQ(bandFromReplicates(phi, {}, {0.05, 1.0}).scale_range.second, 1.0);
  EXPECT_THROW(bandFromReplicates(phi, {}, {0.7, 0.6}), InvalidInput);
  CurveBandOptions odd;
  odd.replicates = 3;
  EXPECT_THROW(odd.check(), InvalidInput);
}

// The score counts the samples above the data in two halves, so that misses piled up near x = 1 show beside a
// pooled rate that a long stretch of easy samples near the data can dilute.
TEST(CurveBand, ScoreSplitsTheSamplesAboveTheDataIntoTheNearerAndTheFartherHalf) {
  const std::vector<double> phi = gammaCurve(2.2);
  const CurveBand band = bandFromReplicates(phi, {}, {0.05, 0.6});
  std::vector<double> truth = phi;
  BandScore score = scoreBand(band, phi, truth);
  ASSERT_GT(score.above, 100);
  EXPECT_LE(std::abs(2 * score.above_far - score.above), 1);
  EXPECT_EQ(score.above_hits, score.above);
  EXPECT_EQ(score.above_far_hits, score.above_far);
  // the truth below the band's lower limit at every sample of the farther half only
  const int n = static_cast<int>(phi.size());
  for (int i = n - score.above_far; i < n; ++i) truth[i] = band.lower[i] - 0.01;
  score = scoreBand(band, phi, truth);
  EXPECT_EQ(score.above_far_hits, 0);
  EXPECT_EQ(score.above_hits, score.above - score.above_far);
}

// The whole estimate on a small noisy synthetic pair whose data stop at x ≈ 0.58: the truth lies inside the band
// at about the nominal rate or more (the part above the data is a bound), and the band is not the trivial [0, 1].
TEST(CurveBand, SyntheticPairBandContainsTheTruth) {
  const GammaModel truth_model{2.2};
  cv::Mat image = test::levinImage(2) * 0.3;  // irradiance up to 0.3: intensities up to 0.3^(1/2.2) ≈ 0.58
  SimulationOptions sim;
  sim.noise_variance = 0.0005;
  const SimulationResult pair = simulatePair(image, truth_model, test::levinKernel(3), sim);
  CrfFitOptions fit_options;
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), fit_options);
  const std::pair<double, double> covered{fit.covered_levels.first / double(fit.levels - 1),
                                          fit.covered_levels.second / double(fit.levels - 1)};
  ASSERT_LT(covered.second, 0.7);
  CurveBandOptions options;
  options.replicates = 6;
  const CurveBand band = estimateCurveBand(pair.sharp, pair.blurred, test::levinKernel(3), fit_options, fit, covered,
                                           options);
  EXPECT_EQ(band.replicates + band.failed_replicates, 6);
  const BandScore score = scoreBand(band, fit.inverse_crf, sampleInverse(truth_model));
  EXPECT_GE(double(score.inside_hits) / score.inside, 0.85) << band.summary();
  EXPECT_GE(double(score.above_hits) / score.above, 0.85) << band.summary();
  EXPECT_LT(score.median_width_inside, 0.3) << band.summary();
}

TEST(CurveBand, ReplicateRatioRuleCombinesEachHalfsRatioAsThePairDid) {
  const ReplicateRatioRule rule{0.6, 3.8, 4.1};
  EXPECT_DOUBLE_EQ(rule.heldRatio(3.8), 4.1);  // the whole pair's images: the reported r
  EXPECT_NEAR(std::log(rule.heldRatio(3.8 * std::exp(0.05)) / 4.1), 0.6 * 0.05, 1e-12);  // w times the half's move
  EXPECT_DOUBLE_EQ((ReplicateRatioRule{0.0, 3.8, 4.1}.heldRatio(2.0)), 4.1);  // r held at EXIF: no spread of r
  EXPECT_THROW((ReplicateRatioRule{1.5, 3.8, 4.1}.check()), InvalidInput);
}

// Mean and root-mean-square of the half-sample refits' deviation from the reported φ (each after its best common
// scale over the covered range), averaged over the covered samples.
std::pair<double, double> replicateDeviation(const std::vector<double>& phi, const HalfSampleRefits& refits,
                                             std::pair<double, double> covered) {
  const int n = static_cast<int>(phi.size());
  const int i0 = static_cast<int>(covered.first * (n - 1)), i1 = static_cast<int>(covered.second * (n - 1));
  double mean_abs = 0, rms = 0;
  for (int i = i0; i <= i1; ++i) {
    double sum = 0, sum_squares = 0;
    for (const auto& rep : refits.curves) {
      double num = 0, den = 0;
      for (int k = i0; k <= i1; ++k) num += phi[k] * rep[k], den += rep[k] * rep[k];
      const double d = num / den * rep[i] - phi[i];
      sum += d, sum_squares += d * d;
    }
    mean_abs += std::abs(sum / refits.curves.size());
    rms += std::sqrt(sum_squares / refits.curves.size());
  }
  return {mean_abs / (i1 - i0 + 1), rms / (i1 - i0 + 1)};
}

// The property the shape band rests on: the half-sample refits deviate from the reported φ by the sampling error
// alone, centred on it (then Var(half − full) ≈ Var(full)). When the reported r combines the images' r with EXIF
// (here 5 % above the images', weight 0.5), halves that keep their own r all sit at the images' r and deviate from
// the reported curve by the same exponent shift: a bias that inflated the band (99 % coverage at r = 4, 8 on
// `bench pairs`). With the rule each half combines its own r the same way and the refits are centred again.
TEST(CurveBand, HalfSampleRefitsRunTheReportedRatioEstimatorAndAreCentredOnIt) {
  const cv::Mat kernel = test::levinKernel(3);
  const SimulationResult pair = test::gammaPairAtRatio4();
  CrfFitOptions free_ratio;
  free_ratio.nominal_ratio = 4;
  const CrfFitResult images = fitInverseCrf(pair.sharp, pair.blurred, kernel, free_ratio);
  const double reported_ratio = images.ratio * 1.05;  // images' r 0.5, EXIF 0.5 with EXIF at images' × 1.05²
  CrfFitOptions held = free_ratio;
  held.fit_ratio = false;
  held.nominal_ratio = reported_ratio;
  const CrfFitResult reported = fitInverseCrf(pair.sharp, pair.blurred, kernel, held);
  const std::pair<double, double> covered{reported.covered_levels.first / double(reported.levels - 1),
                                          reported.covered_levels.second / double(reported.levels - 1)};
  CrfFitOptions refit = free_ratio;  // as the band stage: the halves fit r, from the reported fit
  refit.nominal_ratio = reported_ratio;
  refit.model = reported.chosen == "ggcm" ? CrfModelChoice::ggcm : CrfModelChoice::emor;
  refit.start = CrfFitOptions::Start{reported.model, reported_ratio};
  const ReplicateRatioRule rule{0.5, images.ratio, reported_ratio};
  const HalfSampleRefits own = refitOnHalfSamples(pair.sharp, pair.blurred, kernel, refit, reported.pixels.used_mask,
                                                  6, 32, 1);
  const HalfSampleRefits combined = refitOnHalfSamples(pair.sharp, pair.blurred, kernel, refit,
                                                       reported.pixels.used_mask, 6, 32, 1, rule);
  ASSERT_EQ(own.curves.size(), 6u);
  ASSERT_EQ(combined.curves.size(), 6u);
  double mean_log_own = 0, mean_log_combined = 0;
  for (int k = 0; k < 6; ++k) {
    mean_log_own += std::log(own.ratios[k] / reported_ratio) / 6;
    mean_log_combined += std::log(combined.ratios[k] / reported_ratio) / 6;
    EXPECT_NEAR(combined.ratios[k], rule.heldRatio(combined.images_ratios[k]), 1e-9);
  }
  EXPECT_LT(mean_log_own, -0.03);  // the halves' own r: the images', 5 % below the reported
  EXPECT_LT(std::abs(mean_log_combined), 0.01);
  const auto [mean_own, rms_own] = replicateDeviation(reported.inverse_crf, own, covered);
  const auto [mean_combined, rms_combined] = replicateDeviation(reported.inverse_crf, combined, covered);
  EXPECT_GT(mean_own, 0.8 * rms_own) << "own r: the deviation is a common shift";
  EXPECT_LT(mean_combined, 0.7 * rms_combined) << "combined r: centred";
  EXPECT_LT(rms_combined, 0.5 * rms_own);
}

io::CalibrationReport reportWithBand(double gamma, double half_width) {
  io::CalibrationReport report;
  report.command = "calibrate";
  report.inverse_crf["G"] = gammaCurve(gamma);
  report.covered_range["G"] = {0.1, 0.9};
  CurveBand band = bandFromReplicates(report.inverse_crf["G"], {}, {0.1, 0.9});
  band.shape_half_width.assign(kCurveSamples, half_width);
  report.extra["inverse_crf_band"] = io::curveBandsJson({{"G", band}});
  return report;
}

TEST(CurveBand, BandAgreementStatistic) {
  const auto a = reportWithBand(2.2, 0.01), b = reportWithBand(2.2, 0.01), c = reportWithBand(1.8, 0.01);
  const auto bands_a = io::readCurveBands(a), bands_c = io::readCurveBands(c);
  ASSERT_EQ(bands_a.count("G"), 1u);
  const BandAgreement same =
      bandAgreement(a.inverse_crf.at("G"), &bands_a.at("G"), b.inverse_crf.at("G"), &bands_a.at("G"), {0.1, 0.9}, 1);
  EXPECT_EQ(same.fraction_within, 1.0);
  EXPECT_NEAR(same.mean_z2, 0.0, 1e-12);
  EXPECT_GT(same.samples, 800);
  const BandAgreement differ =
      bandAgreement(a.inverse_crf.at("G"), &bands_a.at("G"), c.inverse_crf.at("G"), &bands_c.at("G"), {0.1, 0.9}, 1);
  EXPECT_LT(differ.fraction_within, 0.3);
  EXPECT_GT(differ.mean_z2, 10.0);
}

TEST(CurveBand, CompareAndExportUseTheBand) {
  test::TempDir dir;
  io::writeReport(dir / "a.json", reportWithBand(2.2, 0.01));
  io::writeReport(dir / "b.json", reportWithBand(2.0, 0.01));
  const std::string bin = test::crfcalBinary().string();
  auto r = test::run(bin + " compare " + (dir / "a.json").string() + " " + (dir / "b.json").string() + " -o " +
                     (dir / "cmp").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("within the combined 90 % band"), std::string::npos) << r.output;
  std::ifstream in(dir / "cmp" / "compare.json");
  const auto json = nlohmann::json::parse(in);
  const auto& g = json["channels"][0]["band_agreement"];
  EXPECT_GE(g["fraction_within"].get<double>(), 0.0);
  EXPECT_LE(g["fraction_within"].get<double>(), 1.0);
  EXPECT_GT(g["mean_z2"].get<double>(), 0.0);

  r = test::run(bin + " export " + (dir / "a.json").string() + " --band upper -o " + (dir / "upper.csv").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  r = test::run(bin + " export " + (dir / "a.json").string() + " -o " + (dir / "curve.csv").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream upper(dir / "upper.csv"), curve(dir / "curve.csv");
  const std::string upper_text((std::istreambuf_iterator<char>(upper)), {}), curve_text((std::istreambuf_iterator<char>(curve)), {});
  EXPECT_NE(upper_text, curve_text);
  // A report without a band: one line naming it, non-zero exit, nothing written.
  io::CalibrationReport plain = reportWithBand(2.2, 0.01);
  plain.extra.erase("inverse_crf_band");
  io::writeReport(dir / "plain.json", plain);
  r = test::run(bin + " export " + (dir / "plain.json").string() + " --band lower -o " + (dir / "x.csv").string());
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.output.find("no band"), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(dir / "x.csv"));
}

// calibrate writes the band: "inverse_crf_band" with 1024-sample limits per channel and the covered range.
TEST(CurveBand, CalibrateReportHasTheBand) {
  const fs::path pair = test::samples() / "pairs";
  ASSERT_TRUE(fs::exists(pair / "sharp.jpg"));
  test::TempDir dir;
  const auto r = test::run(test::crfcalBinary().string() + " calibrate -q " + (pair / "sharp.jpg").string() + " " +
                           (pair / "blurred.jpg").string() + " --channels g --rounds 0 --no-effects --band-replicates 4 "
                           "--kernel " + (test::samples() / "levin09" / "kernel03.txt").string() + " -o " +
                           (dir / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  ASSERT_TRUE(report.contains("inverse_crf_band")) << report.dump().substr(0, 400);
  const auto& g = report["inverse_crf_band"]["G"];
  EXPECT_EQ(g["lower"].size(), 1024u);
  EXPECT_EQ(g["upper"].size(), 1024u);
  EXPECT_EQ(g["replicates"].get<int>() + g["failed_replicates"].get<int>(), 4);
  ASSERT_TRUE(report["covered_range"].contains("G"));
  for (size_t i = 0; i < 1024; ++i) {
    EXPECT_LE(g["lower"][i].get<double>(), report["inverse_crf"]["G"][i].get<double>() + 1e-12);
    EXPECT_GE(g["upper"][i].get<double>(), report["inverse_crf"]["G"][i].get<double>() - 1e-12);
  }
  // Above the data the band is the learned prior's (the ten bundled camera curves) unless --band-above bounds.
  EXPECT_EQ(g["above_data"]["kind"], "learned_prior");
  EXPECT_EQ(g["above_data"]["training_curves"], 10);
}

TEST(CurveBand, CalibrateBandAboveBoundsKeepsTheExponentBoundsAndIsWiderAboveTheData) {
  const fs::path pair = test::samples() / "pairs";
  test::TempDir dir;
  nlohmann::json bands[2];
  const char* kinds[] = {"learned", "bounds"};
  for (int k = 0; k < 2; ++k) {
    const fs::path out = dir / kinds[k];
    const auto r = test::run(test::crfcalBinary().string() + " calibrate -q " + (pair / "sharp.jpg").string() + " " +
                             (pair / "blurred.jpg").string() + " --channels g --rounds 0 --no-effects "
                             "--band-replicates 2 --band-above " + kinds[k] + " --kernel " +
                             (test::samples() / "levin09" / "kernel03.txt").string() + " -o " + out.string());
    ASSERT_EQ(r.exit_code, 0) << r.output;
    std::ifstream in(out / "report.json");
    bands[k] = nlohmann::json::parse(in)["inverse_crf_band"]["G"];
  }
  EXPECT_EQ(bands[1]["above_data"]["kind"], "exponent_bounds");
  ASSERT_EQ(bands[1]["above_data"]["exponent"].size(), 2u);
  // Above the covered range the bounds (x^g_hi .. x^g_lo) are wider on average than the prior's 90 % spread.
  const double top = bands[0]["covered"][1].get<double>();
  double width[2] = {0, 0};
  int samples = 0;
  for (int i = 0; i < 1024; ++i) {
    if (i / 1023.0 <= top) continue;
    ++samples;
    for (int k = 0; k < 2; ++k) width[k] += bands[k]["upper"][i].get<double>() - bands[k]["lower"][i].get<double>();
  }
  ASSERT_GT(samples, 10) << "the bundled pair's data reach x = " << top;
  EXPECT_LT(width[0], width[1]);
}

}  // namespace
}  // namespace crfcal
