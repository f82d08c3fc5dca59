// The clipping model's plateau grid (Problem::fit → bestPlateau, calib/src/effect_problem.cpp) is searched coarse to
// fine, its levels compared on paused LM runs (stop 33, docs/RESULTS.md#speed-small). On residuals with a planted
// plateau of B (spread over several grid levels by noise, one case with two valleys of the in-sample error) or with
// none, it must choose the level the exhaustive grid of full fits chooses, with the same fit to the bit.
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <span>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "effect_problem_support.hpp"
#include "crfcal/emor.hpp"

namespace crfcal::effect {
namespace {

constexpr int kTerms = 2;

double lookup(std::span<const double, emor::kSamples> f, double v) {
  const double x = std::clamp(v, 0.0, 1.0) * (emor::kSamples - 1);
  const int i = std::min(emor::kSamples - 2, static_cast<int>(x));
  return f[i] + (x - i) * (f[i + 1] - f[i]);
}

// One channel of the residual model with φ the identity: B = min(r X, plateau) + noise (plateau > 1: none; the noise
// spreads the plateau over several grid levels, as a JPEG's coding does), the φ
// columns a₀ h_k(X) − h_k(B) of the EMoR terms and their slopes at B, as collect() forms them.
Samples plateauSamples(double ratio, double plateau, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> irradiance(0.02, 0.95 / ratio);
  std::normal_distribution<double> noise(0.0, 0.004);
  std::vector<double> phi(emor::kSamples);
  for (int i = 0; i < emor::kSamples; ++i) phi[i] = double(i) / (emor::kSamples - 1);
  Samples s = emptySamples(1, kTerms, std::move(phi));
  for (int i = 0; i < 6000; ++i) {
    const double x = irradiance(rng);
    const double b = std::clamp(std::min(ratio * x, plateau) + noise(rng), 0.0, 1.0);
    s.block.push_back(i % 64);
    s.fine.push_back(i % 256);
    s.fold.push_back(i % 2);
    s.d.push_back(1.0);
    s.Y.push_back(b);
    s.rho2.push_back(0.0);
    s.level.push_back(b);
    s.X[0].push_back(x);
    s.pos.emplace_back(i % 100, i / 100);
    for (int k = 0; k < kTerms; ++k) {
      const auto h = emor::inverseBasis(k + 1);
      const int bi = std::clamp(static_cast<int>(b * 1023 + 0.5), 0, 1023);
      const int lo = std::max(0, bi - 1), hi = std::min(emor::kSamples - 1, bi + 1);
      s.Hb[k].push_back(h[bi]);
      s.Dh[k].push_back((h[hi] - h[lo]) * (emor::kSamples - 1) / (hi - lo));
      s.KH[k].push_back(lookup(h, x));
      s.P[k].push_back(ratio * lookup(h, x) - lookup(h, b));
    }
  }
  groupByWeight(s);  // as collect() does: the LM factorises the samples per level of B
  return s;
}

// The exhaustive grid as before stop 33: every level fitted to the full tolerance from the linear start, the lowest
// in-sample error (the coarser level on a tie).
ChannelFit exhaustiveBest(const Problem& problem, const Spec& spec) {
  const Samples& s = problem.samples()[0];
  const std::vector<std::size_t> idx = test::allSamples(s);
  ChannelFit best;
  double best_error = std::numeric_limits<double>::infinity();
  for (double clip : plateauGrid(s, idx)) {
    const ChannelFit f = problem.fitLevel(s, spec, idx, clip);
    if (!f.ok) continue;
    const double error = test::inSampleError(problem, spec, f);
    if (error < best_error) {
      best_error = error;
      best = f;
    }
  }
  return best;
}

// The same level and the same fit to the bit (the chosen level's paused LM runs on through the passes of an
// uninterrupted run), so the same in-sample error.
void expectSameChoiceAsExhaustiveGrid(double ratio, double plateau, unsigned seed) {
  const Problem problem({plateauSamples(ratio, plateau, seed)}, 64, 256, 0.05);
  Spec spec;
  spec.clipping = true;
  const ChannelFit exhaustive = exhaustiveBest(problem, spec);
  const ChannelFit searched = problem.fit(problem.samples()[0], spec, -1);
  ASSERT_TRUE(exhaustive.ok);
  ASSERT_TRUE(searched.ok);
  EXPECT_EQ(searched.clip, exhaustive.clip) << "plateau " << plateau << ", seed " << seed;
  ASSERT_EQ(searched.theta.size(), exhaustive.theta.size());
  for (Eigen::Index k = 0; k < searched.theta.size(); ++k)
    EXPECT_EQ(searched.theta(k), exhaustive.theta(k)) << "coefficient " << k << ", plateau " << plateau;
  EXPECT_EQ(test::inSampleError(problem, spec, searched), test::inSampleError(problem, spec, exhaustive));
}

TEST(EffectPlateauGrid, CoarseToFineSearchChoosesThePlantedPlateauLikeTheExhaustiveGrid) {
  // plateaus reached by 2–18 % of the samples (between the grid's 98 and 80 % quantiles)
  for (unsigned seed : {1u, 2u})
    for (double plateau : {0.93, 0.91, 0.90, 0.88, 0.86, 0.82, 0.78}) expectSameChoiceAsExhaustiveGrid(1.0, plateau, seed);
}

TEST(EffectPlateauGrid, CoarseToFineSearchChoosesNoPlateauLikeTheExhaustiveGridOnUnclippedResiduals) {
  for (unsigned seed : {3u, 4u}) expectSameChoiceAsExhaustiveGrid(1.0, 2.0, seed);
}

}  // namespace
}  // namespace crfcal::effect
