#include "crfcal/sensor_noise.hpp"

#include <cmath>

#include "crfcal/error.hpp"

namespace crfcal {

std::vector<double> intensityNoisePerLevel(const PoissonGaussian& noise, const ResponseModel& phi, int levels,
                                           double cap) {
  if (levels < 2) throw InvalidInput("intensityNoisePerLevel: levels must be >= 2");
  if (!(cap > 0)) throw InvalidInput("intensityNoisePerLevel: cap must be > 0");
  const std::vector<double> f = sampleInverse(phi, levels);
  const double step = 1.0 / (levels - 1);
  std::vector<double> sigma(static_cast<std::size_t>(levels));
  for (int v = 0; v < levels; ++v) {
    const int lo = std::max(v - 1, 0), hi = std::min(v + 1, levels - 1);
    const double slope = (f[hi] - f[lo]) / ((hi - lo) * step);
    sigma[v] = std::min(cap, std::sqrt(noise.variance(f[v])) / std::max(slope, 1e-3));
  }
  return sigma;
}

}  // namespace crfcal
