// The inputs of an irradiance-domain kernel estimate (irradiance_kernel_inputs.hpp).
#include "irradiance_kernel_inputs.hpp"

#include <algorithm>

#include <opencv2/imgproc.hpp>

#include "crfcal/noise_estimation.hpp"

namespace crfcal::detail {

cv::Mat denoiseForKernel(const cv::Mat& image) {
  const double sigma = estimateNoiseSigma(image).sigma;
  if (!(sigma > 0.002)) return image;
  cv::Mat f, out;
  image.convertTo(f, CV_32F);
  cv::bilateralFilter(f, out, 7, static_cast<float>(std::max(3 * sigma, 0.02)), 2.0);
  out.convertTo(out, CV_64F);
  return out;
}

cv::Mat intensityScaleWeights(const ResponseCurve& curve, const cv::Mat& blurred) {
  constexpr double step = 5.0 / 255, min_slope = 0.02;
  const cv::Mat upper = curve.inverse(cv::min(blurred + step, 1.0));
  const cv::Mat lower = curve.inverse(cv::max(blurred - step, 0.0));
  const cv::Mat slope = (upper - lower) / (2 * step);
  return 1.0 / cv::max(slope, min_slope);
}

}  // namespace crfcal::detail
