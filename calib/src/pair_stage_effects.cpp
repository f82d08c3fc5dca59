// Stage "effects" of calibratePair: named effects tested on the fit's residuals (effects.hpp); a detected effect's
// extended model supplies φ unless it moved an r the user fixed.
#include <algorithm>
#include <cmath>
#include <string>

#include "crfcal/error.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

void diagnoseResidualEffects(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  const CrfFitOptions& fit_options = state.fit_options;
  const cv::Rect& window = result.fit_window;
  const auto start = Clock::now();
  state.report("effects", 0);
  EffectInputs ei;
  ei.channels = result.channels;
  ei.sharp = state.window_sharp;
  ei.blurred = state.window_blurred;
  ei.fits = result.fits;
  // A channel that kept the chroma model is diagnosed by its pointwise fit: the effects' refits are pointwise, so
  // against the modelled fit they would measure the chroma model as an "effect" (measured: G of a semi-real pair
  // 0.0036 → 0.027 through such a decision, docs/RESULTS.md#chroma-choice).
  for (const auto& [name, fit] : state.pointwise_fits) ei.fits[name] = fit;
  ei.kernel = state.kernel;
  ei.kernel_estimated = result.kernel_estimated;
  ei.nominal_ratio = options.fit.nominal_ratio;  // EXIF / --ratio (fit_options' may hold the combined r)
  ei.ratio_held_for_small_blur = result.ratio_fixed_by_small_blur;
  ei.centre = cv::Point2d((state.sharp.cols - 1) / 2.0 - window.x, (state.sharp.rows - 1) / 2.0 - window.y);
  ei.corner_radius = 0.5 * std::hypot(state.sharp.cols, state.sharp.rows);
  ei.valid = state.overlap(window);
  ei.fit = fit_options;
  ei.kernel_options = state.kernel_options;  // grown with the first kernel, if it was
  ei.kernel_options.lambda = options.irradiance_kernel_lambda;  // the tile kernels are irradiance-domain estimates
  ei.weighted_tile_kernels = options.weight_irradiance_kernel;
  try {
    result.effects = diagnoseEffects(ei, options.effects);
    if (!result.effects.fits.empty()) {
      result.base_fits = result.fits;
      const auto& modelled = result.chroma_model_channels;
      for (const auto& [name, fit] : result.effects.fits) {
        // The extended models are pointwise: a channel that kept the chroma model keeps its fit.
        if (std::find(modelled.begin(), modelled.end(), name) != modelled.end()) continue;
        // A fixed r (--fix-ratio) is the user's constraint: an extended model that moved it is not adopted.
        if (!fit_options.fit_ratio &&
            std::abs(fit.ratio - fit_options.nominal_ratio) > 1e-9 * fit_options.nominal_ratio) {
          result.warnings.push_back("channel " + name + ": the effects' refit changed the fixed r (" +
                                    std::to_string(fit.ratio) + "); kept the fit with the fixed r");
          continue;
        }
        result.fits[name] = fit;
      }
    }
  } catch (const InvalidInput& e) {
    result.warnings.push_back(std::string("effect diagnostics skipped: ") + e.what());
  }
  result.timings["effects"] = secondsSince(start);
  state.report("effects", 1, result.effects.detected().empty() ? "none detected" : "detected");
}

}  // namespace crfcal::detail
