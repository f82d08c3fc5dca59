// Stage "fit window" of calibratePair: the window of the frame handed to the φ fit (crf_fitter.hpp, Eq. 21–25),
// both shots cut to it per channel, and the fit of one channel on it.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/chroma_subsampling.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "pair_stages.hpp"
#include "parallel_jobs.hpp"

namespace crfcal::detail {

void markChromaDetail(PairCalibrationState& state, const cv::Mat& sharp_in) {
  const PairCalibrationOptions& options = state.options;
  if (sharp_in.channels() != 3 || !options.rgb) return;
  // Modelled (--chroma-model auto): the fits use the bound. Else, a subsampled file: the verdict's check uses it.
  const bool modelled = options.sharp_chroma.subsampled();
  if (!modelled && !options.sharp_stored_chroma.subsampled()) return;
  const ChromaSubsampling sampling = modelled ? options.sharp_chroma : options.sharp_stored_chroma;
  for (const char* name : {"R", "B"}) {
    cv::Mat bound = chromaErrorBound(sharp_in, sampling, name, options.chroma_detail);
    if (state.result.sharp_rotation_deg == -90) cv::rotate(bound, bound, cv::ROTATE_90_CLOCKWISE);
    else if (state.result.sharp_rotation_deg == 90) cv::rotate(bound, bound, cv::ROTATE_90_COUNTERCLOCKWISE);
    (modelled ? state.sharp_chroma_error : state.sharp_chroma_check_error)[name] = bound;
  }
}

void chooseFitWindow(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  const cv::Mat& sharp = state.sharp;
  // The whole frame for moderate sizes, else a window around the best tile.
  cv::Rect window(0, 0, sharp.cols, sharp.rows);
  if (std::max(sharp.cols, sharp.rows) > options.max_fit_side) {
    const cv::Point centre = (result.tiles.front().rect.tl() + result.tiles.front().rect.br()) / 2;
    const int w = std::min(options.max_fit_side, sharp.cols), h = std::min(options.max_fit_side, sharp.rows);
    window = cv::Rect(std::clamp(centre.x - w / 2, 0, sharp.cols - w), std::clamp(centre.y - h / 2, 0, sharp.rows - h),
                      w, h);
  }
  result.fit_window = window;
  // Both shots inside the window, every channel (the blurred one resampled into the sharp frame: the window's
  // origin composed into the homography). No data outside the overlap: 0, i.e. censored for the fitter.
  const cv::Mat T = (cv::Mat_<double>(3, 3) << 1, 0, window.x, 0, 1, window.y, 0, 0, 1);
  const cv::Mat blurred_window = options.register_pair
                                     ? warpToSharp(state.blurred, result.registration.homography * T, window.size())
                                     : state.blurred(window);
  std::vector<cv::Mat> planes;
  cv::split(blurred_window, planes);
  const cv::Mat outside = ~state.overlap(window);
  for (const auto& name : result.channels) {
    cv::Mat s = channelPlane(state.sharp_planes, name)(window).clone(), b = channelPlane(planes, name).clone();
    s.setTo(0, outside);
    b.setTo(0, outside);
    state.window_sharp[name] = s;
    state.window_blurred[name] = b;
    if (const auto it = state.sharp_chroma_error.find(name); it != state.sharp_chroma_error.end())
      state.window_sharp_error[name] = it->second(window).clone();
    if (const auto it = state.sharp_chroma_check_error.find(name); it != state.sharp_chroma_check_error.end())
      state.window_sharp_check_error[name] = it->second(window).clone();
  }
}

namespace {

// The fit options of channel `name`: the stage's, with the sharp shot's chroma error bound when it is modelled.
CrfFitOptions channelFitOptions(const PairCalibrationState& state, const std::string& name) {
  CrfFitOptions fo = state.fit_options;
  if (const auto it = state.window_sharp_error.find(name); it != state.window_sharp_error.end())
    fo.sharp_error_bound = it->second;
  return fo;
}

}  // namespace

CrfFitResult fitChannel(const PairCalibrationState& state, const std::string& name, const cv::Mat& kernel_full) {
  // The smallest centred window holding the kernel's mass: the fitter dilates clipped regions and the frame
  // border by the kernel's window, so empty margins (the estimation window's, or a given file's) would only
  // cost pixels.
  const cv::Mat kernel = cropKernel(kernel_full, 0.0);
  CrfFitOptions fo = channelFitOptions(state, name);
  fo.progress = [&state, &name](double f, const std::string& stage) { state.report("fit " + name, f, stage); };
  return fitInverseCrf(state.window_sharp.at(name), state.window_blurred.at(name), kernel, fo);
}

namespace {

// The sample index of a level of the fit's level grid on the 1024 samples of φ.
int sampleOfLevel(int level, int levels, std::size_t samples) {
  return static_cast<int>(std::lround(static_cast<double>(level) * (samples - 1) / std::max(levels - 1, 1)));
}

// ChromaModelChoice: whether channel `name`'s modelled fit is kept against its pointwise fit; records the scale.
bool keepsChromaModel(PairCalibrationState& state, const std::string& name, const CrfFitResult& modelled,
                      const CrfFitResult& pointwise) {
  const auto covered = [](const CrfFitResult& f) {
    return std::make_pair(sampleOfLevel(f.covered_levels.first, f.levels, f.inverse_crf.size()),
                          sampleOfLevel(f.covered_levels.second, f.levels, f.inverse_crf.size()));
  };
  double scale = 0;
  try {
    scale = relativeCurveScale(modelled.inverse_crf, covered(modelled), pointwise.inverse_crf, covered(pointwise));
  } catch (const InvalidInput&) {
    return false;  // no common range to compare on: the pointwise model, as for a channel the model cannot fit
  }
  state.result.chroma_model_scale[name] = scale;
  return scale > state.options.chroma_choice.min_relative_scale;
}

}  // namespace

std::map<std::string, CrfFitResult> fitChannels(PairCalibrationState& state, const std::vector<std::string>& names,
                                                const cv::Mat& kernel, bool fallback_warnings,
                                                bool choose_chroma_model) {
  // The jobs: every channel as it is modelled, then (choose_chroma_model) the modelled ones once more pointwise.
  std::vector<std::string> pointwise_names;
  if (choose_chroma_model)
    for (const auto& name : names)
      if (state.window_sharp_error.count(name)) pointwise_names.push_back(name);
  const int n = static_cast<int>(names.size()), jobs = n + static_cast<int>(pointwise_names.size());
  std::vector<std::optional<CrfFitResult>> fits(jobs);
  state.report("fit", 0, n == 1 ? names[0] : std::to_string(n) + " channels");
  const std::vector<std::exception_ptr> errors = runInParallel(jobs, [&](int i) {
    const std::string& name = i < n ? names[i] : pointwise_names[i - n];
    CrfFitOptions fo = channelFitOptions(state, name);
    if (i >= n) fo.sharp_error_bound = cv::Mat();
    fo.progress = nullptr;  // progress from the workers would interleave: the stage reports per batch
    fits[i] = fitInverseCrf(state.window_sharp.at(name), state.window_blurred.at(name), cropKernel(kernel, 0.0),
                            fo);  // cropped as fitChannel does
  });
  for (int i = n; i < jobs; ++i)
    if (errors[i]) std::rethrow_exception(errors[i]);  // the pointwise fit of a channel: as without the model
  std::map<std::string, CrfFitResult> out;
  for (int i = 0; i < n; ++i) {
    const std::string& name = names[i];
    if (errors[i]) {
      try {
        std::rethrow_exception(errors[i]);
      } catch (const InvalidInput& e) {
        // The chroma model (a subsampled sharp JPEG) leaves too few pixels: today's pointwise model.
        if (!state.window_sharp_error.count(name)) throw;
        state.window_sharp_error.erase(name);
        if (fallback_warnings)
          state.result.warnings.push_back(name + ": too few pixels where the sharp shot's subsampled chroma is flat (" +
                                          e.reason() + "); fitted with the pointwise model, less reliable than G");
        const auto p = std::find(pointwise_names.begin(), pointwise_names.end(), name);
        fits[i] = p != pointwise_names.end() ? std::move(fits[n + (p - pointwise_names.begin())])
                                             : std::optional<CrfFitResult>(fitChannel(state, name, kernel));
      }
    } else if (const auto p = std::find(pointwise_names.begin(), pointwise_names.end(), name);
               p != pointwise_names.end()) {
      std::optional<CrfFitResult>& pointwise = fits[n + (p - pointwise_names.begin())];
      if (!keepsChromaModel(state, name, *fits[i], *pointwise)) {
        state.window_sharp_error.erase(name);  // later refits (ratio evidence) use the pointwise model too
        fits[i] = std::move(pointwise);
      } else {
        state.pointwise_fits[name] = std::move(*pointwise);
      }
    }
    out[name] = std::move(*fits[i]);
  }
  state.report("fit", 1);
  return out;
}

void checkPointwiseChroma(PairCalibrationState& state) {
  PairCalibrationResult& result = state.result;
  if (!state.options.sharp_stored_chroma.subsampled()) return;
  // The pointwise R and B: every one without --chroma-model auto, and those auto's choice kept pointwise (their
  // bound was dropped from window_sharp_error; the check rebuilds it from the stored sampling).
  const auto start = Clock::now();
  const auto& modelled = result.chroma_model_channels;
  std::vector<std::string> names;
  for (const char* name : {"R", "B"})
    if (result.fits.count(name) && std::find(modelled.begin(), modelled.end(), name) == modelled.end())
      names.push_back(name);
  if (names.empty()) return;
  if (state.window_sharp_check_error.empty() && state.options.sharp_chroma.subsampled()) {
    // auto kept the pointwise fit: the bound of the modelled fit it compared with, cut to the window again
    for (const auto& name : names)
      if (const auto it = state.sharp_chroma_error.find(name); it != state.sharp_chroma_error.end())
        state.window_sharp_check_error[name] = it->second(result.fit_window).clone();
  }
  const cv::Mat kernel = cropKernel(state.kernel, 0.0);  // as fitChannel hands it to the fitter
  const auto covered = [](const CrfFitResult& f) {
    const double top = std::max(f.levels - 1, 1);
    return IntensityRange{f.covered_levels.first / top, f.covered_levels.second / top};
  };
  std::vector<PairCalibrationState::ChromaCheck> check(names.size());
  std::vector<std::optional<CrfFitResult>> flat_fits(names.size());
  const std::vector<std::exception_ptr> errors = runInParallel(static_cast<int>(names.size()), [&](int i) {
    const std::string& name = names[static_cast<std::size_t>(i)];
    const auto bound = state.window_sharp_check_error.find(name);
    if (bound == state.window_sharp_check_error.end()) return;
    CrfFitOptions fo = state.fit_options;
    fo.sharp_error_bound = bound->second;
    fo.progress = nullptr;
    CrfFitResult flat = fitInverseCrf(state.window_sharp.at(name), state.window_blurred.at(name), kernel, fo);
    const CrfFitResult& reported = result.fits.at(name);
    const ChannelComparison c = compareCurves(flat.inverse_crf, reported.inverse_crf, covered(flat), covered(reported));
    PairCalibrationState::ChromaCheck& measured = check[static_cast<std::size_t>(i)];
    measured.shape_difference = c.rmse_covered_aligned;
    measured.pixels_left_out = flat.pixels.unmodelled;
    measured.scale = c.scale_covered;
    measured.ambiguity_rise = flat.ambiguity_rise;
    flat_fits[static_cast<std::size_t>(i)] = std::move(flat);
  });
  for (std::size_t i = 0; i < names.size(); ++i) {
    if (errors[i]) {
      try {
        std::rethrow_exception(errors[i]);
      } catch (const InvalidInput&) {
        // too few pixels where the chroma is flat (or no range both cover): not checked, the blanket reason stays
      }
    }
    // Beyond the shape target and above the pointwise fit (the sign of the lost chroma's bias), and fixing the
    // exponent by itself: the flat-chroma fit is reported, as --chroma-model auto would keep it; its bound goes with
    // it (bands, joint fits).
    PairCalibrationState::ChromaCheck& c = check[i];
    const double min_rise = state.options.chroma_replacement_min_ambiguity_rise;
    const bool biased = flat_fits[i] && c.shape_difference > state.options.verdict.max_chroma_shape_difference &&
                        c.scale > 1;
    if (biased && state.options.replace_chroma_biased_fits) {
      if (result.effects.refit_adopted) {
        c.not_replaced = "an effect's extended model supplied the reported phi, so that one is kept";
      } else if (!(c.ambiguity_rise >= min_rise)) {
        char why[200];
        std::snprintf(why, sizeof why,
                      "that fit does not fix the curve's exponent by itself (ambiguity rise %.3g < %.3g), so it is "
                      "not reported instead",
                      c.ambiguity_rise, min_rise);
        c.not_replaced = why;
      }
      c.replaced = c.not_replaced.empty();
    }
    if (c.replaced) {
      result.fits[names[i]] = std::move(*flat_fits[i]);
      result.chroma_model_channels.push_back(names[i]);
      state.window_sharp_error[names[i]] = state.window_sharp_check_error.at(names[i]);
    }
    state.chroma_check[names[i]] = c;
  }
  state.result.timings["chroma_check"] = secondsSince(start);
}

}  // namespace crfcal::detail
