// The shape spread of several inverse responses over a common range (curve_shape_spread.hpp).
#include "crfcal/curve_shape_spread.hpp"

#include <algorithm>
#include <cmath>

#include "crfcal/error.hpp"

namespace crfcal {

double curveShapeSpread(const std::vector<std::vector<double>>& curves, std::pair<double, double> range) {
  if (curves.size() < 2) throw InvalidInput("shape spread needs at least two curves", ErrorSubject::curve);
  const std::size_t n = curves.front().size();
  for (const auto& c : curves)
    if (c.size() != n || n < 2) throw InvalidInput("curves must have the same number (>= 2) of samples", ErrorSubject::curve);
  const auto [lo, hi] = range;
  if (!(lo >= 0 && hi <= 1 && lo < hi)) throw InvalidInput("shape spread range must satisfy 0 <= lo < hi <= 1", ErrorSubject::curve);
  const int i0 = static_cast<int>(std::ceil(lo * double(n - 1))), i1 = static_cast<int>(std::floor(hi * double(n - 1)));
  if (i1 - i0 < 1) throw InvalidInput("shape spread range covers fewer than two samples", ErrorSubject::curve);
  for (const auto& c : curves)
    if (!(c[static_cast<std::size_t>(i1)] > 0)) throw InvalidInput("a curve is not positive at the range's top", ErrorSubject::curve);
  const double m = double(curves.size());
  double sum = 0;
  for (int k = i0; k <= i1; ++k) {
    double mean = 0;
    for (const auto& c : curves) mean += c[static_cast<std::size_t>(k)] / c[static_cast<std::size_t>(i1)] / m;
    for (const auto& c : curves) {
      const double d = c[static_cast<std::size_t>(k)] / c[static_cast<std::size_t>(i1)] - mean;
      sum += d * d / m;
    }
  }
  return std::sqrt(sum / double(i1 - i0 + 1));
}

std::pair<double, double> commonRange(const std::vector<std::pair<double, double>>& ranges) {
  std::pair<double, double> common{0.0, 1.0};
  for (const auto& r : ranges) {
    common.first = std::max(common.first, r.first);
    common.second = std::min(common.second, r.second);
  }
  return common;
}

}  // namespace crfcal
