#pragma once
// Non-blind deconvolution with a known kernel K and a known inverse response φ (Sec. 3.2 of the seed).
//
// The seed's second result (Eq. 17–18, Fig. 3–4): a camera records B = ψ(φ(I) ⊗ K), so deconvolving the
// intensities B with K leaves the artefact P ⊗ K⁻¹ (P = B − B̂ from the blur inconsistency Γ), which rings around
// high-contrast edges; deconvolving the irradiance φ(B) and mapping back with ψ does not.
//
//   domain intensity:  I* = deconv(B, K)                (the seed's failing case)
//   domain irradiance: I* = ψ(deconv(φ(B), K))          (what a calibrated camera allows)
//
// Methods:
//   total variation — FTVd (Wang, Yang, Yin, Zhang 2008, the seed's [26]):
//       min_u Σ_p ‖∇u(p)‖ + λ/2 Σ_p M(p) ((K ⊗ u)(p) − f(p))²
//     by half-quadratic splitting (auxiliary w ≈ ∇u, penalty β/2 ‖w − ∇u‖²): the w-step is isotropic shrinkage,
//     the u-step one FFT solve. FTVd grows β geometrically (continuation); by default crfcal adds the scaled
//     multiplier b of w = ∇u (ADMM / split Bregman, Goldstein & Osher 2009: shrink ∇u + b, solve with w − b,
//     b ← b + ∇u − w), which converges at a fixed moderate β in fewer steps. M is the data mask (below).
//   wiener — U = conj(K̂) F̂ / (|K̂|² + nsr), the linear baseline.
//
// Data mask M and boundaries: u lives on a domain padded by the kernel's size on every side (FFT sizes even and
// 5-smooth; the DFTs are FFTW's), so the FFT's wrap-around only couples padded pixels; M = 0 on the padding and on
// saturated pixels of B (B ≥ `saturation` in that channel: the recorded value is only a lower bound, as the seed
// excludes them from the fit), 1 elsewhere. The masked data term is minimised by majorisation–minimisation:
// before each u-step the masked-out pixels of f are replaced by the current K ⊗ u (ḟ = M f + (1 − M) K ⊗ u), which
// keeps every u-step a single FFT solve and decreases the masked objective. Wiener cannot mask: it uses the
// reflect-padded image (the same padding, then cropped), and saturated pixels enter its data as recorded.
//
// Large images: tiles (DeconvolutionOptions::tile_size), each fitted with the same free boundary on its own FFT
// canvas and overlapping its neighbours; the (channel, tile) jobs run in parallel (cv::parallel_for_).
//
// Kernels follow crfcal::convolve exactly (kernel.hpp: convolution, centre (cols/2, rows/2)).
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_curve.hpp"

namespace crfcal {

enum class DeconvolutionMethod { TotalVariation, Wiener };
enum class DeconvolutionDomain { Intensity, Irradiance };

// "tv" / "wiener", "intensity" / "irradiance" (throw InvalidInput for anything else).
DeconvolutionMethod parseDeconvolutionMethod(const std::string& name);
DeconvolutionDomain parseDeconvolutionDomain(const std::string& name);
const char* toString(DeconvolutionMethod method);
const char* toString(DeconvolutionDomain domain);

struct DeconvolutionOptions {
  DeconvolutionMethod method = DeconvolutionMethod::TotalVariation;
  DeconvolutionDomain domain = DeconvolutionDomain::Irradiance;  // the seed's recommendation
  // TV data weight λ (FTVd's μ) for signals in [0,1]. Larger: sharper, noisier. 3000 suits 8-bit images without
  // added noise (Levin set: measured best between 1000 and 1e4); noisy images want ~300–1000.
  double lambda = 3000;
  // Penalty β of the splitting w ≈ ∇u. The default is ADMM (split Bregman: multipliers on w = ∇u) at a fixed β:
  // on the bench's Levin crops 25 steps at β = 256 match FTVd's continuation (β = 1 … 4096 doubling, 4 steps each,
  // 52 steps): mean PSNR +0.03 dB irradiance, +0.17 dB intensity. bregman = false, beta_start 1, beta_max 4096, factor 2, 4 inner: plain FTVd.
  double beta_start = 256;     // first penalty β
  double beta_max = 256;       // last β (continuation: β ← β · factor while β ≤ beta_max)
  double beta_factor = 2;      // β ← β · factor
  int inner_iterations = 25;   // u/w alternations per β
  bool bregman = true;         // ADMM (split Bregman) multipliers on w = ∇u; false: FTVd's quadratic penalty only
  double tolerance = 1e-4;     // leave a β early when the relative change of u falls below this
  double wiener_nsr = 2e-3;    // Wiener noise-to-signal ratio (the regulariser of the baseline)
  double saturation = 0.99;    // B ≥ this (intensity, per channel) is saturated: out of the TV data term
  bool mask_saturated = true;  // false: saturated pixels are fitted like any other (for measuring the mask)
  bool free_boundary = true;   // TV: padding out of the data term (false: the reflect-padded data is fitted)
  bool single_precision = true;  // CV_32F DFTs (about 2x faster, half the memory); false: CV_64F, the reference
  // Large images are deconvolved in tiles of about this FFT size (0: the whole image at once); each tile fits its
  // core plus `tile_overlap` px on every side (0: twice the kernel's extent) and keeps the core. Images that fit in
  // 1.25 tiles are done whole. 1536 (640, then 960 with OpenCV's DFT): with FFTW's transforms at 12 MP and a 25 px
  // kernel, 8 TV steps take 8.8 s wall against 10.1 s at 960 (FFT area 1.25× the image instead of 1.38×; medians of
  // 3, docs/RESULTS.md "Speed at 12 MP"), and the fewer seams gain +0.1 dB.
  int tile_size = 1536;
  int tile_overlap = 0;
  // Called after each (channel, tile) job of deconvolve() with the fraction of jobs done and "done/total", one call
  // at a time (under a lock, from the job's thread); empty: none.
  std::function<void(double fraction, const std::string& detail)> progress;
  void check() const;          // throws InvalidInput naming the bad option

  // These options with the fast TV schedule (`crfcal deblur --fast`): 8 u-steps at β = 128 instead of 25 at β = 256,
  // about a third of the time (12 MP: 7.5 s against 22.2 s). Levin bench: −0.8 dB, the irradiance domain's gain over the intensity domain +3.25 dB instead of
  // +3.79 (docs/RESULTS.md, "Speed: fewer TV steps").
  DeconvolutionOptions withFastSchedule() const;
};

struct DeconvolutionResult {
  cv::Mat deblurred;                    // CV_64F in [0,1], intensity, same size and channels as the input
  DeconvolutionOptions options;         // as used
  int iterations = 0;                   // u-steps of the first tile (TV), 1 for Wiener
  int tiles = 1;                        // tiles per channel
  long long saturated_pixels = 0;       // masked pixel-channels (TV with mask_saturated)
  cv::Size padded_size;                 // FFT size of the first tile
  int kernels = 1;                      // distinct kernels the tiles used (local kernels: each tile the nearest)
  double seconds = 0;                   // wall time
  double prepare_seconds = 0;           // of which: φ(B) and the data masks
  double solve_seconds = 0;             // the (channel, tile) solves with ψ of their cores; the rest: releases
  std::string summary() const;
};

// Deconvolves one channel `observed` (CV_32F or CV_64F, in the domain to deconvolve) with `kernel`; `data_mask`
// (CV_8U, same size, 0 = excluded; empty = all pixels) enters the TV data term. Large images go tile by tile (the
// tiles in parallel). Returns a CV_64F image of the same size, not clamped. `iterations` (optional) receives the
// number of u-steps of the first tile.
cv::Mat deconvolveChannel(const cv::Mat& observed, const cv::Mat& kernel, const cv::Mat& data_mask,
                          const DeconvolutionOptions& options, int* iterations = nullptr);

// Deblurs `blurred` (1 or 3 channels, CV_8U/16U/32F/64F; integer types scaled to [0,1]) with `kernel` (normalised
// here; throws InvalidInput for a kernel normalizeKernel rejects) in options.domain, each channel with its own φ
// (`curves`: one for all channels or one per channel, in the image's channel order); every (channel, tile) pair is
// one parallel job.
DeconvolutionResult deconvolve(const cv::Mat& blurred, const cv::Mat& kernel, const std::vector<ResponseCurve>& curves,
                               const DeconvolutionOptions& options = {});

// A kernel that holds around `centre` (pixels of the blurred image): a blur that varies across the frame, estimated
// per tile (PairCalibrationResult::tile_kernels).
struct LocalKernel {
  cv::Point2d centre;
  cv::Mat kernel;
};

// As above with local kernels: each tile is deconvolved with the kernel whose centre is nearest the tile's own
// centre, the tiles no larger than the centres' spacing (cores of about the distance between the two closest
// centres, at least 64 px; options.tile_size stays the upper limit, 0 = the whole image with the kernel nearest its
// centre); the tiles' overlap and padding follow the largest kernel. One local kernel is deconvolve() with that kernel.
DeconvolutionResult deconvolve(const cv::Mat& blurred, const std::vector<LocalKernel>& kernels,
                               const std::vector<ResponseCurve>& curves, const DeconvolutionOptions& options = {});

// PSNR in dB of `estimate` against `reference` (both [0,1]), ignoring `border` pixels on every side.
double psnr(const cv::Mat& estimate, const cv::Mat& reference, int border = 0);

}  // namespace crfcal
