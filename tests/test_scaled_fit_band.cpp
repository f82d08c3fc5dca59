// The band of the static references' curves (calib/include/crfcal/scaled_fit_band.hpp): cluster halves and the
// band's coverage of a known curve when the only error is noise.
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/error.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/scaled_fit_band.hpp"

namespace crfcal {
namespace {

TEST(ScaledFitBand, ClusterHalvesAreComplementaryPairsAndDeterministic) {
  const auto halves = clusterHalves(11, 6, 3);
  ASSERT_EQ(halves.size(), 6u);
  for (std::size_t k = 0; k < halves.size(); k += 2) {
    int first = 0;
    for (int c = 0; c < 11; ++c) {
      EXPECT_NE(halves[k][c], halves[k + 1][c]) << "cluster " << c << " in both or neither half of pair " << k / 2;
      first += halves[k][c];
    }
    EXPECT_EQ(first, 5);  // ⌊11/2⌋ in the first half
  }
  EXPECT_NE(halves[0], halves[2]) << "every pair draws its own halves";
  EXPECT_EQ(clusterHalves(11, 6, 3), halves);
  EXPECT_TRUE(clusterHalves(3, 8, 1).empty());
}

// A bracket of `points` scene points at exposures 1, 2.8, 8 through φ = an EMoR curve (so that the K-term model has
// no representation error), noise σ on x: observations t_j = s_p·φ(x_pj), one cluster per point.
struct SyntheticBracket {
  std::vector<ScaledObservation> observations;
  std::vector<int> cluster;
};

SyntheticBracket syntheticBracket(const ResponseCurve& truth, int points, double sigma, std::uint64_t seed) {
  SyntheticBracket b;
  std::mt19937_64 random(seed);
  std::uniform_real_distribution<double> log_irradiance(std::log(0.01), std::log(1.0));
  std::normal_distribution<double> noise(0, sigma);
  for (int p = 0; p < points; ++p) {
    const double e = std::exp(log_irradiance(random));
    std::vector<ScaledObservation> own;
    for (double t : {1.0, 2.8, 8.0}) {
      const double x = truth.forward(std::min(e * t, 1.0)) + noise(random);
      if (x < 0.02 || x >= 0.97) continue;
      own.push_back({ScaledObservation::Kind::Exact, x, t, 0, p % 2, (x / t) * (x / t)});
    }
    if (own.size() < 2) continue;
    const int group = b.cluster.empty() ? 0 : b.cluster.back() + 1;
    for (auto& o : own) {
      o.group = group;
      b.observations.push_back(o);
      b.cluster.push_back(group);
    }
  }
  return b;
}

TEST(ScaledFitBand, ShapeBandCoversACurveTheModelCanRepresentAtAboutItsLevel) {
  // Noise is the only error here, so the band (half-sample refits of the points, K held, plus the K ± 1 fits) must
  // cover the truth's shape at about its 90 % level: a band that ignores the clusters' shared scale, or that uses
  // the replicates' spread without the half-sample factor, lands far below.
  const ResponseCurve truth(EmorModel{{-0.8, 0.2, 0.05}});
  ScaledFitOptions fit_options;
  fit_options.profile_scales = true;
  fit_options.smoothness = 1e-4;
  fit_options.exponent_smoothness = 1e-6;
  CurveBandOptions band_options;
  band_options.replicates = 8;
  int inside = 0, hits = 0;
  std::vector<double> widths;
  for (std::uint64_t seed = 1; seed <= 12; ++seed) {
    const SyntheticBracket b = syntheticBracket(truth, 150, 0.004, seed);
    const ScaledFitResult fit = fitScaledInverseFixed(b.observations, 3, fit_options);
    band_options.seed = seed;
    const CurveBand band = scaledFitBand(b.observations, b.cluster, fit_options, fit, band_options);
    ASSERT_FALSE(band.empty());
    EXPECT_EQ(band.replicates + band.failed_replicates, 8);
    for (std::size_t i = 0; i < band.lower.size(); ++i) {
      EXPECT_LE(band.lower[i], fit.inverse[i] + 1e-12);
      EXPECT_GE(band.upper[i], fit.inverse[i] - 1e-12);
    }
    const BandScore score = scoreBand(band, fit.inverse, truth.sample(kCurveSamples));
    inside += score.inside;
    hits += score.shape_hits;
    widths.push_back(score.median_shape_width_inside);
  }
  const double coverage = double(hits) / inside;
  EXPECT_GT(coverage, 0.7) << "shape band covers the truth at " << coverage;
  std::sort(widths.begin(), widths.end());
  EXPECT_LT(widths[widths.size() / 2], 0.02) << "a 0.004 noise on 150 points should not need a wide band";
}

TEST(ScaledFitBand, RefusesAClusterListOfAnotherLength) {
  const SyntheticBracket b = syntheticBracket(ResponseCurve(GammaModel{2.2}), 40, 0.003, 1);
  ScaledFitOptions fit_options;
  fit_options.profile_scales = true;
  const ScaledFitResult fit = fitScaledInverseFixed(b.observations, 3, fit_options);
  std::vector<int> short_list(b.cluster.begin(), b.cluster.end() - 1);
  EXPECT_THROW(scaledFitBand(b.observations, short_list, fit_options, fit), InvalidInput);
}

}  // namespace
}  // namespace crfcal
