// The effect search as named stages over the shared EffectSearch state (effect_problem.hpp):
//   prepare → collect residuals → forward selection (each step: test every candidate, add the best, settle φ)
//   → backward pass → describe the selected model → model checks → refit φ with the selected model.
// effects.hpp describes the models and the criterion.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>

#include "crfcal/error.hpp"
#include "crfcal/response_model.hpp"
#include "effect_problem.hpp"
#include "parallel_jobs.hpp"

namespace crfcal::effect {

const std::vector<const LevelEffect*>& levelEffects() {
  static const std::vector<const LevelEffect*> effects{
      &vignettingEffect(),
      &blackLevelOffsetEffect(),
      &clippingEffect(),
      &channelMixingEffect(),
  };
  return effects;
}

const std::vector<const ModelCheck*>& modelChecks() {
  static const std::vector<const ModelCheck*> checks{
      &spatiallyVaryingBlurCheck(),    // around the selected model's φ
      &exposureRatioMismatchCheck(),   // within the selected model
      &signalDependentNoiseCheck(),    // on I itself
  };
  return checks;
}

namespace {

const LevelEffect& levelEffect(const std::string& name) {
  for (const LevelEffect* effect : levelEffects())
    if (name == effect->name) return *effect;
  throw Error("unknown effect " + name);
}

void collectResiduals(EffectSearch& search) {
  for (const auto& name : search.in.channels) search.ratios.push_back(search.in.fits.at(name).ratio);
  search.problem = search.problemAround(search.curves, search.ratios);
  search.report.samples = static_cast<int>(search.problem.samples()[0].size());
  search.used_fine.assign(search.fine_blocks, 0);
  for (int b : search.problem.samples()[0].fine) search.used_fine[b] = 1;
}

// How far the extended model moves φ (its re-fit vs the current model's, both on all samples; RMSE over [0, 1],
// clipping: below the plateau, above it nothing is measured; worst channel). A linearised first step: the refit
// rounds move φ further.
double phiChange(const EffectSearch& search, const LevelEffect& effect, const Evaluation& be, const Evaluation& ee) {
  const int nc = search.nc, terms = search.terms;
  double phi_change = 0;
  for (int c = 0; c < nc; ++c) {
    if (!be.full[c].ok || !ee.full[c].ok) continue;
    const auto pb = adjustedPhi(search.curves[c].phi, coefficients(search.current, be.full[c], c, nc, terms).alpha);
    const auto pe =
        adjustedPhi(search.curves[c].phi, coefficients(effect.extend(search.current), ee.full[c], c, nc, terms).alpha);
    std::size_t top = pb.size();
    if (effect.phi_change_below_plateau && ee.full[c].clip > 0 && ee.full[c].clip <= 1)
      top = static_cast<std::size_t>(ee.full[c].clip * (pb.size() - 1)) + 1;
    phi_change = std::max(phi_change, curveRmse(std::vector<double>(pb.begin(), pb.begin() + top),
                                                std::vector<double>(pe.begin(), pe.begin() + top)));
  }
  return phi_change;
}

// Tests every candidate against the current model (entries updated). Attribution, not a race: of the candidates
// that pass their own test, the one that leaves the smallest held-out error on ALL held-back pixels is chosen
// (each candidate fitted on one fold, measured on the other, around the same φ), so a local test (clipping's
// plateau blocks) cannot outbid an effect that explains more of the pair; its evidence against the runner-up is
// recorded (effect_attribution.cpp). Returns the winner's name and evaluation, or an empty name.
std::string bestCandidate(EffectSearch& search, Evaluation& best_eval) {
  const std::vector<Candidate> candidates =
      levelCandidates(search, search.problem, search.current, search.current_eval);
  const Candidate* winner = nullptr;
  for (const Candidate& c : candidates) {
    EffectEntry& e = search.entry(c.name);
    e.tested = true;
    e.gain = c.cmp.gain;
    e.statistic = c.cmp.z;
    e.parameters["phi_change"] = phiChange(search, levelEffect(c.name), search.current_eval, c.eval);
    if (c.plausible)
      search.not_considered.erase(c.name);
    else
      search.not_considered[c.name] =
          c.flattened.empty() ? "the extended model's parameters are not physical (runaway fit): not considered"
                              : "its phi re-fit is nearly constant over the data in " + c.flattened +
                                    ", where phi is not (the verdict's flat rule): not a physical explanation, not "
                                    "considered";
    if (c.passes && (!winner || c.eval.total < winner->eval.total)) winner = &c;
  }
  if (!winner) return {};
  recordRunnerUp(search, *winner, candidates);
  best_eval = winner->eval;
  return winner->name;
}

// One round: the pair corrected with the current model and φ refitted (or, without refits, φ moved by the model's
// own re-fit); the residuals re-collected and the model re-evaluated around the new φ. Returns how far φ moved
// (RMSE, worst channel), or a negative value when nothing moved.
double settleRound(EffectSearch& search) {
  const int nc = search.nc;
  bool moved = false;
  double phi_moved = 0;
  std::vector<Coefficients> cc(nc);
  for (int c = 0; c < nc; ++c)
    if (search.current_eval.full[c].ok)
      cc[c] = coefficients(search.current, search.current_eval.full[c], c, nc, search.terms);
  const auto fits = search.options.refit
                        ? refitPair(search, search.current, search.curves, cc, search.current_eval.full, false, false,
                                    0.0)
                              .fits
                        : std::map<std::string, CrfFitResult>{};
  for (int c = 0; c < nc; ++c) {
    if (!search.current_eval.full[c].ok) continue;
    const std::vector<double> before = search.curves[c].phi;
    if (!fits.empty()) {
      search.curves[c] = makeCurve(fits.at(search.in.channels[c]).inverse_crf);
      search.ratios[c] = fits.at(search.in.channels[c]).ratio;
    } else {
      search.curves[c] = makeCurve(adjustedPhi(search.curves[c].phi, cc[c].alpha));
      search.ratios[c] = cc[c].scale;
    }
    phi_moved = std::max(phi_moved, curveRmse(before, search.curves[c].phi));
    moved = true;
  }
  if (!moved) return -1;
  search.problem = search.problemAround(search.curves, search.ratios);
  search.current_eval = search.problem.evaluate(search.current);
  return phi_moved;
}

// The next effects are tested around the grown model's own φ (the linearised re-fit stays local): rounds until φ
// settles (refit_rounds at most). One round left structure that a companion effect then "explained": planted
// channel mixing was then named with a companion far more often (docs/RESULTS.md#effects).
void settle(EffectSearch& search) {
  for (int round = 0; round < std::max(1, search.options.refit_rounds); ++round) {
    const double phi_moved = settleRound(search);
    if (phi_moved < 0 || phi_moved < 5e-4) break;  // settled: well below the 0.005 accuracy φ is judged by
  }
}

// Greedy forward selection of the level effects: the largest significant held-out gain first, then φ settled
// around the grown model, so one planted effect does not make its confounders fire.
void forwardSelection(EffectSearch& search) {
  search.current_eval = search.problem.evaluate(search.current);
  search.report.base_error = search.current_eval.count > 0 ? search.current_eval.total / search.current_eval.count : 0;
  for (const LevelEffect* effect : levelEffects())
    if (const char* why = effect->not_applicable(search)) search.entry(effect->name).detail = why;
  while (true) {
    Evaluation best_eval;
    const std::string best = bestCandidate(search, best_eval);
    if (best.empty()) break;
    search.selected.push_back(best);
    search.entry(best).detected = true;
    search.current = search.withSelected();
    search.current_eval = best_eval;
    settle(search);
  }
}

// With two or more effects selected, each must still pass the same test inside the final model (the model without
// it vs the final one, around the final φ): greedy forward selection keeps a companion that only absorbed what the
// first effect's unsettled re-fit left behind (measured on planted channel mixing, docs/RESULTS.md#effects). The
// weakest failing one is dropped, until all pass.
void backwardPass(EffectSearch& search) {
  const EffectOptions& options = search.options;
  while (search.selected.size() >= 2) {
    std::string weakest;
    double weakest_gain = std::numeric_limits<double>::infinity();
    Comparison weakest_cmp;
    for (const auto& name : search.selected) {
      const Comparison cmp = levelEffect(name).test(search, search.problem.evaluate(search.withSelected(name)),
                                                    search.current_eval);
      if (!(cmp.gain >= options.min_gain && cmp.z >= options.min_z) && cmp.gain < weakest_gain) {
        weakest = name;
        weakest_gain = cmp.gain;
        weakest_cmp = cmp;
      }
    }
    if (weakest.empty()) break;
    search.selected.erase(std::find(search.selected.begin(), search.selected.end(), weakest));
    EffectEntry& e = search.entry(weakest);
    e.detected = false;
    e.gain = weakest_cmp.gain;
    e.statistic = weakest_cmp.z;
    e.parameters["dropped_by_backward_pass"] = true;
    search.current = search.withSelected();
    search.current_eval = search.problem.evaluate(search.current);
  }
}

// Parameters of the selected model (fitted on all samples); the other level effects' parameters as if added to it.
void describeSelectedModel(EffectSearch& search) {
  const int nc = search.nc;
  for (int c = 0; c < nc; ++c)
    search.coef.push_back(search.current_eval.full[c].ok
                              ? coefficients(search.current, search.current_eval.full[c], c, nc, search.terms)
                              : Coefficients{});
  std::vector<const LevelEffect*> effects;
  for (const LevelEffect* effect : levelEffects())
    if (!effect->not_applicable(search)) effects.push_back(effect);
  // The fits of the model extended by each effect not in it are independent: one per core, the dearest first
  // (a plateau level grid, then the coupled channels of mixing), so that no long fit starts last.
  const int n = static_cast<int>(effects.size());
  std::vector<Evaluation> extended(n);
  std::vector<Spec> models;
  for (const LevelEffect* effect : effects) models.push_back(effect->extend(search.current));
  const std::vector<std::exception_ptr> errors =
      detail::runInParallelDearestFirst(dearestFitsFirst(models, 1), [&](int i) {
        if (!effects[i]->in(search.current))
          extended[i] = search.problem.evaluate(models[static_cast<std::size_t>(i)], false);
      });
  for (int i = 0; i < n; ++i) {
    if (errors[i]) std::rethrow_exception(errors[i]);
    const LevelEffect& effect = *effects[i];
    EffectEntry& e = search.entry(effect.name);
    if (effect.in(search.current)) effect.describe(search, search.current, search.current_eval, e);
    else effect.describe(search, extended[i].spec, extended[i], e);
    const auto why = search.not_considered.find(effect.name);
    if (why != search.not_considered.end() && !e.detected) e.detail += "; " + why->second;
  }
}

// The level effect that explains a ratio mismatch with r at EXIF's value (effect_exposure_ratio_mismatch.cpp) is
// named and joins the selected model, whose parameters are described again; the refit then corrects for it.
void nameInsteadOfRatio(EffectSearch& search) {
  if (search.ratio_explained_by.empty()) return;
  search.selected.push_back(search.ratio_explained_by);
  search.entry(search.ratio_explained_by).detected = true;
  search.current = search.withSelected();
  search.current_eval = search.problem.evaluate(search.current);
  search.coef.clear();
  describeSelectedModel(search);
}

// φ from the selected model: the pair corrected and φ refitted, `refit_rounds` times (parameters and φ_ext
// re-estimated with each refitted φ). A wrong EXIF ratio can also trap the fitter (it starts from r_EXIF): with
// only exposure_ratio_mismatch, φ is refitted from the diagnostics' ratio when the fitter's own r differs by > 2 %.
// Returns whether the refit ran for the ratio alone (no level effect, no noise law): the refit confirmRatioMismatch
// discards when the mismatch is not confirmed.
bool refitWithSelectedModel(EffectSearch& search) {
  const EffectInputs& in = search.in;
  const int nc = search.nc;
  const Spec& current = search.current;
  const bool blur_refit = search.entry("spatially_varying_blur").detected;  // detected only when tested
  const bool level_refit = current.vignetting || current.offset || current.mixing || current.clipping || blur_refit;
  const bool noise_refit = search.noise_detected && in.fit.experimental.noise != NoiseHandling::none;
  bool ratio_refit = false;
  if (search.entry("exposure_ratio_mismatch").detected)
    for (int c = 0; c < nc; ++c) {
      const double fitter_ratio = in.fits.at(in.channels[c]).ratio;
      if (search.current_eval.full[c].ok && std::abs(fitter_ratio / search.coef[c].scale - 1) > 0.02) ratio_refit = true;
    }
  if (!(search.options.refit && (level_refit || noise_refit || ratio_refit))) return false;
  std::vector<Curve> cur = search.curves;
  std::vector<Coefficients> cf = search.coef;
  std::vector<ChannelFit> ff = search.current_eval.full;
  for (int round = 0; round < search.options.refit_rounds; ++round) {
    PairRefit refit = refitPair(search, current, cur, cf, ff, blur_refit, noise_refit, 0.0);
    if (refit.fits.empty()) {
      // A later round's failure keeps the earlier round's refit; a first round's is reported (the guard records it).
      if (round == 0) search.refit_failure = std::move(refit.failure);
      break;
    }
    search.report.fits = std::move(refit.fits);
    if (round + 1 == search.options.refit_rounds || !level_refit) break;
    // Re-estimate the parameters (and φ_ext) with the refitted φ.
    for (int c = 0; c < nc; ++c) cur[c] = makeCurve(search.report.fits.at(in.channels[c]).inverse_crf);
    std::vector<double> rr;
    for (const auto& name : in.channels) rr.push_back(search.report.fits.at(name).ratio);
    const Evaluation ev = search.problemAround(cur, rr).evaluate(current, false);
    for (int c = 0; c < nc; ++c)
      if (ev.full[c].ok) {
        cf[c] = coefficients(current, ev.full[c], c, nc, search.terms);
        ff[c] = ev.full[c];
      }
  }
  return !(level_refit || noise_refit);
}

// exposure_ratio_mismatch is named from the linearised model's scale a, which re-fits φ by four EMoR terms only and
// is a poor estimate of r on real-regime pairs (bench pairs --ratio 8, clean pairs, EXIF 8.32, truth 8: a = 12.3 and
// 10.9 where the fitter's r is 7.89 and 7.62, docs/RESULTS.md#ratio-check-free-r; that gap came from the search's
// debias of I's darkest codes, now applied only when the fit debiases, docs/RESULTS.md#effects-debias; a camera colour
// matrix planted at r ≈ 6 still gives a 47 % off EXIF). EXIF r of a real camera is good to a few per cent
// (issue 18), so the mismatch stays named only when the full fit of the seed's model agrees: the fitter started from
// a with r free (the ratio-only refit when that ran; the base fit when its r was within 2 % of a) returns an r
// beyond EXIF's tolerance on a's side. A refit with level effects is no such witness: it may trade an offset for the
// exponent (r → r^γ; the refit guard judges it). Otherwise the name is withdrawn, a refit made for the ratio alone is
// discarded, and the pair's ratio evidence (pair_stage_ratio.cpp) combines the images' r with EXIF as for any pair
// whose EXIF was not found off. A fixed r (the user's, or held at EXIF for a blur too small to fix it) is not
// confirmed or withdrawn here: the naming stays as the held-out test made it.
void confirmRatioMismatch(EffectSearch& search, bool ratio_only_refit) {
  EffectEntry& e = search.entry("exposure_ratio_mismatch");
  const EffectInputs& in = search.in;
  if (!e.detected || !in.fit.fit_ratio) return;
  const std::size_t g = static_cast<std::size_t>(search.g_index);
  const std::string& green = in.channels[g];
  const double a = search.coef[g].scale;
  double full_ratio = in.fits.at(green).ratio;
  if (ratio_only_refit && search.report.fits.count(green)) {
    full_ratio = search.report.fits.at(green).ratio;
  } else if (std::abs(full_ratio / a - 1) > 0.02) {
    CrfFitOptions fo = in.fit;
    fo.progress = nullptr;
    fo.nominal_ratio = a;
    try {
      full_ratio = fitInverseCrf(in.sharp.at(green), in.blurred.at(green), search.K, fo).ratio;
    } catch (const InvalidInput&) {
      // no full fit from a: the base fit's r (started from EXIF) stands as the witness
    }
  }
  const double rel_full = full_ratio / in.nominal_ratio - 1, rel_a = a / in.nominal_ratio - 1;
  e.parameters["full_fit_ratio"] = full_ratio;
  if (std::abs(rel_full) > search.options.ratio_tolerance && rel_full * rel_a > 0) return;
  e.detected = false;
  e.parameters["not_confirmed_by_full_fit"] = 1;
  e.detail += fmt("; not named: the full fit from r %.4g returned r %.4g (%+.1f%% from EXIF), within EXIF's tolerance "
                  "or on its other side",
                  a, full_ratio, 100 * rel_full);
  if (ratio_only_refit) {  // the refit made for the ratio alone is discarded, and so is its failure
    search.report.fits.clear();
    search.refit_failure.clear();
  }
}

}  // namespace

}  // namespace crfcal::effect

namespace crfcal {

EffectReport diagnoseEffects(const EffectInputs& in, const EffectOptions& options) {
  using namespace effect;
  options.check();
  const auto start = std::chrono::steady_clock::now();
  EffectSearch search(in, options);
  if (!options.enabled) {
    for (auto& e : search.report.entries) e.detail = "diagnostics disabled";
    return search.report;
  }
  if (!prepareProblem(search)) {
    for (auto& e : search.report.entries) e.detail = "too few usable pixels";
    return search.report;
  }
  collectResiduals(search);
  forwardSelection(search);
  backwardPass(search);
  describeSelectedModel(search);
  for (const ModelCheck* check : modelChecks()) check->run(search);
  nameInsteadOfRatio(search);
  const bool ratio_only_refit = refitWithSelectedModel(search);
  confirmRatioMismatch(search, ratio_only_refit);
  guardRefit(search);
  search.report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return search.report;
}

}  // namespace crfcal
