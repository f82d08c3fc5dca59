// Attribution between competing explanations of the same misfit (issue 18): an effect is named because it explains
// the held-back pixels better than its competitors, not because it was the first to pass its own test. Every
// candidate is fitted on one fold of the checkerboard and its error measured on the other (effects.hpp), around the
// same φ, so their held-out errors are comparable; the named effect's evidence against the runner-up is the
// held-out drop from the runner-up's model to its own, with the same score test as every effect's own test
// (scoreTest: z = Σ d / (2 σ sqrt(A Σ δ²)), d the per-sample drop, δ the change of prediction).
#include <algorithm>
#include <array>
#include <exception>
#include <limits>
#include <optional>

#include "crfcal/channel_verdict.hpp"
#include "effect_problem.hpp"
#include "parallel_jobs.hpp"

namespace crfcal::effect {

std::vector<Candidate> levelCandidates(const EffectSearch& search, const Problem& problem, const Spec& base,
                                       const Evaluation& base_eval) {
  std::vector<const LevelEffect*> effects;
  for (const LevelEffect* effect : levelEffects())
    if (!effect->not_applicable(search) && !effect->in(base)) effects.push_back(effect);
  // Each candidate's evaluation is three independent fits of the same problem (either fold, all samples): 3n jobs
  // over the cores, the dearest candidate's first (clipping fits a grid of plateau levels), so that no core waits
  // at the end for a long fit begun late. The results are those of problem.evaluate, in levelEffects() order.
  const int n = static_cast<int>(effects.size());
  std::vector<Spec> extended(n);
  for (int i = 0; i < n; ++i) extended[i] = effects[i]->extend(base);
  std::vector<std::array<PartFit, 3>> parts(n);  // fold 0, fold 1, all samples
  const std::vector<std::exception_ptr> fit_errors =
      detail::runInParallelDearestFirst(dearestFitsFirst(extended, 3), [&](int job) {
        const int i = job / 3, part = job % 3;
        parts[i][part] = problem.fitPart(extended[i], part == 2 ? -1 : part, &base_eval);
      });
  for (const std::exception_ptr& error : fit_errors)
    if (error) std::rethrow_exception(error);
  std::vector<std::optional<Candidate>> out(n);
  const std::vector<std::exception_ptr> errors = detail::runInParallel(n, [&](int i) {
    const LevelEffect& effect = *effects[i];
    Candidate c{effect.name,
                problem.assemble(extended[i], true, {std::move(parts[i][0]), std::move(parts[i][1])},
                                 std::move(parts[i][2])),
                {}, false, false, {}};
    c.cmp = effect.test(search, base_eval, c.eval);
    c.plausible = physical(extended[i], c.eval, search.nc, search.terms);
    if (c.plausible) c.flattened = flattenedChannel(search, problem, extended[i], c.eval);
    c.plausible = c.plausible && c.flattened.empty();
    c.passes = c.plausible && c.cmp.gain >= search.options.min_gain && c.cmp.z >= search.options.min_z;
    out[i] = std::move(c);
  });
  std::vector<Candidate> candidates;
  for (int i = 0; i < n; ++i) {
    if (errors[i]) std::rethrow_exception(errors[i]);
    candidates.push_back(std::move(*out[i]));
  }
  return candidates;
}

std::string flattenedChannel(const EffectSearch& search, const Problem& problem, const Spec& spec,
                             const Evaluation& ev) {
  const VerdictOptions verdict;  // what the verdict calls a flat curve, and the fraction it tolerates
  for (int c = 0; c < search.nc; ++c) {
    const Samples& s = problem.samples()[static_cast<std::size_t>(c)];
    if (!ev.full[c].ok || s.size() == 0) continue;
    std::vector<double> levels = s.level;
    const std::size_t tail = levels.size() / 1000;
    std::nth_element(levels.begin(), levels.begin() + tail, levels.end());
    const double lo = levels[tail];
    std::nth_element(levels.begin(), levels.end() - 1 - tail, levels.end());
    const std::pair<double, double> covered{lo, levels[levels.size() - 1 - tail]};
    const std::vector<double> refit =
        adjustedPhi(s.phi, coefficients(spec, ev.full[c], c, search.nc, search.terms).alpha);
    if (flatFraction(refit, covered, verdict) >= flatFraction(s.phi, covered, verdict) + verdict.max_flat_fraction)
      return search.in.channels[static_cast<std::size_t>(c)];
  }
  return {};
}

Comparison headToHead(const EffectSearch& search, const Evaluation& runner_up, const Evaluation& winner) {
  Comparison cmp = scoreTest(search.problem.samples(), runner_up, winner, search.used_fine, search.blocks);
  cmp.gain = runner_up.total > 0 ? cmp.gain / runner_up.total : 0;
  return cmp;
}

void recordRunnerUp(EffectSearch& search, const Candidate& winner, const std::vector<Candidate>& candidates) {
  const Candidate* runner_up = nullptr;
  for (const Candidate& c : candidates)
    if (&c != &winner && c.plausible && (!runner_up || c.eval.total < runner_up->eval.total)) runner_up = &c;
  EffectEntry& e = search.entry(winner.name);
  if (!runner_up) {
    e.runner_up.clear();
    return;
  }
  const Comparison h = headToHead(search, runner_up->eval, winner.eval);
  e.runner_up = runner_up->name;
  e.runner_up_gain = runner_up->cmp.gain;
  e.evidence_gain = h.gain;
  e.evidence_z = h.z;
}

}  // namespace crfcal::effect
