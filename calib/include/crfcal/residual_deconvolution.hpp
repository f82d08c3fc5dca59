#pragma once
// Deblurring with the pair's sharp shot as extra information: residual deconvolution (Yuan, Sun, Quan, Shum 2007,
// "Image deblurring with blurred/noisy image pairs", the seed's [4]), in the irradiance domain.
//
// The sharp shot I of a pair is an unblurred view of the scene, underexposed by r and noisy (high ISO). Denoised, it
// gives most of the scene; what it misses (the detail the denoiser removed) is what deconvolution must recover, and
// that residual is small, so its ringing is small (Yuan et al. Sec. 4). In irradiance (Eq. 4: φ(B) = r φ(I) ⊗ K):
//
//   N  = r · warp(φ(denoise(I)))             the denoised sharp shot at the blurred shot's exposure, in B's frame
//   ΔB = φ(B) − N ⊗ K                        the residual blurred image (signed)
//   ΔI = deconv(ΔB, K)                       non-blind deconvolution of the residual (deconvolution.hpp: TV or Wiener;
//                                            saturated pixels of B out of the TV data term)
//   result = ψ(N + ΔI)
//
// Yuan et al. deconvolve ΔI by a gain-controlled Richardson–Lucy; here the residual goes through crfcal's TV (FTVd /
// ADMM) solver, whose gradient penalty on ΔI plays the same role of keeping the residual's ringing down.
// Denoising: OpenCV's non-local means (cv::fastNlMeansDenoising) on each 8-bit channel of I in its own frame (before
// any resampling, so the noise is still white), with the filter strength set from the noise the image shows
// (noise_estimation.hpp). Where the warped sharp shot has no pixels, N = φ(B): the residual there is φ(B) − φ(B) ⊗ K
// and the result is close to blind deconvolution, without a step at the overlap's edge.
// The exposure ratio r is fitted per channel by least squares of φ(B) against φ(denoise(I)) ⊗ K over unsaturated
// pixels of the overlap (it also absorbs a white-balance difference between the shots); `ratio` > 0 fixes it.
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/deconvolution.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal {

struct ResidualDeconvolutionOptions {
  // Deconvolution of the residual (method, λ, iterations, saturation mask, tiles). The domain is always irradiance.
  DeconvolutionOptions deconvolution;
  double ratio = 0;               // r = exposure of B / exposure of I (Eq. 4); 0: fitted per channel from the images
  // NL-means strength h = this × the sharp shot's estimated noise σ (8-bit levels). bench deblur (r = 4, ISO 400 /
  // ISO 3200 sharp shot): h = 3σ 36.60 / 32.48 dB, SSIM 0.944 / 0.916; 2σ 37.10 / 32.51 dB, SSIM 0.939 / 0.903.
  double denoise_strength = 3.0;
  int template_window = 7;        // NL-means patch size (odd; OpenCV's recommended 7)
  int search_window = 21;         // NL-means search window (odd; OpenCV's recommended 21)
  void check() const;             // throws InvalidInput naming the bad option
};

struct ResidualDeconvolutionResult {
  cv::Mat deblurred;                 // CV_64F intensity in [0,1], B's size and channels
  cv::Mat sharp_denoised;            // ψ(N): the denoised sharp shot at B's exposure, in B's frame, CV_64F [0,1]
  std::vector<double> ratio;         // r used per channel
  std::vector<double> noise_sigma;   // the sharp shot's estimated noise σ per channel (intensity, [0,1] units)
  double overlap_fraction = 0;       // of B's frame covered by the warped sharp shot
  int iterations = 0;                // u-steps of the residual's first tile (first channel)
  double seconds = 0;                // wall time
  std::string summary() const;
};

// Deblurs `blurred` (1 or 3 channels, 8/16-bit or float in [0,1]) with `kernel` and φ (`curves`: one, or one per
// channel), using `sharp` (same channels; 8-bit, or converted to 8 bits for the denoiser), the pair's sharp shot.
// `sharp_to_blurred`: the 3×3 homography from the sharp shot's pixels to the blurred shot's (registration.hpp,
// a calibration report's "registration"); empty = identity (the shots registered, then of the same size).
// Throws InvalidInput with ErrorSubject::sharp_image when the sharp shot's channels do not match or, without a
// homography, its size differs, and ErrorSubject::pair when the warped sharp shot does not overlap B.
ResidualDeconvolutionResult deconvolveResidual(const cv::Mat& blurred, const cv::Mat& sharp,
                                               const cv::Mat& sharp_to_blurred, const cv::Mat& kernel,
                                               const std::vector<ResponseCurve>& curves,
                                               const ResidualDeconvolutionOptions& options = {});

}  // namespace crfcal
