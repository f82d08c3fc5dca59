#include "crfcal/simulation.hpp"

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal {

void SimulationOptions::check() const {
  if (!(ratio > 0)) throw InvalidInput("exposure ratio must be positive");
  if (!(noise_variance >= 0)) throw InvalidInput("noise variance must be non-negative");
  if (bits != 8 && bits != 16) throw InvalidInput("bits must be 8 or 16");
}

SimulationResult simulatePair(const cv::Mat& image, const ResponseModel& model, const cv::Mat& kernel,
                              const SimulationOptions& options) {
  options.check();
  const cv::Mat k = normalizeKernel(kernel);
  const ResponseCurve curve(model);
  const cv::Mat input = toUnitGray(image);
  SimulationResult result;
  // Eq. 2–4: I = ψ(Ĩ), B = ψ(r · (Ĩ ⊗ K)).
  result.irradiance = options.image_is_irradiance ? input : curve.inverse(input);
  result.sharp_clean = options.image_is_irradiance ? curve.forward(input) : input;
  cv::Mat blurred_irradiance = convolve(result.irradiance, k) * options.ratio;
  result.clipped_pixels = cv::countNonZero(blurred_irradiance > 1.0);
  cv::min(blurred_irradiance, 1.0, blurred_irradiance);
  result.blurred = quantize(curve.forward(blurred_irradiance), options.bits);
  result.intensity_blurred = intensityBlur(result.sharp_clean, k);
  result.sharp = quantize(addGaussianNoise(result.sharp_clean, options.noise_variance, options.seed), options.bits);
  return result;
}

}  // namespace crfcal
