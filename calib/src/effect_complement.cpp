// The complement check (issue 18): a second effect that the refit of φ absorbed. Forward selection tests each
// remaining effect with a linearised re-fit of φ around the φ that fitInverseCrf settled on for the grown model
// (effect_search.cpp, settle). That refit has no term for an effect the model lacks, so it absorbs what it can of
// it into φ: beside a colour mix, an offset bends the mix-corrected pair's refitted φ by ≈ c / (r − 1), and around
// that φ the offset's own test sees almost nothing (held-out drop 0.003, z 0.6, although it passed at the first
// step with 0.056 and its model still moved φ by 0.028: docs/RESULTS.md#effects-code-254).
// So an effect whose held-out drop was significant (z ≥ min_z, physical parameters) at some step of the forward
// selection and that was not selected gets a second hearing — its relative gain there was measured against an error
// dominated by the misfit the winner explains, so min_gain is applied here, against what the winner leaves — with φ refitted on both sides: the selected model and the selected model plus that effect are each carried
// through the same correction + refit of φ (refitPair, settled as the search settles), and the two refitted curves
// are compared on the held-back pixels with φ as refitted (no EMoR re-fit: the curves themselves are judged, as the
// refit guard judges them), each model's parameters fitted on one fold and measured on the other, by the effect's own
// test and thresholds (min_gain, min_z). The best such
// effect is named, and the check repeats with it in the model. No threshold of its own.
#include <algorithm>
#include <cmath>

#include "crfcal/response_model.hpp"
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

struct Refitted {
  std::vector<Curve> curves;
  std::vector<double> ratios;
  bool ok = false;
};

// `spec` carried from `curves` / `ratios` through correction + refit rounds until φ settles (as settle() does).
Refitted refitWith(const EffectSearch& search, const Spec& spec, std::vector<Curve> curves,
                   std::vector<double> ratios) {
  const int nc = search.nc;
  for (int round = 0; round < std::max(1, search.options.refit_rounds); ++round) {
    const Evaluation ev = search.problemAround(curves, ratios).evaluate(spec, false);
    std::vector<Coefficients> cc(nc);
    for (int c = 0; c < nc; ++c)
      if (ev.full[c].ok) cc[c] = coefficients(spec, ev.full[c], c, nc, search.terms);
    const auto fits = refitPair(search, spec, curves, cc, ev.full, false, false, 0.0);
    if (fits.empty()) return {};
    double moved = 0;
    for (int c = 0; c < nc; ++c) {
      if (!ev.full[c].ok) continue;
      const std::vector<double> before = curves[c].phi;
      curves[c] = makeCurve(fits.at(search.in.channels[c]).inverse_crf);
      ratios[c] = fits.at(search.in.channels[c]).ratio;
      moved = std::max(moved, curveRmse(before, curves[c].phi));
    }
    if (moved < 5e-4) break;
  }
  return {std::move(curves), std::move(ratios), true};
}

}  // namespace

HeldoutAsGiven heldoutAsGiven(const EffectSearch& search, const std::vector<Curve>& curves,
                              const std::vector<double>& ratios, const Spec& spec) {
  EffectOptions phi_as_given = search.options;
  phi_as_given.phi_terms = 0;
  HeldoutAsGiven out{Problem(collect(search.p, curves, ratios, search.K, search.layout, phi_as_given), search.blocks,
                             search.fine_blocks, search.options.min_derivative),
                     {}};
  out.eval = out.problem.evaluate(spec);
  return out;
}

void complementCheck(EffectSearch& search) {
  // Only beside a selected effect: with none selected, no refit of φ has absorbed anything, and an effect that did
  // not pass its own test around the base fit is not named.
  if (!search.options.refit || search.selected.empty()) return;
  while (true) {
    std::vector<const LevelEffect*> candidates;
    for (const LevelEffect* effect : levelEffects())
      if (search.significant_once.count(effect->name) && !effect->in(search.current) && !effect->not_applicable(search))
        candidates.push_back(effect);
    if (candidates.empty()) return;
    // The selected model's own settled φ (after a backward pass it may not have been refitted with this model).
    const Refitted base = refitWith(search, search.current, search.curves, search.ratios);
    if (!base.ok) return;
    const HeldoutAsGiven without = heldoutAsGiven(search, base.curves, base.ratios, search.current);
    const LevelEffect* best = nullptr;
    Comparison best_cmp;
    Refitted best_refit;
    for (const LevelEffect* effect : candidates) {
      const Spec spec = effect->extend(search.current);
      const Refitted refit = refitWith(search, spec, base.curves, base.ratios);
      if (!refit.ok) continue;
      const HeldoutAsGiven with = heldoutAsGiven(search, refit.curves, refit.ratios, spec);
      if (!physical(spec, with.eval, search.nc, 0)) continue;
      // Its own test (clipping: over its plateau blocks); the samples are the same pixels around either φ.
      const Comparison cmp = effect->test(search, without.eval, with.eval);
      EffectEntry& e = search.entry(effect->name);
      e.parameters["complement_gain"] = cmp.gain;
      e.parameters["complement_z"] = cmp.z;
      if (cmp.gain >= search.options.min_gain && cmp.z >= search.options.min_z && (!best || cmp.gain > best_cmp.gain)) {
        best = effect;
        best_cmp = cmp;
        best_refit = refit;
      }
    }
    if (!best) return;
    search.significant_once.erase(best->name);
    search.selected.push_back(best->name);
    EffectEntry& e = search.entry(best->name);
    e.detected = true;
    e.parameters["complement_named"] = 1;
    e.gain = best_cmp.gain;
    e.statistic = best_cmp.z;
    search.current = search.withSelected();
    search.curves = best_refit.curves;
    search.ratios = best_refit.ratios;
    search.problem = search.problemAround(search.curves, search.ratios);
    search.current_eval = search.problem.evaluate(search.current);
  }
}

}  // namespace crfcal::effect
