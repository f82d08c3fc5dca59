#pragma once
// Helpers of the tests that drive the effect search's residual model (calib/src/effect_problem.hpp) directly.
#include <cmath>
#include <numeric>
#include <vector>

#include "../calib/src/effect_problem.hpp"

namespace crfcal::effect::test {

// Indices of every sample.
inline std::vector<std::size_t> allSamples(const Samples& s) {
  std::vector<std::size_t> idx(s.size());
  std::iota(idx.begin(), idx.end(), std::size_t{0});
  return idx;
}

// Σ residual² over every sample, each residual from Problem::residual (sample by sample, not the LM's path).
inline double inSampleError(const Problem& problem, const Spec& spec, const ChannelFit& f) {
  const Samples& s = problem.samples()[0];
  double error = 0;
  for (std::size_t i = 0; i < s.size(); ++i) error += std::pow(problem.residual(s, i, spec, f), 2);
  return error;
}

}  // namespace crfcal::effect::test
