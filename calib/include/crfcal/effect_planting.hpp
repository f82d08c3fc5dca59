#pragma once
// Pairs with one planted effect: a real photograph rendered through a known φ exactly like the semi-real handheld
// pairs (handheld_simulation.hpp: E = photo^2.2 scaled to `exposure`; I = ψ(E + n_I); B = ψ(min(1, r (E ⊗ K) + n_B)),
// Poisson–Gaussian irradiance noise), plus ONE named effect of effects.hpp at a given strength:
//   none
//   exposure_ratio_mismatch  EXIF r = true r · (1 + s)^±1 (sign from the seed)
//   channel_mixing           B's irradiance colours mixed: E'_c = (1 − s) E_c + s/2 Σ_{d≠c} E_d  (colour input)
//   signal_dependent_noise   extra intensity-domain noise in I with variance s · I (on top of the camera noise)
//   clipping                 B's irradiance clipped at the level above which a fraction s of it lies (a sensor or
//                            processing clip below full scale)
//   vignetting               B's irradiance × (1 − s ρ²), ρ = distance to the centre / half-diagonal (aperture change)
//   spatially_varying_blur   B blurred with K at the left edge blending linearly into K' at the right edge:
//                            K(x) = (1 − t) K + t K', t = min(s, 1) · x / width, K' = K rotated by 90°
//   black_level_offset       an irradiance offset s added to one shot (B: flare, or I; chosen by the seed)
// The stated detectability thresholds (minimum strengths a calibrate run must detect) are in
// plantingThreshold(); the tests and `crfcal bench effects` draw strengths uniformly in [threshold, 2·threshold].
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal {

struct PlantingOptions {
  std::string effect = "none";   // "none" or one of effectNames()
  double strength = 0;           // meaning per effect, see above
  double ratio = 1.0;            // true exposure ratio r
  double exposure = 0.45;        // mean irradiance of the sharp frame (before r)
  double noise_gain_sharp = 4e-4;   // Poisson part of I (variance = gain · E)
  double noise_gain_blurred = 2e-5;
  double read_noise = 1e-6;
  double shift_x = 0, shift_y = 0, rotation_deg = 0;  // handheld misregistration of B (registration's job)
  std::uint64_t seed = 1;
  void check() const;            // throws InvalidInput
};

struct PlantedPair {
  cv::Mat sharp, blurred;        // CV_8U, channels of the photo (BGR or grey)
  cv::Mat homography;            // sharp → blurred
  double true_ratio = 1;
  double exif_ratio = 1;         // what the camera's EXIF would claim
  std::string effect;
  double strength = 0;
  std::string detail;            // e.g. which shot carries the offset
};

// The minimum strength of each effect that calibration is expected to detect (documented, used by tests/bench).
double plantingThreshold(const std::string& effect);

PlantedPair plantEffect(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel,
                        const PlantingOptions& options = {});

}  // namespace crfcal
