// Stage "ratio evidence" of calibratePair (ratio_evidence.hpp, issue 17 item 3): after the effects, the
// images' r (φ_G's fit with the final kernel) is combined with the nominal ratio (EXIF or --ratio) by their
// precisions, the images' own measured on half-sample refits of the same fit. When the combination moves r, every
// channel is refitted with r held at the combined value (r is the exposure's, common to all channels).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

#include "crfcal/curve_band.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/ratio_evidence.hpp"
#include "crfcal/simex.hpp"
#include "effect_problem.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

namespace {

// log r_SIMEX − log r of φ_G (simex.hpp: linear in λ through 0, 0.5, 1; one draw each): the noise bias of the images'
// r, which every half-sample shares. 0 when the refits fail.
double noiseBiasOfRatio(PairCalibrationState& state) {
  state.report("ratio", 0.3, "noise bias (SIMEX)");
  SimexOptions simex;
  simex.added_variance_multiples = {0.5, 1.0};
  simex.replicates = 1;
  simex.extrapolation_degree = 1;
  simex.seed = state.options.band.seed;
  SimexSummary summary;
  try {
    const CrfFitResult corrected = fitInverseCrfSimex(state.window_sharp.at("G"), state.window_blurred.at("G"),
                                                      cropKernel(state.kernel, 0.0), state.fit_options, simex, &summary);
    if (summary.extrapolated && corrected.ratio > 0 && summary.ratios.front() > 0)
      return std::log(corrected.ratio / summary.ratios.front());
  } catch (const InvalidInput&) {
    // the naive refit failed: no bias measured (the half-sample spread and the floor remain)
  }
  return 0;
}

bool namedByEffects(const PairCalibrationResult& result, const std::string& effect) {
  const std::vector<std::string> named = result.effects.detected();
  return std::find(named.begin(), named.end(), effect) != named.end();
}

// The warning of a conflict between the images' r and the nominal ratio, with what was decided.
std::string conflictWarning(const RatioEvidence& evidence, const std::string& nominal_name) {
  const char* decided =
      evidence.decision == RatioDecision::nominal_held
          ? "the shots' brightness sides with the nominal ratio; r held there, the curve's exponent rests on it"
      : evidence.decision == RatioDecision::images_kept
          ? "the shots' brightness sides with the images; the nominal ratio set aside"
          : "the shots' brightness does not tell which is off; r is their combination";
  char buffer[400];
  std::snprintf(buffer, sizeof buffer, "the images' r (%.3g) and %s (%.4g) differ by %.1f sigma of their difference: %s (r %.4g)",
                evidence.images_ratio, nominal_name.c_str(), evidence.nominal_ratio, evidence.conflict_sigmas, decided,
                evidence.ratio);
  return buffer;
}

// Whether the effects' adopted refit is a spatially varying blur's alone (no level effect named). It changes the
// kernel model, not the levels, and holds r at the tiles' own r from the images — the r this stage weighs against
// the nominal ratio, not a level effect's r that explains the misfit.
bool varyingBlurRefitAlone(const PairCalibrationResult& result) {
  if (result.base_fits.empty() || !namedByEffects(result, "spatially_varying_blur")) return false;
  for (const effect::LevelEffect* level : effect::levelEffects())
    if (namedByEffects(result, level->name)) return false;
  return true;
}

}  // namespace

void combineRatioWithNominal(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  const RatioEvidenceOptions& ro = options.ratio_evidence;
  PairCalibrationResult& result = state.result;
  // A user's fixed r (--fix-ratio) and the small-blur hold leave nothing to combine; without a nominal ratio
  // there is no second source.
  if (!ro.enabled || !state.fit_options.fit_ratio || !(options.fit.nominal_ratio > 0) || !result.fits.count("G"))
    return;
  const auto start = Clock::now();
  state.report("ratio", 0, "half-sample refits");
  const bool blur_alone = varyingBlurRefitAlone(result);
  const CrfFitResult& green = blur_alone ? result.base_fits.at("G") : result.fits.at("G");
  const HalfSampleRefits refits =
      refitOnHalfSamples(state.window_sharp.at("G"), state.window_blurred.at("G"), cropKernel(state.kernel, 0.0),
                         state.fit_options, green.pixels.used_mask, ro.replicates, ro.block_size, options.band.seed);
  const VerdictOptions& vo = options.verdict;  // the brightness interval as the verdict judges it
  const std::pair<double, double> brightness =
      brightnessRatioInterval(brightnessRatio(state, "G"), vo.brightness_ratio_exponent_min,
                              vo.brightness_ratio_exponent_max, vo.max_ratio_factor);
  const double noise_bias_log = ro.measure_noise_bias ? noiseBiasOfRatio(state) : 0;
  RatioEvidence evidence = combineRatioEvidence(green.ratio, refits.ratios, options.fit.nominal_ratio, ro,
                                                brightness, noise_bias_log);
  evidence.failed_replicates = refits.failed;
  // The effects ran first (pair_calibration.cpp): an extended model they adopted explains the misfit with its own r
  // (refitting the base model would discard it), and an exposure_ratio_mismatch they named is EXIF found off on
  // held-back pixels — stronger than the precisions above, unless the shots' brightness sided with EXIF in a conflict.
  const bool moves = evidence.combined && std::abs(evidence.ratio / evidence.images_ratio - 1) > ro.min_relative_change;
  // A varying blur's refit held the images' r along the exponent valley φ^γ, r^γ; when the evidence moves r, the
  // base model refitted at the combined r replaces it (measured at r ≈ 6: the blur beside a knee, shape 0.018 →
  // 0.009; nothing else changed in the effect benches, docs/RESULTS.md#effects-tile-kernels).
  if (moves && blur_alone) {
    result.fits = result.base_fits;
    result.base_fits.clear();
    result.effects.refit_adopted = false;
    result.effects.rejected_fits = std::move(result.effects.fits);
    result.effects.fits.clear();
    result.effects.refit_rejected_reason =
        "the varying blur's refit holds the images' r; the pair's ratio evidence moves r, and the base model is "
        "refitted there";
  }
  if (moves && !result.base_fits.empty())
    evidence.not_adopted_reason = "an effect's extended model supplied the fits (its own r kept)";
  else if (moves && evidence.decision != RatioDecision::nominal_held && namedByEffects(result, "exposure_ratio_mismatch"))
    evidence.not_adopted_reason = "the effect diagnostics found the nominal ratio off on held-back pixels";
  if (moves && evidence.not_adopted_reason.empty()) {
    state.report("ratio", 0.5, "refit with the combined r");
    state.fit_options.fit_ratio = false;
    state.fit_options.nominal_ratio = evidence.ratio;
    result.ratio_from_evidence = true;
    // Same fallback as the rounds for the chroma model (a subsampled sharp JPEG) leaving too few pixels.
    for (auto& [name, fit] : fitChannels(state, result.channels, state.kernel, false)) result.fits[name] = std::move(fit);
  }
  if (evidence.conflict) result.warnings.push_back(conflictWarning(evidence, options.nominal_ratio_name));
  evidence.seconds = secondsSince(start);
  result.ratio_evidence = evidence;
  result.timings["ratio_evidence"] = evidence.seconds;
  state.report("ratio", 1);
}

}  // namespace crfcal::detail
