#pragma once
// Semi-real exposure brackets with a known response, the evidence of `crfcal bench bracket` and the unit tests of
// `crfcal bracket`: a real photograph linearised (x^2.2) is the scene irradiance L; frame j records
//   z_j = ψ(min(1, t_j · L' + n_j))  quantised to 8 bits,
// ψ = φ⁻¹ per channel (a measured camera curve), L' = L moved by a small handheld shift and rotation (frame 0 is not
// moved), n_j Poisson–Gaussian noise in the irradiance domain (variance a·E + b). JPEG compression is added by io.
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal {

struct BracketSimulationOptions {
  std::vector<double> exposures{1, 2.83, 8, 22.6};  // t_j (relative): 1.5-stop steps
  double middle_mean = 0.18;      // mean irradiance t_j·L of the middle frame (mid-grey)
  double shot_noise = 2e-4;       // a: variance per unit irradiance
  double read_noise = 1e-6;       // b: variance at 0
  double max_shift = 3;           // handheld shift of frames 1…, pixels (deterministic pattern, up to this)
  double max_rotation_deg = 0.3;  // handheld rotation of frames 1…, up to this
  std::uint64_t seed = 1;
  void check() const;             // throws InvalidInput
};

// `photo`: 8-bit BGR (or grey) photograph; `phi`: the inverse response of R, G, B (one model: all three). Returns the
// frames as CV_8UC3 (or CV_8UC1), in the order of options.exposures.
std::vector<cv::Mat> simulateBracket(const cv::Mat& photo, const std::vector<ResponseModel>& phi,
                                     const BracketSimulationOptions& options = {});

}  // namespace crfcal
