// The clipping model's plateau level (effect_clipping.cpp): the grid of B's upper quantiles and its coarse-to-fine
// search (Problem::fit hands the clipping spec here). Split from effect_problem.cpp, the residual model it fits.
#include <algorithm>
#include <cmath>
#include <limits>

#include "effect_problem.hpp"

namespace crfcal::effect {

std::vector<double> plateauGrid(const Samples& s, const std::vector<std::size_t>& idx) {
  std::vector<double> y;
  for (auto i : idx) y.push_back(s.level[i]);
  std::sort(y.begin(), y.end());
  std::vector<double> clips{2.0};  // 2: no plateau (the base model, nested)
  if (y.empty()) return clips;
  for (double q : {1.0, 0.999, 0.995, 0.99, 0.98, 0.97, 0.95, 0.93, 0.9, 0.85, 0.8})
    clips.push_back(y[static_cast<std::size_t>(q * (y.size() - 1))]);
  clips.erase(std::unique(clips.begin(), clips.end()), clips.end());
  return clips;
}

// The plateau grid, coarse to fine: "none" and every other level first, then the neighbours of the best until the
// best is flanked by tried levels (a hill climb over the grid; where the in-sample error has two valleys over the
// grid it can stop in the other one: vivo pair 3's clipping candidate, not named either way). The levels are
// compared on LM runs paused at a relative drop of kPlateauSelectionTolerance: the LM's slow tail from there to
// kFitTolerance is ~40 % of its passes and mostly lowers the cost by ~10⁻⁶ of itself (not always: an LM that
// crawls and then drops finds its lower valley only in the tail). The chosen level's run then goes on from where it
// paused, so its fit is the one the exhaustive grid made. Together 35–45 % of the exhaustive grid's LM passes
// (docs/RESULTS.md#speed-small).
ChannelFit Problem::bestPlateau(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx,
                                const std::vector<double>& clips, const Eigen::VectorXd* start,
                                const DesignRows& rows) const {
  const std::size_t n = clips.size();
  std::vector<ChannelFit> fits(n);
  std::vector<LmState> states(n);
  std::vector<double> error(n, std::numeric_limits<double>::quiet_NaN());
  std::vector<char> tried(n, 0);
  // Every level's samples are whole groups of these (the levels censor B's plateau, the groups are B's levels):
  // grouped and factorised once for the grid (without φ terms fitLevel runs no Levenberg–Marquardt and reads none).
  GroupedResiduals groups(0, 0, 0);
  if (!s.Dh.empty()) {
    groups = groupedResiduals(s, spec, idx, rows.cols, &rows);
    groups.factorise();
  }
  const auto tryLevel = [&](std::size_t j) {
    if (j >= n || tried[j]) return;
    tried[j] = 1;
    if (!(clips[j] > 0)) return;
    fits[j] = fitLevel(s, spec, idx, clips[j], start, &rows, kPlateauSelectionTolerance, &states[j], &groups);
    if (!fits[j].ok) return;
    double e = 0;
    for (auto i : idx) {
      const double r = residualOfRow(s, i, fits[j], rows.at(i), rows.cols, rows.targetAt(i));
      e += r * r;
    }
    error[j] = e;
  };
  // The lowest error, the higher (earlier) level on a tie, as the exhaustive loop chose.
  const auto best = [&] {
    std::size_t b = n;
    for (std::size_t j = 0; j < n; ++j)
      if (!std::isnan(error[j]) && (b == n || error[j] < error[b])) b = j;
    return b;
  };
  tryLevel(0);
  for (std::size_t j = 1; j < n; j += 2) tryLevel(j);
  std::size_t chosen = best();
  while (chosen < n) {
    if (chosen > 0) tryLevel(chosen - 1);
    tryLevel(chosen + 1);
    const std::size_t next = best();
    if (next == chosen) break;
    chosen = next;
  }
  if (chosen == n) return {};
  if (states[chosen].finished) return fits[chosen];
  // run on where it paused: the fit the exhaustive grid made at this level, to the bit
  return fitLevel(s, spec, idx, clips[chosen], &fits[chosen].theta, &rows, kFitTolerance, &states[chosen], &groups);
}

}  // namespace crfcal::effect
