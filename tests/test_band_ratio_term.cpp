// The band's ratio term (band_ratio_term.hpp): the σ of log r the half-sample refits cannot see, and φ's response to
// it, which makes the shape band cover a truth whose r error every half shares.
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/band_ratio_term.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/response_model.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {


TEST(BandRatioTerm, UnseenSigmaIsThePosteriorsLessWhatTheHalvesCarryScaledByTheEstimatesAgreement) {
  const RatioEvidence agree = test::combinedRatioEvidence(0.15, 0.03, 0.13, 0.0),
                      differ = test::combinedRatioEvidence(0.15, 0.03, 0.13, 0.4);
  RatioTermInputs combined{true, true, false};  // the a-priori σ, not scaled
  const double w = agree.images_weight, expected = std::sqrt(agree.log_sigma * agree.log_sigma - w * w * 0.03 * 0.03);
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(agree, combined), expected, 1e-12);
  combined.consistency_scale = true;  // scaled by S = |Δ| / σ_Δ: 0 for equal estimates, ≈ 2 for 0.4 apart
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(agree, combined), 0.0, 1e-12);
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(differ, combined), expected * 0.4 / std::hypot(0.15, 0.13), 1e-12);
  // The images' own r reported (no refit with the combination): the halves carry its resampled part, the floor is unseen.
  const RatioTermInputs own{false, false, false};
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(agree, own), std::sqrt(0.15 * 0.15 - 0.03 * 0.03), 1e-12);
  // A conflict arbitrated by the brightness: not scaled by the conflict it resolved.
  RatioEvidence held = differ;
  held.decision = RatioDecision::nominal_held;
  held.log_sigma = 0.13;
  held.images_weight = 0;
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(held, RatioTermInputs{true, true, true}), 0.13, 1e-12);
  EXPECT_EQ(ratioLogSigmaUnseenByHalves(RatioEvidence{}, combined), 0.0);  // no evidence combined: no term
}

// Shape coverage of the truth (after its best common scale onto φ) by φ ± half-width over [i0, i1].
double shapeCoverage(const std::vector<double>& phi, const std::vector<double>& truth,
                     const std::vector<double>& half_width, std::pair<double, double> covered) {
  const int n = static_cast<int>(phi.size());
  const int i0 = static_cast<int>(std::lround(covered.first * (n - 1)));
  const int i1 = static_cast<int>(std::lround(covered.second * (n - 1)));
  double num = 0, den = 0;
  for (int i = i0; i <= i1; ++i) num += phi[i] * truth[i], den += truth[i] * truth[i];
  int hits = 0;
  for (int i = i0; i <= i1; ++i) hits += std::abs(num / den * truth[i] - phi[i]) <= half_width[i];
  return double(hits) / (i1 - i0 + 1);
}

// A synthetic r = 4 pair whose reported r is held 15 % above the truth (an error every half-sample shares: the
// halves hold the same r). The sampling band misses the exponent shift that r's error puts into φ; with the ratio
// term for a σ of log r of that size the truth is covered.
TEST(BandRatioTerm, CoversTheShapeShiftOfARatioErrorTheHalvesShare) {
  const GammaModel truth_model{2.2};  // the pair's curve
  const cv::Mat kernel = test::levinKernel(3);
  const SimulationResult pair = test::gammaPairAtRatio4();
  CrfFitOptions held;
  held.fit_ratio = false;
  held.nominal_ratio = 4 * 1.15;
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, kernel, held);
  const std::pair<double, double> covered{fit.covered_levels.first / double(fit.levels - 1),
                                          fit.covered_levels.second / double(fit.levels - 1)};
  CrfFitOptions refit = held;  // the band's refit options: the chosen model from the fit, r held
  refit.model = fit.chosen == "ggcm" ? CrfModelChoice::ggcm : CrfModelChoice::emor;
  refit.start = CrfFitOptions::Start{fit.model, fit.ratio};
  CurveBandOptions options;
  options.replicates = 6;
  options.include_ratio_term = true;
  const CurveBand without = estimateCurveBand(pair.sharp, pair.blurred, kernel, refit, fit, covered, options);
  const CurveBand with = estimateCurveBand(pair.sharp, pair.blurred, kernel, refit, fit, covered, options,
                                           std::nullopt, std::log(1.15));
  std::vector<double> truth(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) truth[i] = evaluateInverse(truth_model, double(i) / (kCurveSamples - 1));
  ASSERT_EQ(with.ratio_half_width.size(), truth.size());
  EXPECT_TRUE(without.ratio_half_width.empty());
  const double coverage_without = shapeCoverage(fit.inverse_crf, truth, without.shape_half_width, covered);
  const double coverage_with = shapeCoverage(fit.inverse_crf, truth, with.shape_half_width, covered);
  EXPECT_LT(coverage_without, 0.6) << "the sampling band alone cannot see r's common error";
  EXPECT_GT(coverage_with, 0.85);
  options.include_ratio_term = false;  // the option switches it off
  EXPECT_TRUE(estimateCurveBand(pair.sharp, pair.blurred, kernel, refit, fit, covered, options, std::nullopt,
                                std::log(1.15)).ratio_half_width.empty());
}

}  // namespace
}  // namespace crfcal
