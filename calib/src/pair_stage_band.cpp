// Stage "band" of calibratePair: per channel, the pointwise band of φ (curve_band.hpp) — half-sample refits of the
// fit window's blocks with the final kernel and the fit's options, and the exponent bounds beyond the covered range.
// When an effect's extended model supplied φ, the refits are of the base fitter: the band then measures the base
// estimator's sampling spread around the reported curve.
#include <string>

#include "crfcal/kernel.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

void estimateBands(PairCalibrationState& state) {
  PairCalibrationResult& result = state.result;
  const auto start = Clock::now();
  const cv::Mat kernel = cropKernel(state.kernel, 0.0);  // as fitChannel hands it to the fitter
  // r held at the combination of the images and EXIF (ratio_evidence.hpp) is still uncertain: the refits fit it
  // again (from the combined value), so that its spread stays in the band. A user's --fix-ratio stays fixed.
  CrfFitOptions fit_options = state.fit_options;
  if (result.ratio_from_evidence) fit_options.fit_ratio = true;
  int done = 0;
  for (const auto& name : result.channels) {
    const auto covered = result.covered_range.find(name);
    if (covered == result.covered_range.end() || !result.fits.count(name)) continue;
    state.report("band", double(done++) / result.channels.size(), name);
    result.bands[name] = estimateCurveBand(state.window_sharp.at(name), state.window_blurred.at(name), kernel,
                                           fit_options, result.fits.at(name), covered->second,
                                           state.options.band);
  }
  result.timings["band"] = secondsSince(start);
  state.report("band", 1);
}

}  // namespace crfcal::detail
