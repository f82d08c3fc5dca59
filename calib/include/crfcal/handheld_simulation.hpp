#pragma once
// Semi-real handheld pairs: a real photograph re-rendered through a known inverse response φ (a measured curve),
// blurred by a real kernel, misregistered by a handheld motion (shift + small rotation), with camera-like
// (Poisson–Gaussian, irradiance-domain) noise — the evidence protocol of `crfcal bench pairs`.
// Model (Eq. 4): sharp I = ψ(E + n_I), blurred B = warp_H(ψ(min(1, r · (E ⊗ K) + n_B))), E = the linearised
// photo (x^2.2) scaled so that the normally exposed shot has mean irradiance `exposure`:
//   * SharpNormal (the r = 1, 2 benches): the sharp shot is normally exposed (E clipped at 1), the blurred shot r×
//     brighter (clipping where r·E⊗K > 1); noise from the generic gains below;
//   * BlurredNormal (real handheld pairs, the seed's footnote 4: a long low-ISO shot and a short high-ISO one
//     underexposed by r): the blurred shot is normally exposed, the sharp one gets r× less irradiance (E = L/r for
//     the scene irradiance L, unclipped before the blur); with `sharp_noise` / `blurred_noise` each shot gets a
//     camera's measured raw noise at its ISO (sensor_noise.hpp) in the irradiance domain, before the curve.
// JPEG compression and EXIF are added by io.
#include <cstdint>
#include <optional>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"
#include "crfcal/sensor_noise.hpp"

namespace crfcal {

struct HandheldPairOptions {
  double ratio = 1.0;             // true r = Δt_B / Δt_I
  double shift_x = 4.3, shift_y = -2.7;  // handheld shift of the blurred frame, pixels
  double rotation_deg = 0.4;      // handheld rotation of the blurred frame about the centre
  enum class NormallyExposed { Sharp, Blurred };
  NormallyExposed normally_exposed = NormallyExposed::Sharp;  // which shot has mean irradiance `exposure`
  double exposure = 0.45;         // mean irradiance of the normally exposed frame
  double noise_gain_sharp = 4e-4; // Poisson part: variance = gain · E (high ISO)
  double noise_gain_blurred = 2e-5;
  double read_noise = 1e-6;       // Gaussian part (variance)
  // A camera's measured noise at each shot's ISO; when set, replaces the generic gains above for that shot.
  std::optional<SensorNoise> sharp_noise, blurred_noise;
  // Where the blurred frame is moved: false (the benches' record), its 8-bit intensities after the response and
  // its clip (bilinear: an intensity-domain resampling, as a camera's lens correction or a phone's stabilisation
  // crop does); true, its irradiance before the sensor's noise and the response (the hand's motion precedes the
  // sensor).
  bool warp_irradiance = false;
  // An additive irradiance (fraction of full scale) in the blurred shot alone, before its noise and the response: a
  // flare veil or a black-level error of that shot (`bench joint --offset`). 0: none.
  double blurred_offset = 0;
  std::uint64_t seed = 1;
  void check() const;
};

struct HandheldPair {
  cv::Mat sharp, blurred;  // CV_8UC3 (BGR) or CV_8UC1, same as the input's channels
  cv::Mat homography;      // sharp → blurred frame (the truth for registration)
};

HandheldPair makeHandheldPair(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel,
                              const HandheldPairOptions& options = {});

// The sharp shot of a pair whose blurred shot is normally exposed (the BlurredNormal regime above) for a scene
// given as intensities `scene` (one channel, CV_64F in [0,1], the normally exposed view): ψ(φ(scene) / r + n),
// n Poisson–Gaussian camera noise of the short shot's ISO in the irradiance domain (`noise`), clipped, 8-bit,
// registered with the scene (no handheld motion). CV_8U.
cv::Mat underexposedSharpShot(const cv::Mat& scene, const ResponseModel& phi, double ratio, const PoissonGaussian& noise,
                              std::uint64_t seed = 1);

}  // namespace crfcal
