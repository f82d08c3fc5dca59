// Stage "band" of calibratePair: per channel, the pointwise band of φ (curve_band.hpp) — half-sample refits of the
// fit window's blocks with the final kernel and the fit's options, and the exponent bounds beyond the covered range.
// When an effect's extended model supplied φ, the refits are of the base fitter: the band then measures the base
// estimator's sampling spread around the reported curve.
#include <optional>
#include <string>

#include "crfcal/band_ratio_term.hpp"
#include "crfcal/kernel.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

void estimateBands(PairCalibrationState& state) {
  PairCalibrationResult& result = state.result;
  const auto start = Clock::now();
  const cv::Mat kernel = cropKernel(state.kernel, 0.0);  // as fitChannel hands it to the fitter
  // r held at the combination of the images and EXIF (ratio_evidence.hpp) is still uncertain: each refit fits it
  // again from its half and combines it with EXIF by the pair's weights (ReplicateRatioRule), so that the band
  // carries the combined r's spread, not the images' alone. A user's --fix-ratio stays fixed.
  CrfFitOptions fit_options = state.fit_options;
  std::optional<ReplicateRatioRule> ratio_rule;
  if (result.ratio_from_evidence) {
    fit_options.fit_ratio = true;
    const RatioEvidence& evidence = result.ratio_evidence;
    if (state.options.band.replicates_combine_ratio)
      ratio_rule = ReplicateRatioRule{evidence.images_weight, evidence.images_ratio, evidence.ratio};
  }
  // The error of r every half shares (the images' exponent floor, EXIF's own), scaled by how well the two agree
  // (band_ratio_term.hpp); 0 at r = 1 with the images' r (no floor there), and without evidence (no nominal ratio,
  // r held for a small blur or by --fix-ratio).
  RatioTermInputs ratio_inputs;
  ratio_inputs.reported_from_evidence = result.ratio_from_evidence;
  ratio_inputs.halves_combine = ratio_rule.has_value();
  ratio_inputs.sigma = state.options.band.ratio_term_sigma;
  ratio_inputs.level = state.options.band.level;
  // A σ below the evidence's own threshold of a worthwhile change of r (0.5 %) is not worth two fits: at r = 1 the
  // floor is ~1e-4 (0.072·|log r_images| with r_images within 0.7 % of 1) and φ would move by ~1e-6.
  double ratio_log_sigma = ratioLogSigmaUnseenByHalves(result.ratio_evidence, ratio_inputs);
  if (ratio_log_sigma < state.options.ratio_evidence.min_relative_change) ratio_log_sigma = 0;
  int done = 0;
  for (const auto& name : result.channels) {
    const auto covered = result.covered_range.find(name);
    if (covered == result.covered_range.end() || !result.fits.count(name)) continue;
    state.report("band", double(done++) / result.channels.size(), name);
    // A channel fitted where the sharp shot's chroma is flat: its refits too (as fitChannel's options).
    CrfFitOptions channel_options = fit_options;
    if (const auto bound = state.window_sharp_error.find(name); bound != state.window_sharp_error.end())
      channel_options.sharp_error_bound = bound->second;
    result.bands[name] = estimateCurveBand(state.window_sharp.at(name), state.window_blurred.at(name), kernel,
                                           channel_options, result.fits.at(name), covered->second,
                                           state.options.band, ratio_rule, ratio_log_sigma);
  }
  result.timings["band"] = secondsSince(start);
  state.report("band", 1);
}

}  // namespace crfcal::detail
