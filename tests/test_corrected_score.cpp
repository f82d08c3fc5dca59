// The corrected score of issue 23 (noise_debias.hpp): the clipped, quantised noise law of a noisy sharp image on
// the 256-level grid, and the function h = R φ whose expectation under that law is φ again.
#include <algorithm>
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/noise_debias.hpp"

namespace crfcal {
namespace {

constexpr int kLevels = 256;

double normalCdf(double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); }

// E[h(observed) | clean level c] − φ(c), worst over the clean levels.
double worstExpectationError(const NoiseDebias& debias, const std::vector<double>& h, const std::vector<double>& phi) {
  double worst = 0;
  for (int c = 0; c < kLevels; ++c) {
    double e = 0;
    for (int v = 0; v < kLevels; ++v) e += debias.transition()(c, v) * h[v];
    worst = std::max(worst, std::abs(e - phi[c]));
  }
  return worst;
}

// A steep highlight shoulder like the Middlebury cameras' (φ' ≈ 10 in the top levels): φ = x^2.2 blended into a
// rise above x = 0.85.
std::vector<double> shoulderCurve() {
  std::vector<double> phi(kLevels);
  for (int v = 0; v < kLevels; ++v) {
    const double x = v / 255.0;
    const double top = std::max(0.0, x - 0.85) / 0.15;
    phi[v] = 0.6 * std::pow(x / 0.85, 2.2) * (x < 0.85) + (x >= 0.85) * (0.6 + 0.4 * std::pow(top, 1.5));
  }
  return phi;
}

TEST(CorrectedScore, ClippedNoiseLawRowsSumToOneWithPointMassesAtTheEnds) {
  NoiseDebiasOptions options;
  options.sigma = 25.0 / 255;  // the stated protocol's σ² = 0.01
  const NoiseDebias debias(options);
  const auto& t = debias.transition();
  for (int c = 0; c < kLevels; ++c) EXPECT_NEAR(t.row(c).sum(), 1.0, 1e-12) << "clean level " << c;
  // Observed 255 collects every clean + noise ≥ 254.5: half the mass of a clean 255, a sixth of a clean 230.
  EXPECT_NEAR(t(255, 255), normalCdf(0.5 / 25), 1e-9);
  EXPECT_NEAR(t(230, 255), 1 - normalCdf(24.5 / 25), 1e-9);
  EXPECT_NEAR(t(0, 0), normalCdf(0.5 / 25), 1e-9);
  EXPECT_GT(t(230, 255), 10 * t(230, 254));  // a point mass, not the density of one level
  // An interior observed level has the density of one level's width.
  EXPECT_NEAR(t(128, 128), normalCdf(0.5 / 25) - normalCdf(-0.5 / 25), 1e-9);
}

TEST(CorrectedScore, ReproducesAShoulderCurveInExpectationUnderTheClippedLaw) {
  const std::vector<double> phi = shoulderCurve();
  for (double sigma_levels : {8.0, 18.0}) {
    NoiseDebiasOptions options;
    options.sigma = sigma_levels / 255;
    const NoiseDebias debias(options);
    const double naive = worstExpectationError(debias, phi, phi);  // φ evaluated at the noisy level
    const double corrected = worstExpectationError(debias, debias.apply(phi), phi);
    EXPECT_GT(naive, 0.02) << "sigma " << sigma_levels;
    EXPECT_LT(corrected, 0.25 * naive) << "sigma " << sigma_levels;
  }
}

TEST(CorrectedScore, RidgeRegularizerAlsoRemovesTheNoiseBias) {
  const std::vector<double> phi = shoulderCurve();
  NoiseDebiasOptions options;
  options.sigma = 8.0 / 255;
  options.regularizer = DebiasRegularizer::ridge;
  options.regularization = 1e-3;
  const NoiseDebias debias(options);
  const double naive = worstExpectationError(debias, phi, phi);
  const double corrected = worstExpectationError(debias, debias.apply(phi), phi);
  EXPECT_LT(corrected, 0.25 * naive);
}

TEST(CorrectedScore, NoNoiseMeansTheIdentity) {
  NoiseDebiasOptions options;
  options.sigma = 0;
  const NoiseDebias debias(options);
  EXPECT_TRUE(debias.identity());
  const std::vector<double> phi = shoulderCurve();
  EXPECT_EQ(debias.apply(phi), phi);
}

}  // namespace
}  // namespace crfcal
