#pragma once
// Forward blur models of Sec. 3 and the blur inconsistency Γ.
//   irradiance model (Eq. 4): B  = ψ(r · (φ(I) ⊗ K))   — what a camera records
//   intensity model:          B̂ = I ⊗ K                — what most deblurring methods assume
//   blur inconsistency:       Γ  = B − B̂               (Sec. 3.1; 0 ≤ Γ ≤ Imax − Imin for convex φ, Theorem 1)
// Images are single-channel CV_64F in [0,1]; borders replicate (the same for ⊗ and for Imin/Imax, so that
// Theorem 1 holds at the border too).
#include <cstdint>

#include <opencv2/core.hpp>

#include "crfcal/response_curve.hpp"

namespace crfcal {

// (image ⊗ kernel)(p) = Σ_q K(q) · image(p − q + c), c the kernel centre. Any float/integer input, CV_64F out.
cv::Mat convolve(const cv::Mat& image, const cv::Mat& kernel);

// Eq. 4. The exposure ratio r scales irradiance; values above 1 clip (the sensor saturates).
cv::Mat irradianceBlur(const cv::Mat& sharp, const ResponseCurve& curve, const cv::Mat& kernel, double ratio = 1.0);

// B̂ = I ⊗ K.
cv::Mat intensityBlur(const cv::Mat& sharp, const cv::Mat& kernel);

// Γ = B − B̂.
cv::Mat blurInconsistency(const cv::Mat& blurred, const cv::Mat& intensity_blurred);

// Imin / Imax of I over the kernel's support at every pixel (Theorem 1).
struct LocalRange {
  cv::Mat min;
  cv::Mat max;
};
LocalRange localRange(const cv::Mat& sharp, const cv::Mat& kernel);

// Rounds [0,1] values to 2^bits − 1 levels (8-bit or 16-bit storage); values are clamped to [0,1].
cv::Mat quantize(const cv::Mat& image, int bits);

// Adds zero-mean Gaussian noise of the given variance (intensities in [0,1], the seed's Sec. 5 protocol) and
// clamps to [0,1]. Deterministic for a given seed.
cv::Mat addGaussianNoise(const cv::Mat& image, double variance, std::uint64_t seed);

// Converts an 8/16-bit or float image to single-channel CV_64F in [0,1] (colour is converted to grey).
cv::Mat toUnitGray(const cv::Mat& image);

}  // namespace crfcal
