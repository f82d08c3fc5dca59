#include "crfcal/theory_deblur.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "crfcal/blur_model.hpp"
#include "crfcal/deconvolution.hpp"
#include "crfcal/error.hpp"
#include "crfcal/image_quality.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal::theory {
namespace {

// The middle row without `pad` columns on either side.
std::vector<double> middleRow(const cv::Mat& image, int pad) {
  const double* row = image.ptr<double>(image.rows / 2);
  return {row + pad, row + image.cols - pad};
}

// max |a − b| at least `gap` px from the step at `step` (the step itself is smoothed by any regularised K⁻¹; the
// ringing is what lies beside it).
double largestDifference(const std::vector<double>& a, const std::vector<double>& b, int step, int gap) {
  double largest = 0;
  for (size_t i = 0; i < a.size(); ++i)
    if (std::abs(static_cast<int>(i) - step) >= gap) largest = std::max(largest, std::abs(a[i] - b[i]));
  return largest;
}

}  // namespace

void StepEdgeOptions::check() const {
  if (!(low >= 0 && low < high && high <= 1)) throw InvalidInput("step edge needs 0 <= low < high <= 1");
  if (kernel_length < 2 || width < 4 * kernel_length || height < 1)
    throw InvalidInput("step edge needs a kernel of >= 2 px and a width of >= 4 kernel lengths");
  if (!(wiener_nsr > 0)) throw InvalidInput("step edge Wiener regulariser must be positive");
}

StepEdgeResult stepEdgeDeconvolution(const StepEdgeOptions& options) {
  options.check();
  const ResponseCurve curve(options.model);
  const cv::Mat kernel = boxKernel(options.kernel_length);
  // Computed on a canvas 8 kernel lengths wider on each side and cropped: the image borders' own deconvolution
  // errors (the blur's replicated border vs the deconvolution's reflected one) stay out of the profiles.
  const int pad = 8 * options.kernel_length;
  cv::Mat sharp(options.height, options.width + 2 * pad, CV_64F, cv::Scalar(options.low));
  sharp.colRange(pad + options.width / 2, sharp.cols).setTo(options.high);
  const cv::Mat blurred = irradianceBlur(sharp, curve, kernel);  // B (Eq. 5)
  const cv::Mat intensity_blurred = intensityBlur(sharp, kernel);  // B̂
  const cv::Mat artefact = blurred - intensity_blurred;            // P = Γ
  DeconvolutionOptions wiener;
  wiener.method = DeconvolutionMethod::Wiener;
  wiener.wiener_nsr = options.wiener_nsr;
  const cv::Mat deconvolved = deconvolveChannel(blurred, kernel, {}, wiener);  // linear: = K⁻¹B̂ + K⁻¹P
  const cv::Mat artefact_deconvolved = deconvolveChannel(artefact, kernel, {}, wiener);
  const cv::Mat irradiance = deconvolveChannel(curve.inverse(blurred), kernel, {}, wiener);
  const cv::Mat irradiance_deconvolved = curve.forward(cv::Mat(cv::min(cv::max(irradiance, 0.0), 1.0)));

  StepEdgeResult result;
  result.sharp = middleRow(sharp, pad);
  result.blurred = middleRow(blurred, pad);
  result.intensity_blurred = middleRow(intensity_blurred, pad);
  result.artefact = middleRow(artefact, pad);
  result.deconvolved = middleRow(deconvolved, pad);
  result.artefact_deconvolved = middleRow(artefact_deconvolved, pad);
  result.irradiance_deconvolved = middleRow(irradiance_deconvolved, pad);
  result.max_ringing = largestDifference(result.deconvolved, result.sharp, options.width / 2, 3);
  result.max_irradiance_error = largestDifference(result.irradiance_deconvolved, result.sharp, options.width / 2, 3);
  return result;
}

std::string StepEdgeResult::summary() const {
  char text[256];
  std::snprintf(text, sizeof text,
                "step edge %.2f -> %.2f: max P = %.4f; 3 px or more from the step, max |B (x) K^-1 - I| = %.4f "
                "(intensity), max |psi(phi(B) (x) K^-1) - I| = %.4f (irradiance)",
                sharp.front(), sharp.back(), *std::max_element(artefact.begin(), artefact.end()), max_ringing,
                max_irradiance_error);
  return text;
}

TvComparison tvComparison(const cv::Mat& sharp, const cv::Mat& kernel, const TvComparisonOptions& options) {
  if (sharp.empty() || sharp.channels() != 1) throw InvalidInput("Fig. 4 needs a grey sharp image");
  const ResponseCurve curve(options.model);
  TvComparison result;
  sharp.convertTo(result.sharp, CV_64F);
  result.blurred = quantize(irradianceBlur(result.sharp, curve, kernel), 8);
  result.intensity_blurred = quantize(intensityBlur(result.sharp, kernel), 8);
  DeconvolutionOptions tv;
  tv.domain = DeconvolutionDomain::Intensity;
  result.tv_blurred = deconvolve(result.blurred, kernel, {curve}, tv).deblurred;
  result.tv_intensity_blurred = deconvolve(result.intensity_blurred, kernel, {curve}, tv).deblurred;
  tv.domain = DeconvolutionDomain::Irradiance;
  result.tv_irradiance = deconvolve(result.blurred, kernel, {curve}, tv).deblurred;
  const int border = options.border;
  result.psnr_tv_blurred = psnr(result.tv_blurred, result.sharp, border);
  result.psnr_tv_intensity_blurred = psnr(result.tv_intensity_blurred, result.sharp, border);
  result.psnr_tv_irradiance = psnr(result.tv_irradiance, result.sharp, border);
  result.ssim_tv_blurred = ssim(result.tv_blurred, result.sharp, border);
  result.ssim_tv_intensity_blurred = ssim(result.tv_intensity_blurred, result.sharp, border);
  result.ssim_tv_irradiance = ssim(result.tv_irradiance, result.sharp, border);
  return result;
}

std::string TvComparison::summary() const {
  char text[320];
  std::snprintf(text, sizeof text,
                "TV of B (camera, intensity domain): %.2f dB, SSIM %.4f; TV of B^ = I (x) K (no inconsistency): "
                "%.2f dB, SSIM %.4f; psi(TV of phi(B)) (irradiance domain): %.2f dB, SSIM %.4f",
                psnr_tv_blurred, ssim_tv_blurred, psnr_tv_intensity_blurred, ssim_tv_intensity_blurred,
                psnr_tv_irradiance, ssim_tv_irradiance);
  return text;
}

}  // namespace crfcal::theory
