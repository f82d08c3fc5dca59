#include "crfcal/pair_calibration.hpp"

#include <cstdio>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "pair_stages.hpp"

// calibratePair as a sequence of named stages over one state (pair_stages.hpp says which file holds which stage).

namespace crfcal {

void PairCalibrationOptions::check() const {
  registration.check();
  kernel.check();
  tiles.check();
  fit.check();
  if (rounds < 0 || rounds > 10) throw InvalidInput("rounds must be in 0..10");
  if (max_kernel_size != 0 &&
      (max_kernel_size % 2 == 0 || max_kernel_size < kernel.kernel_size || max_kernel_size > 151))
    throw InvalidInput("max_kernel_size must be 0 (automatic) or odd, at least kernel_size and at most 151");
  if (!(saturated_frame_limit > 0 && saturated_frame_limit <= 1)) throw InvalidInput("saturated_frame_limit in (0,1]");
  if (max_fit_side < 128) throw InvalidInput("max_fit_side must be >= 128");
  if (!(min_blur_radius >= 0)) throw InvalidInput("min_blur_radius must be >= 0");
  if (!(min_covered_span >= 0 && min_covered_span <= 1)) throw InvalidInput("min_covered_span must be in [0, 1]");
  if (!(irradiance_kernel_lambda >= 0)) throw InvalidInput("irradiance_kernel_lambda must be >= 0");
  if (!(small_blur_ratio_tolerance >= 0)) throw InvalidInput("small_blur_ratio_tolerance must be >= 0");
  effects.check();
  band.check();
  verdict.check();
  ratio_evidence.check();
  chroma_detail.check();
  if (!(chroma_replacement_min_ambiguity_rise >= 0))
    throw InvalidInput("chroma_replacement_min_ambiguity_rise must be >= 0");
  chroma_choice.check();
  for (const ChromaSubsampling& c : {sharp_chroma, sharp_stored_chroma})
    if (c.h < 1 || c.v < 1 || c.h > 4 || c.v > 4) throw InvalidInput("chroma sampling factors must be 1..4");
}

cv::Point2d PairCalibrationResult::tileCentreInBlurred(const TileKernel& t) const {
  const cv::Rect& rect = tiles.at(static_cast<std::size_t>(t.tile)).rect;
  const std::vector<cv::Point2d> centre{{rect.x + 0.5 * (rect.width - 1), rect.y + 0.5 * (rect.height - 1)}};
  std::vector<cv::Point2d> in_blurred;
  cv::perspectiveTransform(centre, in_blurred, registration.homography);
  return in_blurred.front();
}

std::string PairCalibrationResult::summary() const {
  std::string text = "registration: " + registration.summary() + "\nkernel: " + kernel.summary();
  if (tile_kernels.size() > 1) text += "\nspatial variation: " + disagreement.summary();
  for (const auto& round : rounds) {
    char buffer[200];
    std::snprintf(buffer, sizeof buffer, "\nround %d: kernel change %.3f, phi change %.4f, r %.4f", round.round,
                  round.kernel_change, round.phi_change, round.ratio);
    text += buffer;
  }
  for (const auto& [name, fit] : fits) text += "\n" + name + ": " + fit.summary();
  for (const auto& [name, band] : bands) text += "\nband " + name + ": " + band.summary();
  if (!effects.entries.empty()) text += "\n" + effects.summary();
  return text;
}

PairCalibrationResult calibratePair(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options) {
  options.check();
  const bool transposed = detail::checkPairShapes(sharp, blurred, options);
  detail::PairCalibrationState state(options);
  state.register_start = detail::Clock::now();
  state.blurred = blurred;
  if (transposed)
    detail::turnSharpShot(state, sharp);  // registers too
  else
    state.sharp = sharp;
  detail::markChromaDetail(state, sharp);
  detail::splitPlanes(state);
  detail::checkExposureAndEdges(state);
  detail::registerShots(state);
  try {
    detail::estimateFirstKernelAdmittingBlack(state);
  } catch (const InvalidInput& e) {
    // The reason names where the kernel's pixels went (usablePixelsNote): a pair whose sharp shot is black where the
    // blurred one is clipped, or flat, has no edges even with its black admitted.
    const std::string& reason = e.reason();
    // A kernel that cannot explain one shot by the other, on a pair whose edges barely correlate: two scenes
    // (issue 15: the size-limit advice would only lead to "no edges").
    if (state.same_scene_correlation >= detail::doubtful_same_scene_correlation)
      throw InvalidInput(reason, e.subject());
    // Not only two scenes: a real-regime pair whose sharp shot is dark and noisy also correlates this little
    // (measured: 0.42 at r ≈ 6, `bench effects --ratio 6 --jpeg 90 --handheld`), so both causes are named.
    char correlation[16];
    std::snprintf(correlation, sizeof correlation, "%.2f", state.same_scene_correlation);
    throw InvalidInput("the kernel estimate failed (" + reason + "), and the two images' edges correlate only " +
                           correlation + " after registration: they may not show the same scene, or the sharp "
                           "shot is too dark or noisy to show its edges",
                       ErrorSubject::pair);
  }
  detail::chooseFitWindow(state);
  detail::fitKernelPhiRounds(state);
  if (options.effects.enabled) detail::diagnoseResidualEffects(state);
  detail::combineRatioWithNominal(state);
  detail::checkPointwiseChroma(state);
  detail::summariseFits(state);
  if (options.band.replicates > 0) detail::estimateBands(state);
  detail::computeVerdict(state);
  if (options.keep_fit_inputs) {
    PairFitInputs& inputs = state.result.fit_inputs;
    inputs.sharp = std::move(state.window_sharp);
    inputs.blurred = std::move(state.window_blurred);
    inputs.sharp_error = std::move(state.window_sharp_error);
    inputs.kernel = cropKernel(state.kernel, 0.0);  // as fitChannel hands it to the fitter
    inputs.options = state.fit_options;
    inputs.options.progress = nullptr;
  }
  return std::move(state.result);
}

}  // namespace crfcal
