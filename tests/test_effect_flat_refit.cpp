// The effect search re-fits φ jointly with every model by a few EMoR terms (calib/src/effect_problem.hpp). A model
// whose re-fit makes φ nearly constant over the data, where the curve it is linearised around is not, explains the
// residuals by shrinking them (the floored weights 1/max(φ', min_derivative)), not by a physical effect:
// flattenedChannel (calib/src/effect_attribution.cpp) names such a channel with the verdict's own flat rule.
#include <cmath>
#include <vector>

#include <Eigen/Dense>
#include <gtest/gtest.h>

#include "crfcal/emor.hpp"
#include "effect_problem_support.hpp"

namespace crfcal::effect {
namespace {

constexpr int kTerms = 4;

// Samples of one channel with B's levels spread over [0.05, 0.5] and φ̂ a gamma-2.2 curve (only what the rule reads:
// the levels of B and φ̂; Y = φ̂(B) sets the samples' count).
Samples gammaSamples() {
  std::vector<double> phi(emor::kSamples);
  for (int i = 0; i < emor::kSamples; ++i) phi[i] = std::pow(double(i) / (emor::kSamples - 1), 2.2);
  Samples s = emptySamples(1, kTerms, phi);
  for (int i = 0; i < 2000; ++i) {
    s.level.push_back(0.05 + 0.45 * i / 1999.0);
    s.Y.push_back(phi[static_cast<std::size_t>(std::lround(s.level.back() * (emor::kSamples - 1)))]);
  }
  return s;
}

// The full fit of the base model (scale, then the φ terms) with re-fit coefficients α.
Evaluation baseFit(const Eigen::VectorXd& alpha) {
  Evaluation ev;
  ChannelFit f;
  f.theta = Eigen::VectorXd::Zero(1 + kTerms);
  f.theta(0) = 2;
  f.theta.tail(kTerms) = alpha;
  f.ok = true;
  ev.full = {f};
  return ev;
}

// α of the least-squares φ̂ + Σ α_k h_k ≈ 0 over B's levels: the re-fit that flattens φ there.
Eigen::VectorXd flatteningAlpha(const Samples& s) {
  Eigen::MatrixXd H(static_cast<Eigen::Index>(s.size()), kTerms);
  Eigen::VectorXd target(static_cast<Eigen::Index>(s.size()));
  for (std::size_t i = 0; i < s.size(); ++i) {
    const int j = static_cast<int>(std::lround(s.level[i] * (emor::kSamples - 1)));
    for (int k = 0; k < kTerms; ++k) H(static_cast<Eigen::Index>(i), k) = emor::inverseBasis(k + 1)[j];
    target(static_cast<Eigen::Index>(i)) = -s.phi[static_cast<std::size_t>(j)];
  }
  return H.colPivHouseholderQr().solve(target);
}

TEST(EffectFlatRefit, ReFitFlatOverTheDataIsNamedAndAMovedButRisingOneIsNot) {
  EffectInputs in;
  in.channels = {"G"};
  EffectSearch search(in, EffectOptions{});
  search.nc = 1;
  search.terms = kTerms;
  const Problem problem({gammaSamples()}, 1, 1, 0.05);
  const Eigen::VectorXd flat = flatteningAlpha(problem.samples()[0]);
  EXPECT_EQ(flattenedChannel(search, problem, Spec{}, baseFit(flat)), "G");
  EXPECT_EQ(flattenedChannel(search, problem, Spec{}, baseFit(Eigen::VectorXd::Zero(kTerms))), "");
  // Half the way there halves φ over the data (φ(0.5) 0.22 → 0.11) and leaves it rising like a real curve.
  EXPECT_EQ(flattenedChannel(search, problem, Spec{}, baseFit(0.5 * flat)), "");
}

}  // namespace
}  // namespace crfcal::effect
