#pragma once
// Pairs with one planted effect. The clean pair is the seed's simulation (issue 6: "one pointwise curve per channel,
// Gaussian noise added to I only, exact r, one global kernel, no clipping, no vignetting, no black offset") made
// from a real photograph: E = photo^2.2 scaled to a mean `exposure`; I = ψ(E) + n, n ~ N(0, sharp_sigma²) in the
// intensity domain (Sec. 5), or I = ψ(clip(E + n)) with a sensor's noise n (sharp_sensor_noise, the real regime);
// B = ψ(min(1, r (E ⊗ K) + n_B)) with the long exposure's small Poisson–Gaussian irradiance noise n_B; both stored
// as 8-bit. ONE effect is then planted at a given strength s:
//   none
//   exposure_ratio_mismatch  the EXIF ratio is off: r_EXIF = r · (1 + s)^±1 (sign from the seed)
//   channel_mixing           B's irradiance colours are mixed before the curve (colour input):
//                            E'_c = (1 − s) E_c + s/2 Σ_{d≠c} E_d
//   signal_dependent_noise   I's noise variance depends on the level: σ²(v) = σ₀² · s^((0.5 − v)/0.8), i.e. the
//                            ratio of the variances at v = 0.1 and v = 0.9 is s (darks noisier, the shape of
//                            Poisson noise seen through a concave camera curve); σ₀ = sharp_sigma
//   clipping                 B's irradiance is clipped at a plateau below full scale (sensor/processing clip):
//                            a fraction s of the informative pixels (B below full scale, I unsaturated over the
//                            kernel's support) lies on the plateau
//   vignetting               B's irradiance × (1 − s ρ²), ρ = distance to the centre / half-diagonal
//                            (the two shots differ in aperture: their vignetting ratio)
//   spatially_varying_blur   B blurred with K at the left edge blending linearly into K' at the right edge:
//                            K(x) = (1 − t) K + t K', t = s · x / width, K' = K rotated by 90°
//   black_level_offset       an irradiance offset s added to one shot (B: flare; or I; chosen by the seed)
//
// form = "held_out" plants the same effects in physical forms the detectors do NOT assume (issue 18: a bench that
// plants exactly the detector's model proves little), at the same strength scale:
//   exposure_ratio_mismatch  as above (there is no other form of a wrong EXIF ratio)
//   channel_mixing           a real camera's colour matrix (Canon EOS 5D Mark II, Adobe DNG ColorMatrix at D65,
//                            times sRGB→XYZ, rows normalised to 1), blended with the identity so that the mean
//                            off-diagonal mass per row is s
//   signal_dependent_noise   as above (issue 18 leaves it out of the count)
//   clipping                 a highlight knee instead of a plateau: above the level k that a fraction s of the
//                            informative pixels exceeds, E → k + w (1 − exp(−(E − k)/w)), w = (1 − k)/2
//   vignetting               the cos⁴ law, 1/(1 + (ρ t)²)² with t such that the corners lose s, in either shot
//   spatially_varying_blur   a rotation about the image centre during the exposure (arc at the corners = s × the
//                            kernel's extent), or a depth-dependent scale (K scaled by 1 − s at the top to 1 + s
//                            at the bottom)
//   black_level_offset       per-channel offsets s·u_c (u_c in [0.5, 1.5]) in either shot, or a low-frequency
//                            flare veil in B (a broad Gaussian bump of mean ≈ s)
// second_effect plants a second effect (any form) in the same pair.
// The stated detectability thresholds (minimum strengths that calibration must detect, with the reason for each
// value) are plantingThreshold() / thresholdReason(); tests and `crfcal bench effects` draw strengths uniformly
// in [threshold, 2·threshold].
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"
#include "crfcal/sensor_noise.hpp"

namespace crfcal {

struct PlantingOptions {
  std::string effect = "none";   // "none" or one of effectNames()
  double strength = 0;           // meaning per effect, see above
  std::string second_effect = "none";  // a second effect in the same pair ("none": one effect)
  double second_strength = 0;
  std::string form = "detector";  // "detector" (each detector's own model form) or "held_out" (see above)
  double ratio = 1.0;            // true exposure ratio r
  double exposure = 0.45;        // mean irradiance of the sharp frame (before r)
  double sharp_sigma = 0.01;     // I's intensity-domain noise std (2.6 of 255: a high-ISO short exposure)
  // Optional: I's noise as a camera's sensor makes it (sensor_noise.hpp: a measured Poisson–Gaussian law per raw
  // channel, e.g. a darktable profile at the short shot's ISO), added to I's irradiance before the clip and the curve,
  // in place of sharp_sigma in the intensity domain. Unset: the seed's simulation (Sec. 5). A planted
  // signal_dependent_noise keeps its intensity-domain law. Grey photos take the green channel's law.
  std::optional<SensorNoise> sharp_sensor_noise;
  double noise_gain_blurred = 2e-5;  // B: Poisson part of the irradiance noise (variance = gain · E)
  double read_noise_blurred = 1e-6;  // B: Gaussian part (variance)
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
  std::string detail;            // e.g. which shot carries the offset, which held-out form
  double plateau_intensity = 1;  // clipping: B's plateau level (φ above it is not measurable from the pair)
};

// The minimum strength of each effect that calibration is expected to detect (documented, used by tests/bench).
double plantingThreshold(const std::string& effect);
// Why that value (the φ bias it causes, or the physical tolerance it exceeds), one line.
std::string thresholdReason(const std::string& effect);

PlantedPair plantEffect(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel,
                        const PlantingOptions& options = {});

}  // namespace crfcal
