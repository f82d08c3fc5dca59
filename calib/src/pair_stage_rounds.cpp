// Stage "kernel↔φ rounds" of calibratePair: φ_G fitted with the first kernel (Eq. 21–25; the small-blur hold of r),
// then `rounds` × { K re-estimated in the irradiance domain φ(I), φ(B), where Eq. 4 is linear; φ_G refitted }, the
// change per round recorded; finally the other channels with the last kernel. (Sec. 4 iterates φ and r; K is ours.)
#include <algorithm>
#include <cmath>
#include <string>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"
#include "irradiance_kernel_inputs.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {
namespace {

// φ_G with the first kernel. With a blur too small to separate φ^γ, r^γ from φ, r the images cannot give r (log r
// moves with γ·log r): if theirs disagrees with EXIF / --ratio beyond the tolerance of nominal EXIF values, r is
// held at that value and φ_G refitted.
void fitFirstGreen(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  CrfFitOptions& fit_options = state.fit_options;
  result.fits["G"] = fitChannel(state, "G", state.kernel);
  const double disagreement = std::abs(result.fits["G"].ratio / fit_options.nominal_ratio - 1);
  if (fit_options.fit_ratio && options.fix_ratio_when_blur_is_small && state.first_blur_radius < options.min_blur_radius &&
      disagreement > options.small_blur_ratio_tolerance) {
    result.ratio_images_small_blur = result.fits["G"].ratio;
    fit_options.fit_ratio = false;
    result.ratio_fixed_by_small_blur = true;
    result.fits["G"] = fitChannel(state, "G", state.kernel);
  }
}

// One round: K in the irradiance domain with the current φ_G, then φ_G again. False when the kernel failed (the
// previous kernel is kept, with a warning). Adds the fit's seconds to `fit_time`.
bool kernelPhiRound(PairCalibrationState& state, int round, double& fit_time) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  const Canvas& canvas = state.canvas;
  const ResponseCurve curve = ResponseCurve::fromSamples(result.fits["G"].inverse_crf);
  // Irradiance domain (Eq. 4 is linear there): φ of the denoised I (denoising first avoids Jensen's bias of φ
  // applied to noise) against φ(B).
  const cv::Mat i_irr = curve.inverse(canvas.sharp_denoised), b_irr = curve.inverse(canvas.blurred);
  const cv::Mat weights = options.weight_irradiance_kernel ? intensityScaleWeights(curve, canvas.blurred) : cv::Mat();
  KernelEstimate k;
  try {
    k = estimateCanvasKernel(state, i_irr, b_irr, round == options.rounds, options.irradiance_kernel_lambda, weights);
  } catch (const InvalidInput& e) {
    result.warnings.push_back(std::string("irradiance-domain kernel round ") + std::to_string(round) + " failed (" +
                              e.what() + "); kept the previous kernel");
    return false;
  }
  const double change = kernelRelativeError(k.kernel, state.kernel);
  state.kernel = k.kernel;
  result.kernel = k;
  const auto previous = result.fits["G"].inverse_crf;
  const auto start = Clock::now();
  result.fits["G"] = fitChannel(state, "G", state.kernel);
  fit_time += secondsSince(start);
  result.rounds.push_back({round, change, curveRmse(result.fits["G"].inverse_crf, previous), result.fits["G"].ratio,
                           k.relative_residual});
  return true;
}

}  // namespace

void fitKernelPhiRounds(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  state.fit_options = options.fit;
  state.first_blur_radius = kernelRmsRadius(state.kernel);
  const auto start = Clock::now();
  double fit_time = 0;
  const auto first = Clock::now();
  fitFirstGreen(state);
  fit_time += secondsSince(first);
  result.rounds.push_back({0, 0, 0, result.fits["G"].ratio, result.kernel.relative_residual});
  for (int round = 1; round <= options.rounds && options.given_kernel.empty(); ++round)
    if (!kernelPhiRound(state, round, fit_time)) break;
  const auto others_start = Clock::now();
  std::vector<std::string> others;
  for (const auto& name : result.channels)
    if (name != "G") others.push_back(name);
  if (!others.empty()) {
    auto fits = fitChannels(state, others, state.kernel, true, options.chroma_choice.enabled);
    for (const auto& name : others) {
      if (state.window_sharp_error.count(name)) result.chroma_model_channels.push_back(name);
      result.fits[name] = std::move(fits.at(name));
    }
  }
  fit_time += secondsSince(others_start);
  result.timings["fit"] = fit_time;
  result.timings["kernel_phi_rounds"] = secondsSince(start) - fit_time;
}

}  // namespace crfcal::detail
