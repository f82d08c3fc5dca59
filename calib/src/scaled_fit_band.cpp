#include "crfcal/scaled_fit_band.hpp"

#include <algorithm>
#include <chrono>
#include <numeric>
#include <random>
#include <unordered_map>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "parallel_jobs.hpp"

namespace crfcal {

std::vector<std::vector<bool>> clusterHalves(int clusters, int count, std::uint64_t seed) {
  std::vector<std::vector<bool>> halves;
  if (clusters < 4 || count < 2) return halves;
  std::mt19937_64 random(seed);
  std::vector<int> order(static_cast<std::size_t>(clusters));
  for (int pair = 0; pair < count / 2; ++pair) {
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), random);
    std::vector<bool> first(static_cast<std::size_t>(clusters), false);
    for (int k = 0; k < clusters / 2; ++k) first[static_cast<std::size_t>(order[static_cast<std::size_t>(k)])] = true;
    std::vector<bool> second(first.size());
    std::transform(first.begin(), first.end(), second.begin(), [](bool b) { return !b; });
    halves.push_back(std::move(first));
    halves.push_back(std::move(second));
  }
  return halves;
}

namespace {

// The observations of the clusters in `half`, their groups renumbered 0 … (fitScaledInverse's groups are dense).
std::vector<ScaledObservation> halfOf(std::span<const ScaledObservation> observations, const std::vector<int>& cluster,
                                      const std::vector<bool>& half) {
  std::vector<ScaledObservation> out;
  std::unordered_map<int, int> group_of;
  for (std::size_t i = 0; i < observations.size(); ++i) {
    if (!half[static_cast<std::size_t>(cluster[i])]) continue;
    ScaledObservation o = observations[i];
    const auto [it, inserted] = group_of.emplace(o.group, static_cast<int>(group_of.size()));
    o.group = it->second;
    out.push_back(o);
  }
  return out;
}

}  // namespace

CurveBand scaledFitBand(std::span<const ScaledObservation> observations, const std::vector<int>& cluster,
                        const ScaledFitOptions& fit_options, const ScaledFitResult& fit,
                        const CurveBandOptions& options, std::vector<std::vector<double>> alternatives) {
  options.check();
  const auto start = std::chrono::steady_clock::now();
  if (cluster.size() != observations.size())
    throw InvalidInput("band: one cluster per observation expected", ErrorSubject::curve);
  if (fit.inverse.size() != static_cast<std::size_t>(kCurveSamples) || fit.terms < 1)
    throw InvalidInput("band: the fit has no curve", ErrorSubject::curve);
  int clusters = 0;
  for (int c : cluster) {
    if (c < 0) throw InvalidInput("band: negative cluster id", ErrorSubject::curve);
    clusters = std::max(clusters, c + 1);
  }
  const std::vector<std::vector<bool>> halves = clusterHalves(clusters, options.replicates, options.seed);
  std::vector<std::vector<double>> curves(halves.size());
  const std::vector<std::exception_ptr> errors = detail::runInParallel(static_cast<int>(halves.size()), [&](int k) {
    const std::vector<ScaledObservation> half = halfOf(observations, cluster, halves[static_cast<std::size_t>(k)]);
    curves[static_cast<std::size_t>(k)] = fitScaledInverseFixed(half, fit.terms, fit_options).inverse;
  });
  std::vector<std::vector<double>> replicates;
  int failed = 0;
  for (std::size_t k = 0; k < halves.size(); ++k) {
    if (errors[k]) {
      try {
        std::rethrow_exception(errors[k]);
      } catch (const InvalidInput&) {
        ++failed;  // too few observations in this half: the band has one refit fewer
        continue;
      }
    }
    replicates.push_back(std::move(curves[k]));
  }
  // The model term: the fits with one EMoR term fewer and one more on all observations (the K the cross-validation
  // chose is itself an estimate; resampling with K held cannot see what K costs).
  for (int k : {fit.terms - 1, fit.terms + 1}) {
    if (k < 1 || k > emor::kMaxTerms) continue;
    try {
      alternatives.push_back(fitScaledInverseFixed(observations, k, fit_options).inverse);
    } catch (const InvalidInput&) {
    }
  }
  CurveBand band = bandFromReplicates(fit.inverse, replicates, fit.covered_range, options, alternatives);
  band.failed_replicates = failed;
  band.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return band;
}

}  // namespace crfcal
