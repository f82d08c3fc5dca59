#pragma once
// How far apart several inverse responses are in SHAPE over a common range of x: each curve divided by its value at
// the top of the range (φ → b·φ leaves Eq. 4 unchanged, so the scale is not the data's), then the RMS spread about
// their mean over the samples of the range. The measurement of docs/RESULTS.md ("r from all the pair's evidence")
// and of CalibrateRealPairs.PhonePairsGreenShapesAgreeOverTheCommonCoveredRange. Pure computation.
#include <utility>
#include <vector>

namespace crfcal {

// `curves`: ≥ 2 inverse responses φ(i/(n−1)), each with the same n ≥ 2 samples; `range`: [lo, hi] ⊂ [0, 1], lo < hi,
// covering at least 2 samples. Throws InvalidInput otherwise, or when a curve is not positive at hi.
double curveShapeSpread(const std::vector<std::vector<double>>& curves, std::pair<double, double> range);

// The common part of several covered ranges (max of the lows, min of the highs; lo ≥ hi when they do not overlap).
std::pair<double, double> commonRange(const std::vector<std::pair<double, double>>& ranges);

}  // namespace crfcal
