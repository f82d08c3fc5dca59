#pragma once
// Scoring deblurred real photos against a reference shot of the same scene taken with other settings (the phone
// triplets' g_truth_N: brighter, steadier, another ISO): the reference is registered into the deblurred frame by
// the caller (registration.hpp), then brought to the blurred shot's brightness by a monotone map — per channel,
// the reference's quantiles mapped onto the blurred shot's over the common pixels (histogram specification). The map
// uses neither φ nor any deblurred result, so every estimate is compared with one and the same reference.
#include <opencv2/core.hpp>

namespace crfcal {

// `reference` with each channel's values replaced by the `target` value of the same quantile over `mask` (CV_8U,
// 255 = common pixels); both CV_64F in [0,1], same size and channels. Monotone, piecewise linear between 256 quantiles.
cv::Mat matchBrightness(const cv::Mat& reference, const cv::Mat& target, const cv::Mat& mask);

struct ReferenceScore {
  double psnr = 0;  // dB over the pixels of the mask
  double ssim = 0;  // mean SSIM; pixels outside the mask are given the estimate's values in the reference (error 0)
};

// `estimate` against `reference` (CV_64F in [0,1], same size and channels) over `mask` (CV_8U).
ReferenceScore scoreAgainstReference(const cv::Mat& estimate, const cv::Mat& reference, const cv::Mat& mask);

}  // namespace crfcal
