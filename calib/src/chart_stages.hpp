#pragma once
// Private helpers of the ColorChecker calibration (chart_calibration.cpp, chart_all_patches.cpp).
#include <string>
#include <utility>
#include <vector>

#include "crfcal/chart_calibration.hpp"

namespace crfcal::detail {

// Fits one channel: `observations` holds the `exact` exact samples first (their (shot, patch) in `origin`), then the
// bounds. K by cross-validation over the observations' folds (a fixed K = 3 with fewer than three folds, said in
// `warnings`), the GGCM conversion, the patches' residuals and a warning when the data cover less than half of x.
// Throws InvalidInput when fewer than 4 exact samples.
ChartChannelResult fitChartChannel(int channel, std::vector<ScaledObservation> observations, size_t exact,
                                   const std::vector<std::pair<int, int>>& origin,
                                   const ChartCalibrationOptions& options, std::vector<std::string>& warnings);

// calibrateChart with ReferenceSet::AllPatches (chart_all_patches.cpp).
ChartCalibrationResult calibrateChartAllPatches(const std::vector<ChartShot>& shots,
                                                const ChartCalibrationOptions& options,
                                                const ProgressCallback& progress);

}  // namespace crfcal::detail
