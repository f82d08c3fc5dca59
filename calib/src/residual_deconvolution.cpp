#include "crfcal/residual_deconvolution.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/photo.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/noise_estimation.hpp"
#include "crfcal/registration.hpp"

namespace crfcal {
namespace {

cv::Mat unitPlane(const cv::Mat& plane, ErrorSubject subject) {
  const int depth = plane.depth();
  if (depth != CV_8U && depth != CV_16U && depth != CV_32F && depth != CV_64F)
    throw InvalidInput("images to deblur must be 8-bit, 16-bit or floating point", subject);
  cv::Mat unit;
  plane.convertTo(unit, CV_64F, depth == CV_8U ? 1.0 / 255 : depth == CV_16U ? 1.0 / 65535 : 1.0);
  return unit;
}

// One channel of the sharp shot, denoised by non-local means in its own frame; σ (in [0,1] units) goes to `sigma`.
cv::Mat denoisedPlane(const cv::Mat& plane, const ResidualDeconvolutionOptions& options, double& sigma) {
  cv::Mat eight;
  if (plane.depth() == CV_8U) eight = plane;
  else cv::Mat(unitPlane(plane, ErrorSubject::sharp_image) * 255.0).convertTo(eight, CV_8U);
  sigma = estimateNoiseSigma(eight).sigma;
  const float h = static_cast<float>(options.denoise_strength * sigma * 255.0);
  cv::Mat denoised = eight;
  if (h >= 0.5f) cv::fastNlMeansDenoising(eight, denoised, h, options.template_window, options.search_window);
  return unitPlane(denoised, ErrorSubject::sharp_image);
}

// r minimising Σ_valid (observed − r · predicted)² (Eq. 4 linear in r).
double fittedRatio(const cv::Mat& observed, const cv::Mat& predicted, const cv::Mat& valid) {
  cv::Mat weight;
  valid.convertTo(weight, CV_64F, 1.0 / 255);
  const double cross = predicted.dot(observed.mul(weight));
  const double energy = predicted.dot(predicted.mul(weight));
  if (!(energy > 0) || !(cross > 0))
    throw InvalidInput("the sharp shot predicts none of the blurred shot (no usable overlap)", ErrorSubject::pair);
  return cross / energy;
}

}  // namespace

void ResidualDeconvolutionOptions::check() const {
  deconvolution.check();
  if (!(ratio >= 0) || !std::isfinite(ratio)) throw InvalidInput("residual deconvolution ratio must be >= 0 (0: fitted)");
  if (!(denoise_strength >= 0) || !std::isfinite(denoise_strength))
    throw InvalidInput("denoise strength must be >= 0");
  if (template_window < 3 || template_window % 2 == 0 || search_window < template_window || search_window % 2 == 0)
    throw InvalidInput("NL-means windows must be odd, template >= 3, search >= template");
}

std::string ResidualDeconvolutionResult::summary() const {
  std::string ratios, sigmas;
  char part[64];
  for (size_t c = 0; c < ratio.size(); ++c) {
    std::snprintf(part, sizeof part, "%s%.3f", c ? "/" : "", ratio[c]);
    ratios += part;
    std::snprintf(part, sizeof part, "%s%.4f", c ? "/" : "", noise_sigma[c]);
    sigmas += part;
  }
  char text[400];
  std::snprintf(text, sizeof text,
                "residual deconvolution with the sharp shot (irradiance): %dx%d, %d channel(s), r %s, sharp shot's "
                "noise sigma %s, overlap %.1f %%, %d u-step(s), %.2f s",
                deblurred.cols, deblurred.rows, deblurred.channels(), ratios.c_str(), sigmas.c_str(),
                100 * overlap_fraction, iterations, seconds);
  return text;
}

ResidualDeconvolutionResult deconvolveResidual(const cv::Mat& blurred, const cv::Mat& sharp,
                                               const cv::Mat& sharp_to_blurred, const cv::Mat& kernel,
                                               const std::vector<ResponseCurve>& curves,
                                               const ResidualDeconvolutionOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  options.check();
  if (blurred.empty()) throw InvalidInput("image to deblur is empty", ErrorSubject::blurred_image);
  if (sharp.empty()) throw InvalidInput("the sharp shot is empty", ErrorSubject::sharp_image);
  const int channels = blurred.channels();
  if (sharp.channels() != channels)
    throw InvalidInput("the sharp shot has " + std::to_string(sharp.channels()) + " channel(s), the blurred image " +
                           std::to_string(channels), ErrorSubject::sharp_image);
  if (sharp_to_blurred.empty() && sharp.size() != blurred.size())
    throw InvalidInput("the sharp shot is " + std::to_string(sharp.cols) + "x" + std::to_string(sharp.rows) +
                           " but the blurred image " + std::to_string(blurred.cols) + "x" + std::to_string(blurred.rows) +
                           " (give the registration or a shot of the same size)", ErrorSubject::sharp_image);
  if (curves.size() != 1 && static_cast<int>(curves.size()) != channels)
    throw InvalidInput("deblurring needs one response curve or one per channel (" + std::to_string(channels) + ")");
  const cv::Mat k = normalizeKernel(kernel);
  const cv::Mat homography = sharp_to_blurred.empty() ? cv::Mat::eye(3, 3, CV_64F) : sharp_to_blurred;
  const int margin = std::max(k.rows, k.cols);
  // Pixels of B the warped sharp shot covers; a fit of r also needs the kernel's whole footprint inside it.
  const cv::Mat covered = overlapMask(sharp.size(), homography, blurred.size(), 0);
  const cv::Mat fit_region = overlapMask(sharp.size(), homography, blurred.size(), margin);
  ResidualDeconvolutionResult result;
  result.overlap_fraction = cv::countNonZero(covered) / static_cast<double>(blurred.total());
  if (cv::countNonZero(fit_region) == 0)
    throw InvalidInput("the warped sharp shot does not overlap the blurred image", ErrorSubject::pair);

  std::vector<cv::Mat> blurred_planes, sharp_planes;
  cv::split(blurred, blurred_planes);
  cv::split(sharp, sharp_planes);
  std::vector<cv::Mat> residuals(channels), priors(channels), masks(channels), outputs(channels);
  result.ratio.assign(channels, 0);
  result.noise_sigma.assign(channels, 0);
  for (int c = 0; c < channels; ++c) {
    const ResponseCurve& curve = curves.size() == 1 ? curves[0] : curves[c];
    const cv::Mat b = unitPlane(blurred_planes[c], ErrorSubject::blurred_image);
    const cv::Mat irradiance = curve.inverse(b);
    masks[c] = b < options.deconvolution.saturation;  // saturated pixels of B: out of the data term and of the r fit
    const cv::Mat denoised = curve.inverse(denoisedPlane(sharp_planes[c], options, result.noise_sigma[c]));
    cv::Mat prior = warpToBlurred(denoised, homography, blurred.size());
    irradiance.copyTo(prior, ~covered);  // no sharp pixels: N = φ(B) (close to blind deconvolution there)
    result.ratio[c] = options.ratio > 0 ? options.ratio
                                        : fittedRatio(irradiance, convolve(prior, k), fit_region & masks[c]);
    prior *= result.ratio[c];
    irradiance.copyTo(prior, ~covered);
    residuals[c] = irradiance - convolve(prior, k);
    priors[c] = prior;
  }
  std::vector<int> steps(channels, 0);
  // Channels in parallel; each channel's tiles then run in its own job (OpenCV does not nest parallel_for_).
  cv::parallel_for_(cv::Range(0, channels), [&](const cv::Range& range) {
    for (int c = range.start; c < range.end; ++c)
      outputs[c] = deconvolveChannel(residuals[c], k, options.deconvolution.mask_saturated ? masks[c] : cv::Mat(),
                                     options.deconvolution, &steps[c]);
  });
  std::vector<cv::Mat> deblurred(channels), prior_intensity(channels);
  for (int c = 0; c < channels; ++c) {
    const ResponseCurve& curve = curves.size() == 1 ? curves[0] : curves[c];
    deblurred[c] = curve.forward(cv::min(cv::max(priors[c] + outputs[c], 0.0), 1.0));
    prior_intensity[c] = curve.forward(cv::min(cv::max(priors[c], 0.0), 1.0));
  }
  cv::merge(deblurred, result.deblurred);
  cv::merge(prior_intensity, result.sharp_denoised);
  result.iterations = steps[0];
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

}  // namespace crfcal
