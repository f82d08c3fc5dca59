// Stage "ratio evidence" of calibratePair (ratio_evidence.hpp, issue 17 item 3): after the kernel↔φ rounds, the
// images' r (φ_G's fit with the final kernel) is combined with the nominal ratio (EXIF or --ratio) by their
// precisions, the images' own measured on half-sample refits of the same fit. When the combination moves r, every
// channel is refitted with r held at the combined value (r is the exposure's, common to all channels).
#include <cmath>
#include <cstdio>
#include <string>

#include "crfcal/curve_band.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/ratio_evidence.hpp"
#include "crfcal/simex.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

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
  const CrfFitResult& green = result.fits.at("G");
  const HalfSampleRefits refits =
      refitOnHalfSamples(state.window_sharp.at("G"), state.window_blurred.at("G"), cropKernel(state.kernel, 0.0),
                         state.fit_options, green.pixels.used_mask, ro.replicates, ro.block_size, options.band.seed);
  const VerdictOptions& vo = options.verdict;  // the brightness interval as the verdict judges it
  const std::pair<double, double> brightness =
      brightnessRatioInterval(brightnessRatio(state, "G"), vo.brightness_ratio_exponent_min,
                              vo.brightness_ratio_exponent_max, vo.max_ratio_factor);
  double noise_bias_log = 0;
  if (ro.measure_noise_bias) {
    state.report("ratio", 0.3, "noise bias (SIMEX)");
    SimexOptions simex;
    simex.added_variance_multiples = {0.5, 1.0};
    simex.replicates = 1;
    simex.extrapolation_degree = 1;
    simex.seed = options.band.seed;
    SimexSummary summary;
    try {
      const CrfFitResult corrected = fitInverseCrfSimex(state.window_sharp.at("G"), state.window_blurred.at("G"),
                                                        cropKernel(state.kernel, 0.0), state.fit_options, simex, &summary);
      if (summary.extrapolated && corrected.ratio > 0 && summary.ratios.front() > 0)
        noise_bias_log = std::log(corrected.ratio / summary.ratios.front());
    } catch (const InvalidInput&) {
      // the naive refit failed: no bias measured (the half-sample spread and the floor remain)
    }
  }
  RatioEvidence evidence = combineRatioEvidence(green.ratio, refits.ratios, options.fit.nominal_ratio, ro,
                                                brightness, noise_bias_log);
  evidence.failed_replicates = refits.failed;
  if (evidence.combined && std::abs(evidence.ratio / evidence.images_ratio - 1) > ro.min_relative_change) {
    state.report("ratio", 0.5, "refit with the combined r");
    state.fit_options.fit_ratio = false;
    state.fit_options.nominal_ratio = evidence.ratio;
    result.ratio_from_evidence = true;
    for (const auto& name : result.channels) {
      try {
        result.fits[name] = fitChannel(state, name, state.kernel);
      } catch (const InvalidInput& e) {
        // Same fallback as the rounds: the chroma model (a subsampled sharp JPEG) leaving too few pixels.
        if (!state.window_sharp_error.count(name)) throw;
        state.window_sharp_error.erase(name);
        result.fits[name] = fitChannel(state, name, state.kernel);
      }
    }
  }
  if (evidence.conflict) {
    char buffer[400];
    std::snprintf(buffer, sizeof buffer,
                  "the images' r (%.3g) and %s (%.4g) differ by %.1f sigma of their difference: %s (r %.4g)",
                  evidence.images_ratio, options.nominal_ratio_name.c_str(), evidence.nominal_ratio,
                  evidence.conflict_sigmas,
                  evidence.decision == RatioDecision::nominal_held
                      ? "the shots' brightness sides with the nominal ratio; r held there, the curve's exponent rests on it"
                  : evidence.decision == RatioDecision::images_kept
                      ? "the shots' brightness sides with the images; the nominal ratio set aside"
                      : "the shots' brightness does not tell which is off; r is their combination",
                  evidence.ratio);
    result.warnings.push_back(buffer);
  }
  evidence.seconds = secondsSince(start);
  result.ratio_evidence = evidence;
  result.timings["ratio_evidence"] = evidence.seconds;
  state.report("ratio", 1);
}

}  // namespace crfcal::detail
