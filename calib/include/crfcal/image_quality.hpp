#pragma once
// Image quality measures for deblurring results against the sharp truth (`crfcal bench deblur`, `crfcal theory`).
//
//   SSIM — Wang, Bovik, Sheikh, Simoncelli 2004 ("Image quality assessment: from error visibility to structural
//     similarity"): local means, variances and covariance under an 11×11 Gaussian window (σ = 1.5), constants
//     C1 = (0.01 L)², C2 = (0.03 L)² with dynamic range L = 1; the mean of the SSIM map (channels averaged).
//   edge-band error — the seed's Sec. 3.2: deconvolving intensities rings around high-contrast edges (Eq. 18, the
//     artefact P ⊗ K⁻¹ grows with Imax − Imin). RMS error of the estimate within `band` px of the sharp image's
//     edges, an edge being a pixel whose 3×3 neighbourhood spans at least `contrast` (Imax − Imin).
#include <opencv2/core.hpp>

namespace crfcal {

// Mean SSIM of `estimate` against `reference` (same size and channels, values in [0,1]), ignoring `border` px on
// every side. 1 for identical images. Throws InvalidInput for mismatched images or a border leaving < 11×11 px.
double ssim(const cv::Mat& estimate, const cv::Mat& reference, int border = 0);

struct EdgeBandOptions {
  double contrast = 0.3;  // Imax − Imin over 3×3 at least this: an edge pixel of the reference
  int band = 4;           // px around edge pixels (a (2 band + 1)² square) where the error is measured
  int border = 0;         // px on every side left out
  void check() const;     // throws InvalidInput
};

struct EdgeBandError {
  double rmse = 0;        // RMS of estimate − reference over the band (0 when the band is empty)
  long long pixels = 0;   // pixel-channels in the band
};

// Edge-band error of `estimate` against `reference` (same size and channels, values in [0,1]; the band is found
// per channel).
EdgeBandError edgeBandError(const cv::Mat& estimate, const cv::Mat& reference, const EdgeBandOptions& options = {});

}  // namespace crfcal
