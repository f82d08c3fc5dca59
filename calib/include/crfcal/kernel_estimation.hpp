#pragma once
// Blur-kernel estimation from a registered sharp/blurred pair with a sparsity prior — the seed's [27]
// (Yuan, Sun, Quan, Shum 2007, blurred/noisy pairs), which Sec. 4 uses "to simultaneously register the
// blurry/sharp image pair and estimate the kernel":
//     min_k  Σ_{d∈{x,y}} Σ_{p∈P_d} (∂_d B(p) − (∂_d I ⊗ k)(p))² + λ Σ_j w_j k_j + μ ‖∇k‖²   s.t. k ≥ 0,  K = k / Σk.
// (The small Tikhonov term μ‖∇k‖² on the kernel's own gradient is the usual companion of the sparsity prior in
// kernel estimation, e.g. Cho & Lee 2009: without it the noise of the high-ISO I turns the kernel into a
// checkerboard of isolated pixels.)
// In the gradient domain (constant offsets drop out), coarse-to-fine on an image pyramid (the coarsest level
// solves for the whole window, each finer level for the dilated support of the upsampled coarser kernel), solved
// by accelerated projected gradient (FISTA) on the non-negative orthant.
// The normal equations are EXACT for any validity mask: P_d holds only pixels whose ∂B and whole (2r+1)² window
// of ∂I are valid (overlap, unsaturated), and M = AᵀA, c = Aᵀy are accumulated over those rows (blocked GEMM)
// for the active offsets only. (Approximating M by the auto-correlation of a masked ∂I — the FFT shortcut, exact
// only for an unmasked periodic image — over-counts the pixels near every hole of the mask: with saturated
// highlights and registration borders that over-count shrinks the kernel to a long streak.) Flat pixels, whose
// ∂I window holds no more energy than noise (the noise level measured robustly on the image itself), are left
// out: they add only noise to M (errors in variables) and nothing to c.
// Without the sum constraint the L1 term is a real sparsity prior; the scale Σk is a photometric gain (exposure
// ratio) that normalisation removes, so B ≈ g · (I ⊗ K) is all that is needed: pass B and I in the same
// (irradiance or approximately linearised) domain. The weights w are re-computed from the previous solution
// (re-weighted L1, w_j = 1/(k_j/max k + 0.1)), which approximates the sparsity of [27]'s hysteresis thresholding.
// The kernel absorbs the residual shift of the registration (its centroid is reported). Small entries
// (< prune_threshold · peak) and small disconnected specks are removed at the end. Each region is processed in its
// own crop (region + kernel reach), so the cost depends on the regions, not on the frame (24 MP).
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

struct KernelEstimationOptions {
  int kernel_size = 35;          // maximum kernel extent (odd); blur + residual shift must fit inside
  double lambda = 0.03;          // sparsity weight, relative to the largest data term (max_j c_j)
  int pyramid_levels = 0;        // 0: automatic (halve until the kernel is ≤ 9 px)
  int iterations = 250;          // FISTA iterations per re-weighting round and level
  int reweight_rounds = 2;       // re-weighted L1 rounds per level (0: plain L1)
  double prune_threshold = 0.05; // final entries below this fraction of the peak are set to 0
  double border_limit = 0.04;    // mass fraction in the outer ring of the window: the kernel hit its size limit
  bool throw_on_size_limit = true;  // throw InvalidInput (suggesting --max-kernel-size) when the limit is hit
  double texture_factor = 2.0;   // equations kept where the ∂I window energy > this × the noise-only energy
  int max_equations = 16000;     // per gradient direction and level (uniform deterministic subsample above)
  double smoothness = 0.05;      // μ of μ‖∇k‖² (Tikhonov), relative to the mean diagonal of the Gram matrix
  int support_dilation = 7;      // coarse-to-fine: the upsampled coarser support is dilated by this (odd) disc
  std::function<void(double fraction, const std::string& stage)> progress;  // optional
  void check() const;            // throws InvalidInput
};

struct KernelLevelInfo {
  int level = 0;            // 0 = full resolution
  double scale = 1;
  int kernel_size = 0;
  double relative_residual = 0;  // ‖∂B − g ∂I ⊗ K‖² / ‖∂B‖² on the level's pixels
};

struct KernelEstimate {
  cv::Mat kernel;             // CV_64F, sums to 1, kernel_size × kernel_size (odd)
  double gain = 1;            // Σk before normalisation (≈ exposure ratio in a linear domain)
  double relative_residual = 0;
  double border_mass = 0;     // fraction of the mass in the outermost ring
  bool hit_size_limit = false;
  cv::Point2d centroid;       // mass centroid relative to the kernel centre (residual shift), pixels
  int support = 0;            // non-zero entries
  long long equations = 0;    // gradient equations used at the finest level
  std::vector<KernelLevelInfo> levels;
  std::string summary() const;
};

// One region of the pair used for estimation (full image when empty).
struct KernelRegion {
  cv::Rect rect;
};

// Estimates one kernel from the regions (normal equations summed over them). sharp/blurred: single-channel,
// same size, any depth (integer types scaled to [0,1]); `valid` (optional CV_8U): pixels of B that may be used
// (overlap, unsaturated); `weights` (optional CV_64F, same size): each pixel's equation is multiplied by its weight
// (weighted least squares: 1/σ of the pixel's error, e.g. 1/φ'(B) when both images are in the irradiance domain).
// Throws InvalidInput for mismatched sizes, regions without texture, and — when options.throw_on_size_limit — for a
// kernel that reaches the border of its window.
KernelEstimate estimateKernel(const cv::Mat& sharp, const cv::Mat& blurred, const std::vector<cv::Rect>& regions,
                              const cv::Mat& valid = {}, const KernelEstimationOptions& options = {},
                              const cv::Mat& weights = {});

// Convenience: the whole image as one region.
KernelEstimate estimateKernel(const cv::Mat& sharp, const cv::Mat& blurred, const KernelEstimationOptions& options = {});

// Error between two kernels after aligning their centroids is NOT done (shift matters for the model):
// ‖K₁ − K₂‖₂ / ‖K₂‖₂ with both padded to a common odd size around their centres.
double kernelRelativeError(const cv::Mat& estimate, const cv::Mat& truth);
// The same after translating `estimate` by the shift that minimises the error (integer search |shift| ≤ max_shift,
// then ±1 px in 1/8 px steps, bicubic): how well the kernel's shape is recovered, independent of the registration
// shift it absorbs (a half-pixel shift alone costs ≈ 0.5 on a compact 15 px kernel with integer shifts only).
double kernelShapeError(const cv::Mat& estimate, const cv::Mat& truth, int max_shift = 6);

}  // namespace crfcal
