#pragma once
// Estimating the standard deviation of additive white noise in an image (the noisy, high-ISO sharp image I
// of the seed's Sec. 4–5), from the image alone.
//
// Method: Immerkær's Laplacian-difference operator N = [1 −2 1; −2 4 −2; 1 −2 1] / 6 cancels locally linear
// signal and maps white noise of std σ to std σ. The robust scale 1.4826 · median|N ⊗ I| is taken only over
// pixels whose local mean lies well inside (0, 1), so that clipping at 0 and 1 does not shrink the estimate.
#include <vector>

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

// The same estimate on the image averaged over 2×2 blocks, times 2 (white noise: σ/2 per block mean). A JPEG
// quantises away the highest frequencies, which the full-resolution operator reads, and keeps the noise below them:
// measured on an ISO 800 sharp shot of `bench pairs --ratio 8` at quality 95, 0.49 levels at full resolution and
// 1.61 at half (the same shot at quality 100: 1.48 and 1.85; without noise: 0.00 and 0.25). Where they differ, the
// noise is there but hidden at the finest scale. Images smaller than 18×18 throw InvalidInput.
NoiseEstimate estimateNoiseSigmaAtHalfResolution(const cv::Mat& image, const NoiseEstimationOptions& options = {});

// Signal-dependent noise (real sensors: variance ≈ a·x + b): the same operator, its robust scale taken per bin of
// the 7×7 local mean. Bins are equal-count quantiles of the local mean (at least `min_samples` pixels each, at
// most `max_bins`); the level of a bin is its median local mean.
struct NoiseProfile {
  std::vector<double> level;  // increasing, intensities in [0,1]
  std::vector<double> sigma;  // noise std at that level
};
NoiseProfile estimateNoiseProfile(const cv::Mat& image, int max_bins = 8, const NoiseEstimationOptions& options = {});

// σ(v) on a grid of `levels` levels (x = v/(levels−1)) from a profile: linear between its levels, constant outside,
// clamped to [0, 0.5].
std::vector<double> noiseSigmaPerLevel(const std::vector<double>& level, const std::vector<double>& sigma, int levels);

}  // namespace crfcal
