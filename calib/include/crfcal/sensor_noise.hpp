#pragma once
// Sensor noise of a camera's raw channels as measured for real cameras (darktable's noise profiles): the
// Poisson–Gaussian model, for a raw value x ∈ [0, 1] (black-subtracted, white-scaled)
//     variance(x) = a·x + b,
// a = the shot-noise term (∝ 1 / photons per unit x, so it grows with the ISO gain), b = the read-noise term
// (measured fits can give b slightly below 0: the variance is then clamped at 0). The seed (Sec. 5) adds noise to
// emulate "capturing images under a high ISO"; this is the camera-measured form of that noise.
// Pure computation: no file I/O.
#include <algorithm>
#include <vector>

#include "crfcal/response_model.hpp"

namespace crfcal {

struct PoissonGaussian {
  double a = 0;  // variance per unit raw value (shot noise)
  double b = 0;  // variance at x = 0 (read noise)
  double variance(double x) const { return std::max(0.0, a * std::max(x, 0.0) + b); }
};

// One camera at one ISO: the noise of its red, green and blue raw channels.
struct SensorNoise {
  PoissonGaussian red, green, blue;
};

// σ of a shot's values on its level grid v = 0 … levels − 1 (in [0, 1] units) when the irradiance E = φ(v) carries
// `noise` (added before the response, as a sensor does): to first order through ψ = φ⁻¹,
//     σ_I(v) = √(a·φ(v) + b) / φ'(v),
// φ' by central differences on the grid (one-sided at the ends), capped at `cap` where φ' → 0 (the first order fails
// there anyway). `bench pairs --noise-oracle` gives it to the fit as the sharp shot's true noise.
std::vector<double> intensityNoisePerLevel(const PoissonGaussian& noise, const ResponseModel& phi, int levels = 256,
                                           double cap = 0.1);

}  // namespace crfcal
