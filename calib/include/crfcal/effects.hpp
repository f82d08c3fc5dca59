#pragma once
// Diagnostics after the φ fit: are the residuals of the seed's model B = ψ(r · (φ(I) ⊗ K)) (Eq. 4) explained by a
// named effect that the model lacks? Each effect is an extended model; it is kept only when it lowers the
// HELD-OUT error by a documented criterion (never by a threshold tuned on particular data).
//
// Residuals (irradiance domain, intensity-scaled like the fitter's ω = 1/φ'(B)², Eq. 21 to first order):
//   e_p = (φ(B_p) − Ŷ_p) / φ'(B_p),   base model Ŷ = a · (g(I) ⊗ K)(p)  (a = the exposure ratio, free)
// on a regular subsample of the usable pixels of the fit window (flat and edge pixels alike; B's stored values within
// twice their rounding's σ of saturation_high — the 8-bit code 254 — count as saturated: a clipped highlight that JPEG
// or resampling moved just below full scale is saturation, not the clipping effect); g = φ as the base fit reads
// I: debiased for I's noise (g = R φ, noise_debias.hpp) only when the fit debiases (NoiseHandling::debias). A camera's
// noise enters the irradiance before the curve: φ(I) = clip(E + n) has no Jensen bias, only the clip at black that
// the fitter censors. The intensity-domain debias under the fitter's default named false offsets on clean
// real-regime pairs (docs/RESULTS.md#effects-debias). A noisy I's black and white are read by region (5×5 median), as
// in the fitter. φ is re-fitted jointly with every model (base included: the comparison is fair and nested):
// φ = φ̂ + Σ α_k h_k over the first `phi_terms` EMoR basis curves h_k, with φ'(B) in the residual following the
// re-fit (Levenberg–Marquardt; a fixed 1/φ̂' would let a re-fit "explain" everything by flattening φ), so an effect
// that the base fit absorbed into φ (an offset bends φ by ≈ c / (r − 1)) is still visible.
// Extended models (nested in the base):
//   vignetting              Ŷ = a X (1 + v₁ρ² + v₂ρ⁴)        ρ = distance to the frame centre / half-diagonal
//                                                             (the two shots can differ in aperture)
//   black_level_offset      Ŷ = a X + c                       (flare / black-level offset in one shot; an offset d
//                                                             in I is c = −a d), fitted jointly with φ
//   channel_mixing          Ŷ_c = Σ_d m_cd X_d                 (3×3 mix before the per-channel curves; rgb only;
//                                                             the row sum Σ_d m_cd is the exposure ratio; the
//                                                             channels' φ re-fits are coupled through X_d)
//   clipping                Ŷ = min(a X, φ(b_c))              (a plateau b_c of B below full scale: a sensor or
//                                                             processing clip; b_c on a grid of B's top quantiles,
//                                                             "none" included)
//   exposure_ratio_mismatch a free vs a = r_EXIF, each model with its own φ (the fitter with r fixed), within the
//                                                             selected model
//   spatially_varying_blur  a kernel varying with the position, K₀ + u K_x + v K_y + c R(u, v) (a camera roll to
//                           first order, and a roll spread about the centre to second: R = (−v ∂x + u ∂y)² K), vs
//                           one K₀; both models carry a shift field d(u, v) · ∇K, d linear (the misregistration
//                           registration leaves), and are fitted by least squares on the same fold (kernel
//                           estimated by the pipeline only)
// Cross-validation: the window is cut in a grid of tiles, each tile in two halves; the halves form two folds in a
// checkerboard. Parameters are fitted on one fold and the error is measured on the other, both ways (the extended
// model's fit starts from the base model's, so the comparison reflects the added parameters).
// Criterion: relative held-out drop gain = (E_base − E_ext) / E_base ≥ min_gain AND significant: a score test of
// the drop Σ d_i (d_i = e²_base,i − e²_ext,i) against what noise alone would give for the same change of
// prediction δ_i = e_base,i − e_ext,i, z = Σ d / (2 σ sqrt(A Σ δ²)) ≥ min_z, with σ² the base model's held-out
// residual variance and A the residuals' design effect (the variance inflation of 32×32 block sums: spatially
// correlated or systematically misfit residuals make the test conservative). Clipping acts locally: its drop is
// taken over the 16×16 blocks that contain plateau samples (chosen from B alone). Effects are added greedily:
// of the candidates that pass their own test, the one with the smallest held-out error over all held-back pixels
// first, its runner-up and the held-out drop against it recorded (effect_attribution.cpp); after each, the pair is corrected with the grown model, φ refitted until it
// settles and the remaining effects re-tested around it, so one planted effect does not make its confounders fire.
// A backward pass then drops any selected effect that no longer passes the same test inside the final model.
// exposure_ratio_mismatch in addition needs |a / r_EXIF − 1| > ratio_tolerance (nominal EXIF times, ISOs and
// f-numbers are rounded to 1/3 stop: up to ≈ 6 % each).
// It is the explanation of last resort: a level effect that, with r held at r_EXIF, passes its own test and leaves
// the free r no significant held-out drop against it is named instead (EffectEntry::explained_by). And the full fit of
// the seed's model must agree: started from a with r free, the fitter returns an r beyond ratio_tolerance on a's side
// of r_EXIF, else the name is withdrawn (parameters "full_fit_ratio", "not_confirmed_by_full_fit"; the linearised a
// re-fits φ by phi_terms EMoR curves only and can stray far from the fitter's r, e.g. beside a camera colour matrix).
// signal_dependent_noise is tested on I itself (its noise is what the seed models; in the residuals above it is
// averaged by the kernel and hidden under B's quantisation): Immerkær's residual (noise_estimation.hpp) in each of
// `noise_bins` level bins (equal counts of I's 5×5 local mean), on the 30 % of each bin with the least 7×7 residual
// energy (texture only adds energy; the same fraction everywhere keeps the ratios), same folds. Base: one variance
// for all levels (the seed's homoscedastic Gaussian); extended: one per level bin. Robust (MAD) scales on one fold,
// held-out Huber negative log-likelihood on the other; detected when the paired block t (as z) ≥ min_z AND the
// size of the level dependence — the variance ratio of the log-linear trend over the bins, across the levels the
// bins cover but at most 0.8 apart (0.1–0.9) — ≥ min_noise_contrast (below a contrast κ homoscedastic weights keep
// ≥ 4κ/(1+κ)² of the efficiency — Kantorovich — 89 % at κ = 2; the efficiency of the fit over the levels it has, so
// the trend is not extrapolated beyond them).
// When an effect is detected the reported φ comes from the extended model: the jointly re-fitted φ_ext and the
// parameters correct the pair (B' = ψ(φ(B)/g(ρ)) for vignetting, B' = ψ(φ(B) − c) for an offset,
// I'_c = ψ_c(φ_c(I_c) + Σ_d (m_cd/a_c)(φ_d(I_d) − φ_c(I_c))) for mixing — only the channel's own row; the plateau is
// excluded like saturation; a varying blur: one φ fitted to all tiles at once, each tile with its own kernel
// estimated in the irradiance domain (the check's varying kernel at its centre where it has too few edges); a
// level-dependent σ(v) goes to the fitter's noise_sigma_per_level when its noise handling uses σ; the extended
// model's r starts the fitter) and φ is refitted (fitInverseCrf, same options), `refit_rounds` times (parameters
// and φ_ext re-estimated with each refitted φ). With only exposure_ratio_mismatch, φ is refitted from the
// diagnostics' r when the fitter's own r differs by > 2 % (a wrong EXIF start can trap it); signal_dependent_noise
// keeps the fitted φ when the fitter uses no σ (noise handling none: the pixels are selected by B alone, so the
// noise law only changes the weights; what remains is the second-order Jensen bias of φ(I), as for homoscedastic
// noise of the same power) — the entry says so.
// The refit guard (effect_refit_guard.cpp): the refit's φ is adopted only when it is physically plausible (r on
// EXIF's side of 1, a vignetting corner gain within 0.5–2, r no further from EXIF than the base fit's by more than
// ratio_tolerance) and its held-out error — φ and r as reported, each under the model it was fitted under, the models'
// parameters fitted on one fold and measured on the other — is not larger than the base fit's. Otherwise the base
// fit's φ is reported, the effects stay named and the reason is recorded (refit_rejected_reason). A spatially
// varying blur's per-tile refit is judged, with the base fit's φ, under the varying kernel (the residual problem
// holds one kernel); beside a level effect by the plausibility checks only. A refit that cannot be fitted at all
// (the corrected pair leaves the fitter too few pixels) is reported as failed, with the fitter's reason.
// Code: the search's stages in effect_search.cpp, the shared residual problem in effect_problem.hpp, one file per
// effect test (effect_<name>.cpp); adding an effect is one file, one registry line and its name
// in effectNames() (effect_problem.hpp says how).
#include <map>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/crf_fitter.hpp"
#include "crfcal/kernel_estimation.hpp"

namespace crfcal {

// Effect names as they appear in report.json.
const std::vector<std::string>& effectNames();

struct EffectOptions {
  bool enabled = true;
  double min_gain = 0.05;        // relative held-out error drop required (5 %)
  double min_z = 3.0;            // significance of the drop (one-sided normal deviate, p ≈ 0.0013)
  double min_noise_contrast = 2.0;  // signal_dependent_noise: variance contrast over the level bins (Kantorovich)
  int noise_bins = 8;            // signal_dependent_noise: level bins (equal counts)
  double ratio_tolerance = 0.10; // exposure_ratio_mismatch: |a/r_EXIF − 1| above this (EXIF values are nominal)
  int block = 32;                // block side for the design effect and the noise test, pixels
  int max_samples = 40000;       // regular subsample of the usable pixels per channel
  int grid = 0;                  // tiles per side for the folds / per-tile refits (0: 2 below 600 px, else 3)
  double min_derivative = 0.05;  // φ' floor in the residual scaling
  int phi_terms = 4;             // every model (base too) re-fits φ by this many EMoR basis curves
  bool test_spatial_blur = true; // varying-kernel test (only when the pipeline estimated the kernel)
  bool refit = true;             // refit φ with the extended model when an effect is detected
  int refit_rounds = 3;          // correct → refit → re-estimate rounds: final, and after each effect the search
                                 // selects (until φ moves < 5e-4)
  void check() const;            // throws InvalidInput
};

struct EffectEntry {
  std::string name;
  bool detected = false;
  bool tested = false;           // false: not applicable (detail says why)
  double statistic = 0;          // z of the held-out drop (score test; noise: paired block t)
  double threshold = 0;          // min_z
  double gain = 0;               // relative held-out error drop (nats per sample for signal_dependent_noise)
  double gain_threshold = 0;     // min_gain (signal_dependent_noise: min_noise_contrast, on parameters["contrast"])
  std::map<std::string, double> parameters;  // the extended model's fitted parameters
  std::string detail;
  // Attribution (effect_attribution.cpp): a named effect against the competing explanation that came closest on
  // the held-back pixels (the runner-up), both fitted on one fold and measured on the other around the same φ.
  std::string runner_up;         // the runner-up's name (empty: no competitor was tested)
  double runner_up_gain = 0;     // the runner-up's own relative held-out drop against the same model
  double evidence_gain = 0;      // relative held-out drop from the runner-up's model to this effect's
  double evidence_z = 0;         // its score test (as `statistic`); < threshold: the data barely tell them apart
  // Not named because another effect explains the same misfit on the held-back pixels (exposure_ratio_mismatch:
  // that effect with r at the EXIF value explains it as well as a free r).
  std::string explained_by;
};

struct EffectReport {
  std::vector<EffectEntry> entries;              // one per name of effectNames()
  std::map<std::string, CrfFitResult> fits;      // φ per channel from the extended model (empty: no refit)
  int samples = 0;                               // residual samples per channel
  double base_error = 0;                         // held-out Σe² / n of the base model (intensity units²)
  // The refit guard (effect_refit_guard.cpp): a refit's φ replaces the base fit's only when it is physically
  // plausible, explains the held-back pixels at least as well as the base fit (each φ under its own model), and
  // at least as well as the base fit's φ does under the same extended model (the refitted φ, not only the effect,
  // must explain them).
  bool refit_tried = false;                      // a detected effect asked for a refit
  bool refit_adopted = false;                    // the refit's φ is reported (fits non-empty)
  bool refit_failed = false;                     // the corrected pair could not be refitted (no held-out errors)
  std::string refit_rejected_reason;             // why the base fit was kept (empty when adopted or not tried)
  double heldout_error_base_fit = 0;             // held-out Σe² / n: base φ and r under the base model
  double heldout_error_refit = 0;                // held-out Σe² / n: refitted φ and r under the selected model
  double heldout_error_base_fit_selected_model = 0;  // held-out Σe² / n: base φ and r under the selected model
  std::map<std::string, CrfFitResult> rejected_fits;  // a rejected refit's φ per channel (for comparison)
  double seconds = 0;
  std::vector<std::string> detected() const;
  const EffectEntry* find(const std::string& name) const;
  std::string summary() const;
};

// What the diagnostics need (everything inside the fit window, sharp already registered).
struct EffectInputs {
  std::vector<std::string> channels;               // "R","G","B" or "G"
  std::map<std::string, cv::Mat> sharp, blurred;   // single-channel CV_8U/CV_16U/float in [0,1]; sharp 0 = no data
  std::map<std::string, CrfFitResult> fits;        // the base fits
  cv::Mat kernel;                                  // the global kernel
  bool kernel_estimated = true;                    // false (given kernel): spatially_varying_blur not tested
  double nominal_ratio = 0;  // EXIF or --ratio (the r the fit starts from); ≤ 0: unknown (exposure_ratio_mismatch not tested)
  // r held at nominal_ratio because the blur is too small to fix it (PairCalibrationResult::ratio_fixed_by_small_blur):
  // a free r then moves along the φ^γ, r^γ ambiguity the blur cannot resolve (biased low, docs/RESULTS.md#small-blur),
  // so exposure_ratio_mismatch is tested around the current φ but not named.
  bool ratio_held_for_small_blur = false;
  cv::Point2d centre{-1, -1};                      // optical centre in window coordinates (< 0: window centre)
  double corner_radius = 0;                        // normalising radius (≤ 0: half-diagonal of the window)
  cv::Mat valid;                                   // optional CV_8U: usable pixels (registration overlap)
  CrfFitOptions fit;                               // the options of the base fits (refits use them)
  // A named spatially varying blur's refit estimates each tile's own kernel with these, in the irradiance domain
  // (lambda: the kernel↔φ rounds' PairCalibrationOptions::irradiance_kernel_lambda), weighted 1/φ'(B) unless off.
  KernelEstimationOptions kernel_options;
  bool weighted_tile_kernels = true;               // PairCalibrationOptions::weight_irradiance_kernel
};

EffectReport diagnoseEffects(const EffectInputs& inputs, const EffectOptions& options = {});

}  // namespace crfcal
