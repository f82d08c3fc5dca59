#pragma once
// JPEG chroma subsampling in the pair model (issue 20). A 4:2:0 / 4:2:2 JPEG stores Cb and Cr (JFIF: BT.601, full
// range, of the gamma-encoded RGB) averaged over 2×2 / 2×1 pixel blocks; the decoder rebuilds R and B from
// full-resolution luma plus that chroma. Where the true chroma varies inside a block, a decoded R or B differs from
// ψ(E) by the chroma's lost detail (R: 1.402·ΔCr, B: 1.772·ΔCb), which the pointwise model
// B = ψ(r·(φ(I) ⊗ K)) (Eq. 4) cannot represent.
// Measured (docs/RESULTS.md#chroma): only the sharp shot matters — the blurred shot's chroma is smooth, its blur
// removed the detail the blocks lose (demo pair: sharp 4:2:0 + blurred 4:4:4 gives φ_B RMSE 0.130, sharp 4:4:4 +
// blurred 4:2:0 0.024). The sharp shot's true chroma inside a block is not in the file, so R and B are fitted where
// it does not matter: pixels whose kernel-weighted bound of that error over their support is small (the fitter's
// CrfFitOptions::sharp_error_bound). Fitting there with the true per-pixel error (an oracle from a 4:4:4 twin)
// brings R and B to the 4:4:4 accuracy; chromaErrorBound estimates it from the stored chroma.
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

// Chroma block size relative to luma (JPEG sampling factors): 1×1 = 4:4:4 (or not a JPEG), 2×2 = 4:2:0, 2×1 = 4:2:2.
struct ChromaSubsampling {
  int h = 1, v = 1;
  bool subsampled() const { return h > 1 || v > 1; }
  std::string name() const;  // "4:4:4", "4:2:0", "4:2:2", "4:4:0", or "h×v"
};

struct ChromaDetailOptions {
  // The chroma inside a block can vary only as much as the stored block averages around it do: the bound at a block
  // is the range of the stored averages over the block and this many blocks on each side (2: a 5×5-block window,
  // 10×10 pixels at 4:2:0). Measured on the demo pair: 1 → R/B 0.030/0.027, 2 → 0.026/0.024 (RESULTS).
  int reach_blocks = 2;
  void check() const;  // throws InvalidInput
};

// A per-pixel bound of |decoded − true| of `channel` ("R", "G" or "B") of a decoded JPEG, CV_32F in the channel's
// [0, 1] units: the channel's reconstruction coefficient (R 1.402 Cr, B 1.772 Cb, G 0.344 Cb + 0.714 Cr) times the
// range of the stored chroma averages around the pixel's block, less the median of that range over the image (the
// share of the noise: most blocks are flat), at least 0. bgr: 8- or 16-bit BGR as decoded; blocks aligned with the
// image origin, as in the file. Not subsampled: all zero.
cv::Mat chromaErrorBound(const cv::Mat& bgr, ChromaSubsampling sampling, const std::string& channel,
                         const ChromaDetailOptions& options = {});

// The floor of the exclusion below: a level range the bound (nearly) empties keeps its least affected pixels.
// Why: where chroma detail is large at every edge of some level range — measured on a dark scene with saturated
// colours (IMG_2601, Sony curve, levin:3), the bound kept 0 of the 2,537 B edge pixels above level 0.75 — dropping
// them all leaves φ extrapolated there, and as φ(1) = 1 a wrong top scales the whole curve (φ_B RMSE 0.24, the
// shape over the covered range right: 0.009 after the best scale). Refilling every bin to a fixed share instead
// re-admits biased pixels where the bound is right (demo pair, 25 % in every bin: B 0.024 → 0.063).
// Chosen on the demo pair and that case (RESULTS#chroma): emptied 5 %, refilled 25 %.
struct LevelFloor {
  int bins = 16;                   // equal bins of I's level over [0, 1]
  double emptied_fraction = 0.05;  // a bin keeping fewer than this share of its candidates is emptied ...
  double refilled_fraction = 0.25; // ... and keeps this share instead: its candidates of smallest bound
  void check() const;              // throws InvalidInput
};

// The candidates left out of a fit by a kernel-weighted error bound (CrfFitOptions::sharp_error_bound): those whose
// weighted_bound exceeds max_error, except in a level bin the floor refills, whose threshold is raised to keep
// floor.refilled_fraction of it. weighted_bound, level (in [0, 1]): CV_64F; candidates: CV_8U, non-zero where a
// pixel could be used. Returns CV_8U, 255 at excluded candidates. Wrong types or sizes → InvalidInput.
cv::Mat excludedByErrorBound(const cv::Mat& weighted_bound, const cv::Mat& level, const cv::Mat& candidates,
                             double max_error, const LevelFloor& floor = {});

// Which model a subsampled channel keeps (issue 20, third round): the chroma model's fit, or the pointwise one.
// Why a rule: excluding the chroma edges also removes much of the data that pins φ's scale (φ(B) = r·φ(I) ⊗ K is
// homogeneous in φ; φ(1) = 1 fixes the scale through the extrapolation above the data), so where the pointwise model
// was not biased, the modelled fit is only noisier — measured: R on IMG_2601 (scale a = 0.71), B at r = 4.
// The sign of the bias that the model corrects is known: the decoder's block-averaged chroma makes a sharp shot's
// edge less extreme than it was, so with a convex φ the pointwise mixture φ(I) ⊗ K is too low and the fit makes φ
// more convex, i.e. lower over the data (measured: pointwise B's best scale against the truth 0.57–0.95 on the
// r = 1 pairs where the model helps). A modelled fit that correctly removes that bias therefore lies above the
// pointwise one; one that lies below it moved against the bias, by the noise of its thinner data.
struct ChromaModelChoice {
  bool enabled = true;       // false: a modelled channel always keeps the chroma model's fit (the second round)
  // The modelled fit is kept only if its best scale against the pointwise fit over the range both cover is above
  // this: 1, the sign rule above (no margin tuned on the benchmarks).
  double min_relative_scale = 1.0;
  void check() const;        // throws InvalidInput
};

// The best scale a of `modelled` against `pointwise` (least squares: modelled ≈ a·pointwise) over the samples both
// cover. Both: φ sampled uniformly on [0, 1] (the fitter's 1024 samples, the same count); covered_*: the first and
// last covered sample of each (inclusive). No common sample, different or empty samplings, or pointwise zero there
// → InvalidInput.
double relativeCurveScale(const std::vector<double>& modelled, std::pair<int, int> covered_modelled,
                          const std::vector<double>& pointwise, std::pair<int, int> covered_pointwise);

}  // namespace crfcal
