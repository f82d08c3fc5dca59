#pragma once
// Small statistics the `crfcal bench` tables share (one definition instead of a copy per bench).
#include <algorithm>
#include <cmath>
#include <vector>

#include "crfcal/curve_comparison.hpp"

namespace crfcal::app {

// Median (mean of the two middle values for an even count); NaN for none.
inline double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

// Arithmetic mean; NaN for none.
inline double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / double(v.size());
}

// Shape error of `estimate` against the truth over `range`: RMSE after the best common factor (φ → bφ leaves Eq. 4
// unchanged); NaN when the estimate has a non-finite sample (OpenCV's Robertson).
inline double shapeError(const std::vector<double>& truth, const std::vector<double>& estimate, IntensityRange range) {
  for (double v : estimate)
    if (!std::isfinite(v)) return std::nan("");
  return compareCurves(truth, estimate, range, range).rmse_covered_aligned;
}

}  // namespace crfcal::app
