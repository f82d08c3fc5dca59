#include "crfcal/curve_perturbation.hpp"

#include <cmath>
#include <vector>

#include "crfcal/error.hpp"

namespace crfcal {
namespace {

constexpr int kSamples = 1024;

std::vector<double> powered(const std::vector<double>& phi, double exponent) {
  std::vector<double> out(phi.size());
  for (size_t i = 0; i < phi.size(); ++i) out[i] = std::pow(std::max(phi[i], 0.0), exponent);
  out.front() = 0;
  out.back() = 1;
  return out;
}

double rmse(const std::vector<double>& a, const std::vector<double>& b) {
  double sum = 0;
  for (size_t i = 0; i < a.size(); ++i) sum += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(sum / static_cast<double>(a.size()));
}

}  // namespace

double curveRmse(const ResponseCurve& a, const ResponseCurve& b) { return rmse(a.sample(kSamples), b.sample(kSamples)); }

ResponseCurve powerPerturbedCurve(const ResponseCurve& curve, double target_rmse, bool steeper) {
  if (!(target_rmse > 0 && target_rmse <= 0.2)) throw InvalidInput("curve perturbation RMSE must lie in (0, 0.2]");
  const std::vector<double> phi = curve.sample(kSamples);
  // log a by bisection: the RMSE grows monotonically with |log a|
  double low = 0, high = std::log(8.0);
  const double sign = steeper ? 1 : -1;
  if (rmse(powered(phi, std::exp(sign * high)), phi) < target_rmse)
    throw InvalidInput("curve perturbation: no power within [1/8, 8] moves the curve that far");
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (low + high);
    (rmse(powered(phi, std::exp(sign * mid)), phi) < target_rmse ? low : high) = mid;
  }
  return ResponseCurve::fromSamples(powered(curve.nodes(), std::exp(sign * 0.5 * (low + high))));
}

}  // namespace crfcal
