#pragma once
// Blur-kernel estimation from a registered sharp/blurred pair with a sparsity prior — the seed's [27]
// (Yuan, Sun, Quan, Shum 2007, blurred/noisy pairs), which Sec. 4 uses "to simultaneously register the
// blurry/sharp image pair and estimate the kernel":
//     min_k  Σ_{d∈{x,y}} ‖∂_d B − ∂_d I ⊗ k‖² + λ Σ_j w_j k_j     subject to k ≥ 0,   then K = k / Σk.
// In the gradient domain (constant offsets drop out), coarse-to-fine on an image pyramid, with the normal
// equations built by FFT (auto-correlation of ∂I and cross-correlation of ∂I with ∂B, cv::dft) and solved by
// accelerated projected gradient (FISTA) on the non-negative orthant. Without the sum constraint the L1 term is
// a real sparsity prior; the scale Σk is a photometric gain (exposure ratio) that normalisation removes, so
// B ≈ g · (I ⊗ K) is all that is needed: pass B and I in the same (irradiance or approximately linearised)
// domain. The weights w are re-computed from the previous solution (re-weighted L1, w_j = 1/(k_j/max k + ε)),
// which approximates the sparsity of [27]'s hysteresis thresholding. The kernel absorbs the residual shift of the
// registration (its centroid is reported). Small entries (< prune_threshold · peak) are removed at the end.
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

struct KernelEstimationOptions {
  int kernel_size = 35;          // maximum kernel extent (odd); blur + residual shift must fit inside
  double lambda = 0.01;          // sparsity weight, relative to the largest data term (max_j c_j)
  int pyramid_levels = 0;        // 0: automatic (halve until the kernel is ≤ 9 px)
  int iterations = 250;          // FISTA iterations per re-weighting round and level
  int reweight_rounds = 2;       // re-weighted L1 rounds per level (0: plain L1)
  double prune_threshold = 0.05; // final entries below this fraction of the peak are set to 0
  double border_limit = 0.04;    // mass fraction in the outer ring of the window: the kernel hit its size limit
  bool throw_on_size_limit = true;  // throw InvalidInput (suggesting --kernel-size) when the limit is hit
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
  std::vector<KernelLevelInfo> levels;
  std::string summary() const;
};

// One region of the pair used for estimation (full image when empty).
struct KernelRegion {
  cv::Rect rect;
};

// Estimates one kernel from the regions (normal equations summed over them). sharp/blurred: single-channel,
// same size, any depth (integer types scaled to [0,1]); `valid` (optional CV_8U): pixels of B that may be used
// (overlap, unsaturated). Throws InvalidInput for mismatched sizes, regions without texture, and — when
// options.throw_on_size_limit — for a kernel that reaches the border of its window.
KernelEstimate estimateKernel(const cv::Mat& sharp, const cv::Mat& blurred, const std::vector<cv::Rect>& regions,
                              const cv::Mat& valid = {}, const KernelEstimationOptions& options = {});

// Convenience: the whole image as one region.
KernelEstimate estimateKernel(const cv::Mat& sharp, const cv::Mat& blurred, const KernelEstimationOptions& options = {});

// Error between two kernels after aligning their centroids is NOT done (shift matters for the model):
// ‖K₁ − K₂‖₂ / ‖K₂‖₂ with both padded to a common odd size around their centres.
double kernelRelativeError(const cv::Mat& estimate, const cv::Mat& truth);
// The same after translating `estimate` by the integer shift that minimises the error (|shift| ≤ max_shift):
// how well the kernel's shape is recovered, independent of the absorbed registration shift.
double kernelShapeError(const cv::Mat& estimate, const cv::Mat& truth, int max_shift = 6);

}  // namespace crfcal
