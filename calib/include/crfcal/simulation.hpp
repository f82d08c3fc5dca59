#pragma once
// Synthetic sharp/blurred pairs following the seed's Sec. 5 protocol: a latent irradiance image Ĩ is mapped
// to the sharp intensity image I = ψ(Ĩ) and to the blurred one B = ψ(r · (Ĩ ⊗ K)) (Eq. 3–4), then quantised;
// noise is added to I (the short, high-ISO exposure).
#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal {

struct SimulationOptions {
  double ratio = 1.0;           // exposure ratio r = Δt_B / Δt_I (Eq. 4); the seed's analysis uses r = 1 (Eq. 5)
  double noise_variance = 0.0;  // Gaussian noise variance added to I, intensities in [0,1] (Sec. 5: 0.001–0.01)
  int bits = 8;                 // quantisation of both images: 8 or 16
  bool image_is_irradiance = true;  // true: the input image is Ĩ (Sec. 5); false: it is already the intensity I
  std::uint64_t seed = 1;       // noise seed
  void check() const;           // throws InvalidInput
};

struct SimulationResult {
  cv::Mat irradiance;  // Ĩ = φ(I), CV_64F
  cv::Mat sharp;       // I (noisy, quantised), CV_64F in [0,1]
  cv::Mat sharp_clean; // I before noise and quantisation
  cv::Mat blurred;     // B (quantised), CV_64F in [0,1]
  cv::Mat intensity_blurred;  // B̂ = I ⊗ K of the clean I, CV_64F
  int clipped_pixels = 0;     // pixels of r·(Ĩ ⊗ K) above 1
};

SimulationResult simulatePair(const cv::Mat& image, const ResponseModel& model, const cv::Mat& kernel,
                              const SimulationOptions& options = {});

}  // namespace crfcal
