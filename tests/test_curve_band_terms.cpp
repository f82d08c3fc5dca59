// The band's terms for what every half-sample shares (curve_band.hpp, band_ratio_term.hpp): the ratio term with σ
// from the estimates' disagreement (RatioTermSigma::disagreement: EXIF's stated σ believed, the images' σ from how
// far their r lies from EXIF), the offset term at r = 1 (offsetTermHalfWidth) and the prior term
// (priorTermHalfWidth).
#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/band_ratio_term.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

constexpr double kZ90 = 1.6448536269514722;  // the normal quantile of a 90 % band

RatioTermInputs disagreementInputs() {
  RatioTermInputs inputs;
  inputs.reported_from_evidence = true;
  inputs.halves_combine = true;
  inputs.sigma = RatioTermSigma::disagreement;
  return inputs;
}

TEST(BandRatioDisagreement, ImagesWithinExifsSigmaAreTakenAsRightAndTheTermIsThePullTowardsExif) {
  // |Δ| = 0.04 < σ_nominal = 0.13: the images' σ is their resampled spread (0.01), their weight ŵ ≈ 1, so the
  // reported combination's error is its pull towards EXIF, (ŵ − w)·Δ, plus the spread the halves do not carry.
  const RatioEvidence e = test::combinedRatioEvidence(0.10, 0.01, 0.13, -0.04);
  const double vi = 0.01 * 0.01, vn = 0.13 * 0.13, w_hat = vn / (vi + vn), w = e.images_weight;
  const double shift = std::abs((w - w_hat) * -0.04);
  const double spread = std::sqrt(std::max(0.0, vi * vn / (vi + vn) - w * w * vi));
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(e, disagreementInputs()), shift / kZ90 + spread, 1e-12);
  EXPECT_GT(w_hat, 0.99);
  // Smaller than the Birge-scaled posterior, √(w(1 − w))·|Δ| here: it does not charge the combination with a share
  // of a disagreement that EXIF's own σ explains.
  RatioTermInputs birge = disagreementInputs();
  birge.sigma = RatioTermSigma::birge;
  EXPECT_LT(ratioLogSigmaUnseenByHalves(e, disagreementInputs()), ratioLogSigmaUnseenByHalves(e, birge));
  // Identical estimates: only the spread is left.
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(test::combinedRatioEvidence(0.10, 0.01, 0.13, 0.0), disagreementInputs()),
              spread, 1e-12);
}

TEST(BandRatioDisagreement, TheShiftRuleKeepsOnlyTheExpectedErrorOfTheReportedRatio) {
  RatioTermInputs shift = disagreementInputs();
  shift.sigma = RatioTermSigma::disagreement_shift;
  for (const double delta : {-0.04, 0.0, 0.4}) {
    const RatioEvidence e = test::combinedRatioEvidence(0.2, 0.03, 0.13, delta);
    const double vi = std::max(0.03 * 0.03, delta * delta - 0.13 * 0.13), vn = 0.13 * 0.13;
    EXPECT_NEAR(ratioLogSigmaUnseenByHalves(e, shift), std::abs((e.images_weight - vn / (vi + vn)) * delta) / kZ90,
                1e-12)
        << "delta " << delta;
    EXPECT_LE(ratioLogSigmaUnseenByHalves(e, shift), ratioLogSigmaUnseenByHalves(e, disagreementInputs()));
  }
}

TEST(BandRatioDisagreement, ADisagreementBeyondExifsSigmaIsChargedToTheImagesAndGrowsTheTerm) {
  // Δ = 0.4 (the images' r 49 % above EXIF, the r = 8 bench's worst): σ̂_images² = Δ² − σ_n², the reported r
  // (images' weight w = 0.3 by the a-priori σ) is then off by (w − ŵ)·Δ on average, with the conditional spread.
  double previous = 0;
  for (const double delta : {0.15, 0.25, 0.4}) {
    const RatioEvidence e = test::combinedRatioEvidence(0.2, 0.03, 0.13, delta);
    const double vi = delta * delta - 0.13 * 0.13, vn = 0.13 * 0.13, w_hat = vn / (vi + vn), w = e.images_weight;
    const double expected = std::abs((w - w_hat) * delta) / kZ90 +
                            std::sqrt(vi * vn / (vi + vn) - w * w * 0.03 * 0.03);
    const double sigma = ratioLogSigmaUnseenByHalves(e, disagreementInputs());
    EXPECT_NEAR(sigma, expected, 1e-12) << "delta " << delta;
    EXPECT_GT(sigma, previous) << "delta " << delta;
    previous = sigma;
  }
  EXPECT_GT(previous, 0.1);  // at Δ = 0.4 it reaches the bench's worst errors of log r (0.04-0.16)
}

TEST(BandRatioDisagreement, TheImagesOwnReportedRatioAndArbitratedConflictsAreHandledAsThePairDid) {
  // The images' own r reported (w_rep = 1), halves fitting their own r: the shift is (1 − ŵ)·Δ ≈ 0 for agreeing
  // estimates, and the halves carry the whole resampled spread.
  RatioTermInputs own = disagreementInputs();
  own.reported_from_evidence = false;
  own.halves_combine = false;
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(test::combinedRatioEvidence(0.10, 0.01, 0.13, -0.04), own), 0.0, 2e-4);
  // A conflict the brightness arbitrated: the birge rule (S = 1 there), not evidence about σ.
  RatioEvidence held = test::combinedRatioEvidence(0.15, 0.03, 0.13, 0.6);
  held.decision = RatioDecision::nominal_held;
  held.log_sigma = 0.13;
  held.images_weight = 0;
  EXPECT_NEAR(ratioLogSigmaUnseenByHalves(held, disagreementInputs()), 0.13, 1e-12);
  EXPECT_EQ(ratioLogSigmaUnseenByHalves(RatioEvidence{}, disagreementInputs()), 0.0);
}

// The offset term at r = 1: a truth that differs from φ by an offset within the bound level·φ(x_lo) (after its best
// common scale) lies inside the term's half-width at every covered sample; one four times beyond it does not.
TEST(BandOffsetTerm, CoversAnOffsetWithinPhiAtTheBottomOfTheDataAndNotFourTimesIt) {
  const int n = kCurveSamples;
  std::vector<double> phi(n);
  for (int i = 0; i < n; ++i) phi[i] = std::pow(double(i) / (n - 1), 2.2);
  const std::pair<double, double> covered{0.1, 0.9};
  const std::vector<double> h = offsetTermHalfWidth(phi, covered, 0.9);
  ASSERT_EQ(static_cast<int>(h.size()), n);
  const int i0 = static_cast<int>(std::lround(0.1 * (n - 1))), i1 = static_cast<int>(std::lround(0.9 * (n - 1)));
  const double bound = 0.9 * phi[i0];
  auto coveredFraction = [&](double offset) {  // truth = (φ − c) / 1.1, then its best common scale onto φ
    std::vector<double> truth(n);
    for (int i = 0; i < n; ++i) truth[i] = (phi[i] - offset) / 1.1;
    double num = 0, den = 0;
    for (int i = i0; i <= i1; ++i) num += phi[i] * truth[i], den += truth[i] * truth[i];
    int hits = 0;
    for (int i = i0; i <= i1; ++i) hits += std::abs(num / den * truth[i] - phi[i]) <= h[i] + 1e-12;
    return double(hits) / (i1 - i0 + 1);
  };
  EXPECT_GT(coveredFraction(0.5 * bound), 0.98);
  EXPECT_GT(coveredFraction(-0.5 * bound), 0.98);
  EXPECT_LT(coveredFraction(4 * bound), 0.2);
  // Nothing to add for a curve that is 0 at the bottom of its data (φ(x_lo) = 0 pins the offset).
  const std::vector<double> none = offsetTermHalfWidth(phi, {0.0, 0.9}, 0.9);
  EXPECT_LT(*std::max_element(none.begin(), none.end()), 1e-12);
}

// The prior term is φ's difference to a refit without the extrapolation priors, started from the fit: with the
// priors already off in the fit, the refit has nothing to move against and the term vanishes; with them on it is
// finite, of the curve's size, and the band carries it (and keeps the verdict's reading without it).
TEST(BandPriorTerm, VanishesWhenTheFitHasNoPriorsAndWidensOnlyTheReportedBandOtherwise) {
  const cv::Mat kernel = test::levinKernel(3);
  const SimulationResult pair = test::gammaPairAtRatio4();
  auto fitAndBand = [&](const CrfFitOptions& options, bool prior_term) {
    const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, kernel, options);
    const std::pair<double, double> covered{fit.covered_levels.first / double(fit.levels - 1),
                                            fit.covered_levels.second / double(fit.levels - 1)};
    CrfFitOptions refit = options;  // the band's refit options: the chosen model from the fit
    refit.model = fit.chosen == "ggcm" ? CrfModelChoice::ggcm : CrfModelChoice::emor;
    refit.start = CrfFitOptions::Start{fit.model, fit.ratio};
    CurveBandOptions band;
    band.replicates = 4;
    band.include_prior_term = prior_term;
    return std::make_pair(fit, estimateCurveBand(pair.sharp, pair.blurred, kernel, refit, fit, covered, band));
  };
  CrfFitOptions no_priors;
  no_priors.exponent_smoothness = 0;
  no_priors.shoulder_prior = 0;
  const auto [fit_free, band_free] = fitAndBand(no_priors, true);
  ASSERT_EQ(band_free.prior_half_width.size(), fit_free.inverse_crf.size());
  EXPECT_LT(*std::max_element(band_free.prior_half_width.begin(), band_free.prior_half_width.end()), 1e-3);

  const auto [fit, with] = fitAndBand(CrfFitOptions{}, true);
  const auto [fit_again, without] = fitAndBand(CrfFitOptions{}, false);
  ASSERT_EQ(with.prior_half_width.size(), fit.inverse_crf.size());
  EXPECT_TRUE(without.prior_half_width.empty());
  for (double h : with.prior_half_width) ASSERT_TRUE(std::isfinite(h) && h >= 0 && h < 0.5);
  for (std::size_t i = 0; i < with.shape_half_width.size(); ++i)
    ASSERT_GE(with.shape_half_width[i] + 1e-12, without.shape_half_width[i]);
  // The verdict reads the width before the term (medianShapeSigma): unchanged by it.
  EXPECT_NEAR(medianShapeSigma(with), medianShapeSigma(without), 1e-12);
}

}  // namespace
}  // namespace crfcal
