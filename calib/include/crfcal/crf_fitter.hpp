#pragma once
// The dual-image CRF fitter (seed Sec. 4): given a sharp image I, a blurred image B and the kernel K, recover
// the inverse response φ and the exposure ratio r of B = ψ(r · (φ(I) ⊗ K)) (Eq. 4).
//
// Two objectives:
//  * seed_intensity — the seed's Eq. 22 as published: J(φ) = ‖W · (ψ(r · φ(I) ⊗ K) − B)‖², W = Γ where
//    Γ > τ1 (Eq. 23, r = 1) or W = Imax − Imin where > τ2 (Eq. 24, r ≠ 1), GGCM φ (Eq. 19), r from Eq. 25.
//  * corrected_irradiance (crfcal's default) — errors in variables. The residual is taken in the irradiance
//    domain, r_p = φ(B_p) − r · Σ_v w_p(v) g(x_v), with g = R φ the noise-debiased level function
//    (noise_debias.hpp) so that the mixture is an unbiased estimate of (φ(c) ⊗ K)(p) for the clean sharp
//    image c, and its noise variance (estimated without bias from the squared kernel masses) is subtracted:
//      J(φ) = Σ_p ω_p [ r_p² − r² Σ_v u_p(v) (g(x_v)² − (R φ²)(x_v)) ],   E[J] = Σ_p ω_p (noise-free residual)².
//    ω_p = 1/φ'(B_p)² (iteratively reweighted) makes J the first-order intensity-domain energy of Eq. 21.
//    Pixels are selected from B alone (B is the low-noise image: local range over the kernel support > 
//    `edge_threshold`), so the selection does not correlate with the noise of I. Because J is a quadratic form
//    in the values of φ on the level grid, J = φᵀ Q(r) φ with an L×L matrix Q accumulated once from the sparse
//    level mixtures (level_mixture.hpp): an evaluation costs O(L²), independent of the image size.
// Models: GGCM (Eq. 19, n = 4) and EMoR (first `emor_terms` PCA curves, linear: closed-form minimiser of the
// quadratic form, then constrained refinement if not monotone). `model = automatic` picks the candidate with
// the lower 2-fold cross-validated energy (pixels split in 16×16 tiles, checkerboard; fit on one half,
// corrected energy on the other, summed both ways).
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal {

enum class CrfModelChoice { ggcm, emor, automatic };
enum class CrfObjective { seed_intensity, noise_aware_intensity, corrected_irradiance, instrumental };
enum class CrfOptimizer { nelder_mead, lbfgs, bobyqa };
// none: I used as is. debias: errors-in-variables level functions (σ of I estimated unless given).
// denoise: an edge-preserving (bilateral) filter on I before building the mixtures, no debiasing.
enum class NoiseHandling { none, debias, denoise };

const char* toString(CrfModelChoice value);
const char* toString(CrfObjective value);
const char* toString(CrfOptimizer value);
const char* toString(NoiseHandling value);

struct CrfFitOptions {
  CrfModelChoice model = CrfModelChoice::automatic;
  int ggcm_degree = 4;   // n of Eq. 19 ("n = 4 is usually accurate enough", Sec. 4)
  int emor_terms = 5;    // EMoR basis curves (Grossberg & Nayar: 3–5 reach DoRF accuracy)
  double tau1 = 0.02;    // Eq. 23: W = Γ where Γ > τ1 (r = 1)
  double tau2 = 0.2;     // Eq. 24: W = Imax − Imin where > τ2 (r ≠ 1)
  double initial_ratio = 1.0;  // r from EXIF (footnote 4) or given
  bool fit_ratio = true;       // update r between φ steps (Eq. 25)
  CrfObjective objective = CrfObjective::noise_aware_intensity;
  CrfOptimizer optimizer = CrfOptimizer::bobyqa;
  int multi_starts = 4;        // GGCM starting points for lbfgs/bobyqa (EMoR projection + gammas)
  NoiseHandling noise = NoiseHandling::debias;
  double noise_sigma = -1;     // std of I's noise, intensities in [0,1]; < 0: estimated (noise_estimation.hpp)
  double debias_regularization = 1e-4;  // λ of the deconvolution (noise_debias.hpp)
  double edge_threshold = 0.02;         // corrected_irradiance: local range of B over the support > this
  double saturation_high = 254.5 / 255.0;  // B or I at/above: saturated (dilated by the kernel's support)
  double saturation_low = 0.5 / 255.0;     // B or I at/below: censored black (dilated likewise)
  int irls_rounds = 2;         // reweighting rounds of ω = 1/φ'(B)² (corrected_irradiance)
  int ratio_rounds = 6;        // alternations φ-step / r-step (Eq. 25) at most
  int max_evaluations = 1000;  // per optimiser run
  int min_pixels = 200;        // fewer usable pixels: the pair has no edges → InvalidInput
  int max_pixels = 8000;       // crfcal objectives: deterministic subsample above this (0: all)
  int threads = 0;             // 0: OpenCV's default
  std::function<void(double fraction, const std::string& stage)> progress;  // optional

  // The seed's method as published: Eq. 22 with Γ weights, GGCM n = 4, Nelder–Mead, no noise handling.
  static CrfFitOptions seed();
  void check() const;  // throws InvalidInput
};

struct CrfCandidate {
  std::string kind;            // "ggcm" or "emor"
  ResponseModel model;
  std::vector<double> inverse_crf;  // 1024 samples
  double ratio = 1;
  double energy = 0;           // objective per unit weight on all used pixels
  double criterion = 0;        // 2-fold cross-validated energy (lower is better); = energy for seed_intensity
  bool valid = false;          // monotone, φ(0) = 0, φ(1) = 1
  int evaluations = 0;
};

struct CrfPixelAccounting {
  int total = 0;       // all pixels
  int border = 0;      // kernel support leaves the image
  int saturated = 0;   // saturated/censored in B or I (dilated by the support), inside the border
  int low_weight = 0;  // not an edge: W = 0 (Eq. 23/24) or B's local range ≤ edge_threshold
  int subsampled = 0;  // usable but dropped by max_pixels
  int used = 0;
  cv::Mat used_mask;   // CV_8U, 255 at used pixels
};

struct CrfFitTimings {
  double prepare_s = 0;  // levels, noise estimate, masks
  double mixture_s = 0;  // sparse level mixtures (+ quadratic forms)
  double optimise_s = 0;
  double total_s = 0;
};

struct CrfFitResult {
  ResponseModel model;              // the chosen φ
  std::vector<double> inverse_crf;  // φ(i/1023), i = 0..1023
  double ratio = 1;                 // r (Eq. 4)
  double initial_ratio = 1;
  double energy = 0;                // final objective (per unit weight)
  int iterations = 0;               // φ/r alternations (× reweighting rounds)
  int evaluations = 0;              // objective evaluations, all optimiser runs
  std::vector<CrfCandidate> candidates;
  std::string chosen;               // kind of the chosen candidate
  std::string choice_reason;
  CrfPixelAccounting pixels;
  double noise_sigma = 0;           // σ of I used (estimated or given)
  bool noise_sigma_estimated = false;
  int levels = 256;                 // level grid of the mixtures
  std::size_t mixture_nonzeros = 0;
  CrfObjective objective = CrfObjective::noise_aware_intensity;
  CrfOptimizer optimizer = CrfOptimizer::bobyqa;
  CrfFitTimings timings;

  std::string summary() const;
};

// sharp/blurred: registered single-channel images (CV_8U, CV_16U or CV_64F/CV_32F in [0,1]); kernel: blur
// kernel (normalised internally). Throws InvalidInput for a size mismatch, a pair without edges (too few usable
// pixels) and a pair whose pixels are all saturated. The returned φ is always valid.
CrfFitResult fitInverseCrf(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                           const CrfFitOptions& options = {});

}  // namespace crfcal
