// Stage "verdict" of calibratePair: the diagnostic maps on G (the blur inconsistency Γ of Sec. 3, the fit's
// weights), the warnings a user acts on — a small blur (r weakly determined or held), kernels that disagree
// across the frame, few edge pixels, an underexposed sharp shot, data that cover only part of the intensities — and
// the verdict per channel (channel_verdict.hpp), with the shots' brightness ratio it needs. Two calls: summariseFits
// before the band stage (the band is built over the covered ranges set here), computeVerdict after it (the band's
// shape width is one of the verdict's grounds).
#include <algorithm>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/channel_verdict.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/error.hpp"
#include "crfcal/exposure_fit.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"
#include "image_units.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {
namespace {

// Γ = B − I ⊗ K on G, only where both shots have data under the whole kernel; the G fit's used pixels.
void diagnosticMaps(PairCalibrationState& state) {
  PairCalibrationResult& result = state.result;
  const cv::Mat& K = state.kernel;
  result.gamma_map =
      blurInconsistency(unit(state.window_blurred.at("G")), convolve(unit(state.window_sharp.at("G")), K));
  cv::Mat inside;
  cv::erode(state.overlap(result.fit_window), inside, cv::getStructuringElement(cv::MORPH_RECT, K.size()),
            cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  result.gamma_map.setTo(0, ~inside);
  result.weights = result.fits["G"].pixels.used_mask;
}

// Blur extent: with almost no blur only a weak blur inconsistency (Sec. 3) separates φ^γ, r^γ from φ, r.
void blurWarnings(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  const CrfFitOptions& fit_options = state.fit_options;
  result.blur_radius = kernelRmsRadius(state.kernel);
  char buffer[400];
  if (result.ratio_fixed_by_small_blur) {
    std::snprintf(buffer, sizeof buffer,
                  "the blur is small (kernel RMS radius %.2f px): phi^g with r^g fit alike, and the images' r (%.3g) "
                  "disagrees with %.4g (EXIF or --ratio) by more than %.0f %%: r is held at %.4g "
                  "(--always-fit-ratio to fit it)",
                  state.first_blur_radius, result.ratio_images_small_blur, fit_options.nominal_ratio,
                  100 * options.small_blur_ratio_tolerance, fit_options.nominal_ratio);
    result.warnings.push_back(buffer);
  } else if (result.blur_radius < options.min_blur_radius && fit_options.fit_ratio) {
    std::snprintf(buffer, sizeof buffer,
                  "the blur is small (kernel RMS radius %.2f px): phi and r are nearly ambiguous (phi^g with r^g fit "
                  "alike); the fitted r (%.3g) is weakly determined - consider fixing r to the EXIF value "
                  "(--fix-ratio)",
                  result.blur_radius, result.fits.at("G").ratio);
    result.warnings.push_back(buffer);
  }
  if (result.kernel_estimated && result.tile_kernels.size() > 1 && result.disagreement.varies())
    result.warnings.push_back("the tiles' kernels disagree (" + result.disagreement.summary() +
                              "): the blur varies across the frame; one global kernel is an approximation");
}

// Values (in [0,1]) of `image` at the `used` pixels.
std::vector<float> usedValues(const cv::Mat& image, const cv::Mat& used) {
  std::vector<float> values;
  const cv::Mat u = unit(image);
  for (int y = 0; y < u.rows; ++y)
    for (int x = 0; x < u.cols; ++x)
      if (used.at<uchar>(y, x)) values.push_back(static_cast<float>(u.at<double>(y, x)));
  return values;
}

double quantile(std::vector<float>& values, double q) {
  auto it = values.begin() + static_cast<std::ptrdiff_t>(q * (values.size() - 1));
  std::nth_element(values.begin(), it, values.end());
  return static_cast<double>(*it);
}

// Per channel: few edge pixels; an underexposed sharp shot; the intensities the data constrain (covered_range).
void channelWarnings(PairCalibrationState& state, const std::string& name, const CrfFitResult& fit) {
  PairCalibrationResult& result = state.result;
  if (fit.pixels.used < 2000)
    result.warnings.push_back("channel " + name + ": only " + std::to_string(fit.pixels.used) + " edge pixels used");
  // The intensities the data actually constrain: those of B and I at the used pixels (0.5 % tails dropped);
  // outside, φ is the model's extrapolation.
  const cv::Mat& used = fit.pixels.used_mask;
  if (used.empty() || used.size() != result.fit_window.size() || cv::countNonZero(used) == 0) return;
  const cv::Mat& sharp = state.window_sharp.at(name);
  std::vector<float> values = usedValues(sharp, used), blurred_values = usedValues(state.window_blurred.at(name), used);
  values.insert(values.end(), blurred_values.begin(), blurred_values.end());
  const std::pair<double, double> range{quantile(values, 0.005), quantile(values, 0.995)};
  // The sharp shot alone: an underexposed I carries few levels, each stretched over a wide range of B.
  std::vector<float> sharp_values = usedValues(sharp, used);
  const double top_level = quantile(sharp_values, 0.995) * (sharp.depth() == CV_16U ? 65535.0 : 255.0);
  if (top_level < 64) {
    char buffer[300];
    std::snprintf(buffer, sizeof buffer,
                  "channel %s: the sharp shot is underexposed (99.5 %% of its used pixels below level %.0f of %s): "
                  "few distinct levels constrain phi",
                  name.c_str(), top_level, sharp.depth() == CV_16U ? "65535" : "255");
    result.warnings.push_back(buffer);
  }
  result.covered_range[name] = range;
  if (range.second - range.first < state.options.min_covered_span) {
    char buffer[300];
    std::snprintf(buffer, sizeof buffer,
                  "channel %s: the data cover intensities %.2f-%.2f only; phi outside that range is extrapolated",
                  name.c_str(), range.first, range.second);
    result.warnings.push_back(buffer);
  }
}

}  // namespace

// The brightness ratio of the two shots in channel `name`: the measurement of `crfcal study ratio`
// (estimateExposureRatio by quantile matching with the EMoR mean curve), independent of the fit. Quantiles, not
// per-pixel ratios: the blur moves pixels but keeps the brightness distribution's bulk, and the per-pixel ratio of
// a noisy I needs a selection on I that biases it (measured on `bench pairs --ratio 8`: per-pixel ratios of flat
// pixels 0.25 in log from the value the camera curves imply, quantiles 0.15). Only the pixels both shots cover.
// 0 when too few usable levels.
double brightnessRatio(const PairCalibrationState& state, const std::string& name) {
  const cv::Mat sharp = unit(state.window_sharp.at(name)), blurred = unit(state.window_blurred.at(name));
  const cv::Mat overlap = state.overlap(state.result.fit_window);
  std::vector<double> sharp_values, blurred_values;
  for (int y = 0; y < sharp.rows; ++y)
    for (int x = 0; x < sharp.cols; ++x)
      if (overlap.at<uchar>(y, x)) {
        sharp_values.push_back(sharp.at<double>(y, x));
        blurred_values.push_back(blurred.at<double>(y, x));
      }
  if (sharp_values.size() < 1000) return 0;
  ExposureRatioOptions options;
  options.registered = false;
  try {
    return estimateExposureRatio(cv::Mat(sharp_values).t(), cv::Mat(blurred_values).t(), ResponseCurve(EmorModel{{0.0}}),
                                 options)
        .ratio;
  } catch (const InvalidInput&) {
    return 0;
  }
}

// The verdict per channel from the final fits, the flat regions, the covered ranges and the refit guard.
void computeVerdict(PairCalibrationState& state) {
  PairCalibrationResult& result = state.result;
  const PairCalibrationOptions& options = state.options;
  std::vector<ChannelEvidence> evidence;
  for (const auto& name : result.channels) {
    if (!result.fits.count(name)) continue;
    const CrfFitResult& fit = result.fits.at(name);
    ChannelEvidence e;
    e.channel = name;
    e.ratio = fit.ratio;
    e.nominal_ratio = options.fit.nominal_ratio;
    e.nominal_source = options.nominal_ratio_name;
    e.ratio_fixed = !options.fit.fit_ratio;
    e.ratio_held_small_blur = result.ratio_fixed_by_small_blur;
    e.ratio_images_small_blur = result.ratio_images_small_blur;
    if (const RatioEvidence& re = result.ratio_evidence; re.combined) {
      e.ratio_conflict = re.conflict;
      e.ratio_images = re.images_ratio;
      e.ratio_conflict_sigmas = re.conflict_sigmas;
      e.ratio_held_at_nominal = result.ratio_from_evidence && re.decision == RatioDecision::nominal_held;
      if (re.conflict) e.ratio_decision = toString(re.decision);
      if (re.conflict && !re.not_adopted_reason.empty()) e.ratio_decision = "not adopted: " + re.not_adopted_reason;
    }
    const double brightness = brightnessRatio(state, name);
    if (brightness > 0) result.brightness_ratio[name] = e.brightness_ratio = brightness;
    if (result.covered_range.count(name)) e.covered = result.covered_range.at(name);
    if (const auto band = result.bands.find(name); band != result.bands.end() && !band->second.empty())
      e.shape_band_sigma = medianShapeSigma(band->second);
    e.inverse_crf = fit.inverse_crf;
    e.kernel_sharp_black_admitted = result.kernel_sharp_black_admitted;
    e.kernel_grown_to = result.kernel_grown_to;
    e.kernel_size_start = state.options.kernel.kernel_size;
    const auto& modelled = result.chroma_model_channels;
    if (name != "G" && options.sharp_stored_chroma.subsampled() &&
        std::find(modelled.begin(), modelled.end(), name) == modelled.end())
      e.pointwise_from_subsampled_chroma = options.sharp_stored_chroma.name();
    if (const auto it = state.chroma_check.find(name); it != state.chroma_check.end()) {
      const PairCalibrationState::ChromaCheck& c = it->second;
      e.chroma_check_shape_difference = c.shape_difference;
      e.chroma_check_pixels_left_out = c.pixels_left_out;
      e.chroma_check_scale = c.scale;
      e.chroma_check_replaced = c.replaced;
      e.chroma_check_not_replaced = c.not_replaced;
    }
    evidence.push_back(e);
  }
  RefitEvidence refit;
  refit.tried = result.effects.refit_tried;
  refit.adopted = result.effects.refit_adopted;
  refit.rejected_reason = result.effects.refit_rejected_reason;
  refit.heldout_error_base_fit = result.effects.heldout_error_base_fit;
  refit.heldout_error_refit = result.effects.heldout_error_refit;
  refit.heldout_error_base_fit_selected_model = result.effects.heldout_error_base_fit_selected_model;
  result.verdicts = judgeChannels(evidence, refit, options.verdict);
}

void summariseFits(PairCalibrationState& state) {
  diagnosticMaps(state);
  blurWarnings(state);
  for (const auto& [name, fit] : state.result.fits) channelWarnings(state, name, fit);
}

}  // namespace crfcal::detail
