#pragma once
// The dual-image CRF fitter (seed Sec. 4): given a sharp image I, a blurred image B and the kernel K, recover
// the inverse response φ and the exposure ratio r of B = ψ(r · (φ(I) ⊗ K)) (Eq. 4).
//
// Objectives:
//  * seed_intensity — the seed's Eq. 22 as published: J(φ) = ‖W · (ψ(r · φ(I) ⊗ K) − B)‖², W = Γ where
//    Γ > τ1 (Eq. 23, r = 1) or W = Imax − Imin where > τ2 (Eq. 24, r ≠ 1), GGCM φ (Eq. 19), r from Eq. 25,
//    Nelder–Mead. The mixtures φ(I) ⊗ K are sparse level mixtures (level_mixture.hpp), never convolutions.
//  * moments (crfcal's default) — binned irradiance moments (an instrumental-variable / GMM estimator).
//    The sharp image I is noisy, B is not (the long exposure). For every selected pixel p the irradiance
//    residual e_p = r · Σ_v w_p(v) g(x_v) − φ(B_p), with g = φ (default) or g = R φ the noise-debiased level
//    function (NoiseHandling::debias, noise_debias.hpp: E[g(I) | clean c] = φ(c), zero-mean residuals).
//    Pixels are grouped by instruments computed from B alone (bins of B's level × the position of B_p inside
//    B's local range), so that the noise averages out in the group sums Σ_{p∈k} e_p *before* it is squared (the
//    errors-in-variables bias of per-pixel least squares and the selection bias of thresholds computed on the
//    noisy I are avoided). Jensen's bias E[φ(I + n)] − φ(I), second order in σ, is removed only by the
//    debiasing, which amplifies the noise and measured worse except at σ² = 0.001 (docs/RESULTS.md); by default
//    it remains (the bench's shape error stays 0.004–0.006 over σ² = 0.001–0.01). With the sums
//    H_k = Σ_{p∈k} w_p (kernel-mass histograms of I's levels, debiased as Rᵀ H_k) and N_k = Σ_{p∈k} δ_{B_p},
//      J(φ, r) = Σ_k ω_k ((r Rᵀ H_k − N_k) · φ)²,  ω_k = 1 / (n_k · s_k²),
//    with s_k the bin's per-pixel irradiance scale (φ'(B) times the intensity noise). An evaluation costs
//    O(bins × levels) — independent of the image size.
// Models: GGCM (Eq. 19, n = 4; Levenberg–Marquardt on (α, r) from several starts) and EMoR (first
// `emor_terms` PCA curves; linear least squares in the coefficients, alternated with the closed-form r, then a
// penalised refinement if not monotone). `model = automatic` picks the candidate with the lower 2-fold
// cross-validated energy (pixels split in 16×16 tiles, checkerboard; fit on one half, energy on the other,
// summed both ways).
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/chroma_subsampling.hpp"
#include "crfcal/learned_curve_prior.hpp"
#include "crfcal/noise_debias.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal {

// The exposure ratios crfcal considers (4.3 stops either way; real pairs have r = 3–8, the benches up to 16): the
// fitter's closed-form r (Eq. 25, EMoR and the seed's alternation) is clamped to them, and the effect search takes a
// free r outside them for a runaway of its linearised model (effect_problem.hpp, fittableExposureRatio).
inline constexpr double kMinExposureRatio = 0.05, kMaxExposureRatio = 20.0;

enum class CrfModelChoice { ggcm, emor, automatic };
enum class CrfObjective { seed_intensity, moments };
enum class CrfOptimizer { nelder_mead, levenberg_marquardt };
// none: I used as is. debias: errors-in-variables level functions g = R φ (σ of I estimated unless given).
// denoise: an edge-preserving (bilateral, range 2σ) filter on I before building the mixtures.
// jensen: the second-order correction g = φ − ½σ²φ'' (a local operator: Jensen's bias removed to O(σ⁴) without
// the deconvolution's noise amplification).
enum class NoiseHandling { none, debias, denoise, jensen };

const char* toString(CrfModelChoice value);
const char* toString(CrfObjective value);
const char* toString(CrfOptimizer value);
const char* toString(NoiseHandling value);
NoiseHandling noiseHandlingFromString(const std::string& name);  // throws InvalidInput for an unknown name

struct CrfFitOptions {
  CrfModelChoice model = CrfModelChoice::automatic;
  int ggcm_degree = 4;   // n of Eq. 19 ("n = 4 is usually accurate enough", Sec. 4)
  int emor_terms = 5;    // EMoR basis curves (Grossberg & Nayar: 3–5 reach DoRF accuracy)
  // The nominal exposure ratio r of B to I: from EXIF (footnote 4) or given (--ratio). The start of r (the seed's
  // Eq. 25 alternation, the moments' joint fit), its value when fit_ratio is false, and the centre of the optional
  // ratio prior.
  double nominal_ratio = 1.0;
  bool fit_ratio = true;       // seed: Eq. 25 alternation; moments: r estimated jointly with φ
  // moments, r fitted: σ of a Gaussian prior on log r centred on nominal_ratio (0: off, r from the images alone).
  // φ^γ with r^γ fits a plain two-exposure pair equally well (the exponential ambiguity); only the blur
  // inconsistency (Sec. 3) separates them, so with little blur the images barely determine r and the fit drifts
  // along that valley. The prior row is scaled by the residual variance of the prior-free fit, so it is a posterior:
  // a sharply determined r keeps the images' value, an undetermined one returns to EXIF. A width for real EXIF:
  // nominal values are rounded to 1/3 stop (±1/6 stop on ISO and time of both shots alone give σ ≈ 0.13) and
  // cameras re-meter (docs/RESULTS.md#studies, ratio: 4 % per bracket step, 0.20 on phone pairs), so 0.2
  // (`calibrate --ratio-prior 0.2`). Off by default: measured, it does not move the biased low r of small-blur
  // pairs (the data determine it firmly) and it made the vivo curves agree less (docs/RESULTS.md#small-blur).
  double ratio_prior_sigma = 0;
  int multi_starts = 4;        // GGCM starts (EMoR projection + γ 2.2, 1.6, 3.0, 1.0)
  // moments, LM: a fit of the same pair to start from (the curve band's half-sample refits start from the whole
  // pair's fit: a half's optimum lies next to the whole's). When `model` names the start's kind (GGCM or EMoR), that
  // model is fitted from this start alone instead of its usual starts, the other model is not fitted, and r starts
  // at `ratio`. Empty (the default): the usual starts.
  struct Start {
    ResponseModel model;
    double ratio = 1;
  };
  std::optional<Start> start;
  double noise_sigma = -1;     // std of I's noise, intensities in [0,1]; < 0: estimated (noise_estimation.hpp)
  // Optional signal-dependent noise of I: σ as a function of the clean level v = 0..levels−1 (size = the level
  // grid of the fit: 256 for 8-bit data, 1024 otherwise). Empty: homoscedastic `noise_sigma`. Used for the rows
  // of the debias transition matrix (noise_debias.hpp) and for the moment weights. Wrong size → InvalidInput.
  std::vector<double> noise_sigma_per_level;
  double edge_threshold = 0.02;         // moments: local range of B over the kernel support > this
  int level_bins = 64;                  // moments: bins of B's level
  int position_bins = 2;                // moments: bins of the local min and of the local max of B over the support
  // moments: weight λ of the extrapolation prior λ Σ (g_{j+1} − g_j)², g_j = Δlog φ / Δlog x the local exponent
  // between nodes j/64, on the nodes below the levels the data cover (above them: shoulder_prior). With r = 1 the moments (and the
  // seed's Eq. 22) determine φ on the covered levels only up to an affine map a + bφ (the mixture of a constant
  // is the constant), so φ(0) = 0 and φ(1) = 1 — i.e. the offset and scale of the whole curve — rest on the model's
  // extrapolation; the prior keeps the local gamma changing there the way the data show (zero for any x^γ) instead
  // of a cliff. 0: off.
  double exponent_smoothness = 1e-4;
  // moments: weight of the prior on the local exponent above the covered levels. Real CRFs compress highlights (a
  // shoulder: φ's local exponent rises towards x = 1, up to 4.5–19 on the ten Middlebury cameras), so a symmetric
  // smoothness there is wrong (it raised `bench pairs` to 0.0217). With experimental.shoulder_follows_emor_mean =
  // false a falling exponent costs this weight and a rising one is free: `bench synthetic` 0.0285/0.0308/0.0291 (no
  // priors) → 0.0272/0.0305/0.0291 (docs/RESULTS.md#synthetic-benchmark). But then a pair whose data stop at x = 0.47
  // can put most of φ's scale into a steep rise above the data (a real phone pair: φ_G(0.47) = 0.055, 0.002 with r
  // at EXIF).
  double shoulder_prior = 1e-1;
  // moments: the two priors above only break ties the data leave open. φ is fitted without them and with them; the
  // regularised fit is kept while its data energy is at most this factor times the unregularised one. Measured: on
  // noisy pairs the affine-equivalent curves differ by factors 0.9–2.6 (noise and the model's systematic misfit);
  // on exactly representable noise-free data the prior would cost a factor ~10⁴, so the exact fit is kept.
  double prior_energy_factor = 2.0;
  // moments: lower bound on the local exponent d log φ / d log x between nodes j/64, everywhere (a hinge penalty,
  // zero above it). The affine freedom above lets a fit flatten φ to a + bφ_true with b → 0 (φ ≈ const ≈ 1 on the
  // data, a cliff at 0) at no cost in energy; measured inverse CRFs are far from that (local exponent ≥ 0.56 on the
  // ten Middlebury cameras, ≥ 1 for any gamma curve), so a bound of half the most concave measured one removes the
  // degenerate solutions without touching real curves. 0: off.
  double min_local_exponent = 0.25;
  // moments: a prior over φ outside the covered levels learned from measured curves (learned_curve_prior.hpp, issue
  // 19), added to the hand-set priors above (alone it lost to them: a synthetic r = 1 test,
  // docs/RESULTS.md#learned-prior): the joint Gaussian of φ's local exponents, rows
  // √learned_prior_weight · s · Σ^{-1/2}(g_U − E[g_U | g_O])
  // outside the covered levels and Σ_OO^{-1/2}(g_O − μ_O) inside, s the prior-free fit's residual per data row (so
  // that weight 1 is the posterior); the fit with it is kept under prior_energy_factor like the hand-set priors.
  // null (default): the hand-set priors only.
  std::shared_ptr<const LearnedCurvePrior> learned_prior;
  double learned_prior_weight = 1;
  double saturation_high = 254.5 / 255.0;  // B or I at/above: saturated (dilated by the kernel's support)
  double saturation_low = 0.5 / 255.0;     // B or I at/below: censored black (dilated likewise; a noisy I: its 5×5 median)
  // moments: weight λ of the saturated pixels of B as censored observations (issue 19; crf_censored.hpp). φ → bφ
  // leaves Eq. 4 unchanged, so φ(1) = 1 is otherwise reached by extrapolation from the top of the data. Where B
  // clips, r · (φ(I) ⊗ K) ≥ φ(saturation_high): each clipped pixel on the rim of a clipped region adds the
  // censored-Gaussian −log Φ (a clear violation by δ in B's intensity costs δ², as a data pixel misfit by δ does):
  // λ = 1 weighs them as data. Pixels whose support touches I's highlights, black or the border are not used (I
  // clipped too says nothing). Only the clipped side: the unclipped pixels next to a clip (resampled and JPEG-ringing
  // B) pulled r down by 8 % on the r = 4 bench. 0: off (the seed's "exclude saturated pixels").
  double censored_weight = 0;
  // moments, censored pixels: σ floor of ψ(r · (φ(I) ⊗ K)) at the clip in B's intensity units (B's noise, JPEG,
  // resampling); I's noise through the kernel adds to it per pixel.
  double censored_sigma_floor = 2.0 / 255;
  // moments, censored pixels: the clip condition is relaxed by this many σ_p (−log Φ(t + κ)): a pixel within its
  // noise of the clip costs nothing and does not push φ; only clear violations do.
  double censored_margin = 2.0;
  int max_censored_pixels = 2000;  // deterministic subsample above this (0: all)
  // Optional CV_32F map of the pair's size: a bound of the error of I's values that the pointwise model cannot
  // represent, in [0, 1] units — the lost chroma detail of a subsampled JPEG (chroma_subsampling.hpp). A pixel is
  // used only if the kernel-weighted bound over its support, (bound ⊗ K)(p), is at most max_sharp_error: its mixture
  // φ(I) ⊗ K is then off by at most about φ' times that. Empty: none (today's model). Wrong size → InvalidInput.
  cv::Mat sharp_error_bound;
  // 4 levels of 8 bits. Measured on the demo pair (RESULTS#chroma): 2 levels leave too few R pixels (R 0.043), 8 too
  // many chroma edges (B 0.073); the oracle (true error) at 4 levels: R 0.011, B 0.026.
  double max_sharp_error = 4.0 / 255;
  // With sharp_error_bound: a level range of I the bound (nearly) empties keeps its least affected pixels, so that φ is
  // not extrapolated there (chroma_subsampling.hpp LevelFloor; measured: RESULTS#chroma).
  LevelFloor sharp_error_floor;
  int max_evaluations = 1000;  // per Nelder–Mead run / LM iterations × 10
  int min_pixels = 200;        // fewer usable pixels: the pair has no edges → InvalidInput
  int max_pixels = 0;          // deterministic subsample above this (0: all pixels)
  // Optional CV_8U mask of the images' size: only pixels where it is non-zero may be used (the curve band's
  // resampling of image blocks, curve_band.hpp). Empty: every pixel. Wrong size → InvalidInput.
  cv::Mat pixel_selection;
  int threads = 0;             // 0: OpenCV's default
  std::function<void(double fraction, const std::string& stage)> progress;  // optional

  // Ablations and the seed's published method, kept for the benchmarks' comparisons (`bench synthetic`
  // variants, `calibrate --noise-handling/--shoulder`). The defaults are crfcal's method; every other value was
  // measured no better on the benchmarks (docs/RESULTS.md), except where noted.
  struct Experimental {
    CrfObjective objective = CrfObjective::moments;  // seed_intensity: the seed's Eq. 22 (with tau1, tau2, ratio_rounds)
    CrfOptimizer optimizer = CrfOptimizer::levenberg_marquardt;  // for GGCM; EMoR is linear
    double tau1 = 0.02;    // seed_intensity, Eq. 23: W = Γ where Γ > τ1 (r = 1)
    double tau2 = 0.2;     // seed_intensity, Eq. 24: W = Imax − Imin where > τ2 (r ≠ 1)
    int ratio_rounds = 6;  // seed_intensity: alternations φ-step / r-step (Eq. 25) at most
    NoiseHandling noise = NoiseHandling::none;  // debias helps only at σ² = 0.001 (measured); see the bench
    double debias_regularization = 1e-4;        // noise = debias: λ of the deconvolution (noise_debias.hpp)
    DebiasRegularizer debias_regularizer = DebiasRegularizer::smoothness;  // noise = debias: its penalty
    // moments: continuously-updated GMM — every bin sum divided by its model standard deviation at the current φ
    // (I's noise through the transition matrix + quantisation), so the squared noise adds a φ-independent
    // constant; fitted from the least-squares solution; then GGCM vs EMoR by the lower CUE energy (equal parameter
    // counts). Measured worse (docs/RESULTS.md#synthetic-benchmark).
    bool variance_correction = false;
    // true: above the data φ's local exponent changes as the EMoR mean curve g0's does (the measured average
    // shoulder of 201 real responses), each difference penalised with shoulder_prior. false (default): the one-sided
    // prior (every rise free, a fall costs). Measured (docs/RESULTS.md#vivo): the mean shoulder makes curves that
    // stop early agree (vivo green spread 0.216 → 0.049) and helps the seed benchmark's 8-bit reading
    // (0.0081/0.0074/0.0064 → 0.0070/0.0061/0.0053), but where truth is known and the data stop early it is not
    // better: a clipped Olympus E500 pair 0.0133 → 0.0563, the [0, 1] reading at σ² = 0.001 0.0272 → 0.0285, a pure
    // power law at r = 1 worse. Real shoulders vary too much (local exponent up to 4.5–19) for the mean one to be a
    // safe default.
    bool shoulder_follows_emor_mean = false;
    // Which black pixels of I are censored (their kernel support dropped). false (default): every black pixel of a
    // clean I, only black regions (5×5 median) where I's noise reaches black — σ̂ above one 8-bit level at full or at
    // half resolution (a JPEG hides the noise from the finest scale). true: the rule before stop 37, which read the
    // full resolution only (docs/RESULTS.md#black-end). For ablations (`bench pairs --black-end per-pixel`, `study
    // pairs`).
    bool black_per_pixel_when_clean = false;
  } experimental;

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
  double criterion = 0;        // 2-fold cross-validated energy (lower is better); = energy without CV
  bool valid = false;          // monotone, φ(0) = 0, φ(1) = 1
  int evaluations = 0;
};

struct CrfPixelAccounting {
  int total = 0;       // all pixels
  int border = 0;      // kernel support leaves the image
  int saturated = 0;   // saturated/censored in B or I (dilated by the support), inside the border
  int unmodelled = 0;  // not saturated, but I's kernel-weighted error bound above max_sharp_error (sharp_error_bound)
  int low_weight = 0;  // not an edge: W = 0 (Eq. 23/24) or B's local range ≤ edge_threshold
  int subsampled = 0;  // usable but dropped by max_pixels
  int used = 0;
  int censored_clipped = 0;  // B clipped, used as censored observations (CrfFitOptions::censored_weight)
  cv::Mat used_mask;   // CV_8U, 255 at used pixels
};

struct CrfFitTimings {
  double prepare_s = 0;  // levels, noise estimate, masks, debias operator
  double mixture_s = 0;  // sparse level mixtures / moment sums
  double optimise_s = 0;
  double total_s = 0;
};

struct CrfFitResult {
  ResponseModel model;              // the chosen φ
  std::vector<double> inverse_crf;  // φ(i/1023), i = 0..1023
  double ratio = 1;                 // r (Eq. 4)
  double nominal_ratio = 1;         // CrfFitOptions::nominal_ratio (EXIF or given)
  double ratio_images_only = 0;     // with a ratio prior: r of the prior-free EMoR fit (what the images alone say)
  double ratio_prior_scale = 0;     // with a ratio prior: the prior row's scale (0: the prior was not applied)
  // moments: relative rise of the data energy when φ, r move to φ^γ, r^γ with γ = 0.9 or 1.1 (the smaller of the
  // two). ~0: the blur does not separate the exponent from r (a plain two-exposure pair); large: it does. Negative
  // when the fitted model, held by its priors, is not at the bottom of that valley. A diagnostic (measured: Levin
  // kernels 0.8–31, box blurs of 2–7 px −0.25–1.2; docs/RESULTS.md#small-blur), not used for decisions.
  double ambiguity_rise = 0;
  double energy = 0;                // final objective (per unit weight)
  int iterations = 0;               // φ/r alternations or LM iterations
  int evaluations = 0;              // objective evaluations, all optimiser runs
  std::vector<CrfCandidate> candidates;
  std::string chosen;               // kind of the chosen candidate
  std::string choice_reason;
  CrfPixelAccounting pixels;
  double noise_sigma = 0;           // σ of I used (estimated or given; mean over levels when per level)
  bool noise_sigma_estimated = false;
  int levels = 256;                 // level grid of the mixtures
  int moment_bins = 0;              // non-empty instrument bins (moments)
  std::pair<int, int> covered_levels{0, 0};  // lowest/highest level of the data (moments; 0.1 % tails dropped)
  std::size_t mixture_nonzeros = 0;
  CrfObjective objective = CrfObjective::moments;
  CrfOptimizer optimizer = CrfOptimizer::levenberg_marquardt;
  CrfFitTimings timings;

  std::string summary() const;
};

// sharp/blurred: registered single-channel images (CV_8U, CV_16U or CV_64F/CV_32F in [0,1]); kernel: blur
// kernel (normalised internally). Throws InvalidInput for a size mismatch, a pair without edges (too few usable
// pixels: "no usable edges") and a pair whose pixels are all saturated. The returned φ is always valid.
CrfFitResult fitInverseCrf(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                           const CrfFitOptions& options = {});

// fitInverseCrf with r fitted (options.fit_ratio), then φ fitted again on the same pixels with r held at
// held_ratio(first fit's r) (nominal_ratio = it, fit_ratio off; a start given in options becomes the first fit's
// model at that r): the two results of two fitInverseCrf calls, but the pixels, noise operators and moments — which
// do not depend on r, the ratio's prior or the start with the moment objectives — are prepared once (two thirds of a fit
// on a 0.1 MP pair; the seed's intensity objective is fitted twice).
// The band's half-sample refits with the pair's ratio rule (curve_band.hpp) are its use. Throws as fitInverseCrf, and
// InvalidInput when options.fit_ratio is off.
struct CrfFitAtHeldRatio {
  CrfFitResult free_ratio;  // r fitted
  CrfFitResult held_ratio;  // φ at the held r
};
CrfFitAtHeldRatio fitInverseCrfThenHoldRatio(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                             const CrfFitOptions& options,
                                             const std::function<double(double fitted_ratio)>& held_ratio);

// φ fitted at each of `ratios` held (fit_ratio off, nominal_ratio = that r; a start given in options starts every fit,
// its r replaced by the held one) on one preparation of the pixels and moments (which do not depend on r with the
// moment objectives): the results of one fitInverseCrf call per ratio. The band's ratio term (curve_band.hpp) is its
// use: how the fit's φ moves when r is held a σ of log r away. Throws as fitInverseCrf, and InvalidInput for a
// ratio ≤ 0.
std::vector<CrfFitResult> fitInverseCrfAtHeldRatios(const cv::Mat& sharp, const cv::Mat& blurred,
                                                    const cv::Mat& kernel, const CrfFitOptions& options,
                                                    const std::vector<double>& ratios);

}  // namespace crfcal
