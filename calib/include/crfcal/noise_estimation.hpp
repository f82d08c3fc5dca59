#pragma once
// Estimating the standard deviation of additive white noise in an image (the noisy, high-ISO sharp image I
// of the seed's Sec. 4–5), from the image alone.
//
// Method: Immerkær's Laplacian-difference operator N = [1 −2 1; −2 4 −2; 1 −2 1] / 6 cancels locally linear
// signal and maps white noise of std σ to std σ. The robust scale 1.4826 · median|N ⊗ I| is taken only over
// pixels whose local mean lies well inside (0, 1), so that clipping at 0 and 1 does not shrink the estimate.
#include <opencv2/core.hpp>

namespace crfcal {

struct NoiseEstimationOptions {
  double clip_margin = 0.2;  // use pixels whose 7×7 mean is in [margin, 1 − margin]
  int min_samples = 500;     // fewer usable pixels: fall back to all interior pixels
  void check() const;        // throws InvalidInput
};

struct NoiseEstimate {
  double sigma = 0;   // noise std, intensities in [0,1]
  int samples = 0;    // pixels used
};

// `image`: single channel CV_8U, CV_16U or float in [0,1].
NoiseEstimate estimateNoiseSigma(const cv::Mat& image, const NoiseEstimationOptions& options = {});

}  // namespace crfcal
