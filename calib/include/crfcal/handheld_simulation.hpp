#pragma once
// Semi-real handheld pairs: a real photograph re-rendered through a known inverse response φ (a measured curve),
// blurred by a real kernel, misregistered by a handheld motion (shift + small rotation), with camera-like
// (Poisson–Gaussian, irradiance-domain) noise — the evidence protocol of `crfcal bench pairs`.
// Model (Eq. 4): E = linearised photo (x^2.2) scaled to mid-exposure; sharp I = ψ(E + n_I);
//                blurred B = warp_H(ψ(min(1, r · (E ⊗ K) + n_B))). JPEG compression and EXIF are added by io.
#include <cstdint>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal {

struct HandheldPairOptions {
  double ratio = 1.0;             // true r = Δt_B / Δt_I
  double shift_x = 4.3, shift_y = -2.7;  // handheld shift of the blurred frame, pixels
  double rotation_deg = 0.4;      // handheld rotation of the blurred frame about the centre
  double exposure = 0.45;         // mean irradiance of the sharp frame (before r)
  double noise_gain_sharp = 4e-4; // Poisson part: variance = gain · E (high ISO)
  double noise_gain_blurred = 2e-5;
  double read_noise = 1e-6;       // Gaussian part (variance)
  std::uint64_t seed = 1;
  void check() const;
};

struct HandheldPair {
  cv::Mat sharp, blurred;  // CV_8UC3 (BGR) or CV_8UC1, same as the input's channels
  cv::Mat homography;      // sharp → blurred frame (the truth for registration)
};

HandheldPair makeHandheldPair(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel,
                              const HandheldPairOptions& options = {});

}  // namespace crfcal
