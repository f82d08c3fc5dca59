#pragma once
// Diagnostics after the φ fit: are the residuals of the seed's model B = ψ(r · (φ(I) ⊗ K)) (Eq. 4) explained by a
// named effect that the model lacks? Each effect is an extended model; it is kept only when it lowers the
// HELD-OUT error by a documented criterion (never by a threshold tuned on particular data).
//
// Residuals (irradiance domain, intensity-scaled like the fitter's ω = 1/φ'(B)², Eq. 21 to first order):
//   e_p = (φ(B_p) − Ŷ_p) / φ'(B_p),   base model Ŷ = a · (φ(I) ⊗ K)(p)  (a = the exposure ratio, free)
// on a regular subsample of the unsaturated pixels of the fit window (flat and edge pixels alike).
// Extended models (all nested in the base; linear in their parameters unless noted):
//   vignetting              Ŷ = a X (1 + v₁ρ² + v₂ρ⁴)        ρ = distance to the frame centre / half-diagonal
//                                                             (the two shots can differ in aperture)
//   black_level_offset      Ŷ = a X + c                       (flare / black-level offset in one shot)
//   channel_mixing          Ŷ_c = Σ_d m_cd X_d                 (3×3 mix before the per-channel curves; rgb only)
//   clipping                Ŷ = min(a X, c)                   (sensor or processing clip below full scale)
//   spatially_varying_blur  X from per-tile kernels (grid of tiles) instead of one K
//   exposure_ratio_mismatch a free vs a fixed to the EXIF ratio (footnote 4), within the selected model
//   signal_dependent_noise  Var(e) = α + β · level vs constant (held-out Gaussian likelihood)
// Every model (base included) may also re-adjust φ by `phi_terms` EMoR basis curves h_k, linearised:
// columns a₀ (K ⊗ h_k(I)) − h_k(B) — so an effect that the base φ fit partly absorbed is still visible.
// signal_dependent_noise: held-out residual variance modelled as α u + γ (σ_I constant in intensity, the fitter's
// assumption; u = (a/φ'(B))² K²⊗φ'(I)²) vs α u + β t + γ (σ_I² = α + β I; t = (a/φ'(B))² K²⊗(φ'(I)² I)).
// Cross-validation: the window is cut in a grid of tiles, each tile in two halves; the halves form two folds in a
// checkerboard. Parameters (and, for spatially_varying_blur, the tile kernels) are fitted on one fold and the
// error is measured on the other, both ways. The held-out error E = Σ e² is accumulated per 32×32 block.
// Criterion (every effect): relative held-out drop  gain = (E_base − E_ext) / E_base ≥ min_gain  AND the paired
// block differences d_b = E_base,b − E_ext,b significant: z = mean(d) / (sd(d) / √n) ≥ min_z (tile-to-tile
// spread, a one-sided paired test). Effects are added greedily (largest significant gain first, the rest
// re-tested against the grown model), so one planted effect does not make its confounders fire.
// exposure_ratio_mismatch in addition needs |a / r_EXIF − 1| > ratio_tolerance (nominal EXIF times and
// apertures are rounded to 1/3 stop). signal_dependent_noise uses the held-out negative log-likelihood drop per
// sample (nats) ≥ min_nll_gain with the same paired z.
// When an effect is detected the reported φ comes from the extended model: the images are corrected with the
// fitted parameters (B' = ψ(φ(B)/g(ρ)), B' = ψ(φ(B) − c) or I' = ψ(φ(I) − d), B' = ψ(M⁻¹ φ(B))), the clip level
// is excluded like saturation, per-tile fits with per-tile kernels are averaged — then φ is refitted
// (fitInverseCrf, same options). signal_dependent_noise and exposure_ratio_mismatch keep the base φ (the fitter
// already fits r freely; it has no per-pixel weights) — their entries say so.
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
  double min_z = 3.0;            // paired block test of the drop (one-sided, ≈ p < 0.002 for normal blocks)
  double min_nll_gain = 0.05;    // signal_dependent_noise: held-out NLL drop per sample, nats
  double ratio_tolerance = 0.10; // exposure_ratio_mismatch: |a/r_EXIF − 1| above this (EXIF values are nominal)
  int block = 32;                // pairing block side, pixels
  int max_samples = 40000;       // regular subsample of the usable pixels per channel
  int grid = 0;                  // tiles per side for the folds / per-tile kernels (0: 2 below 600 px, else 3)
  double min_derivative = 0.05;  // φ' floor in the residual scaling
  int phi_terms = 1;             // every model (base too) may re-adjust φ by this many EMoR basis curves
                                 // (linearised), so that a φ that absorbed an effect does not hide it
  bool test_spatial_blur = true; // needs 2·grid² + 2 kernel estimations (the slowest test)
  bool refit = true;             // refit φ with the extended model when an effect is detected
  void check() const;            // throws InvalidInput
};

struct EffectEntry {
  std::string name;
  bool detected = false;
  bool tested = false;           // false: not applicable (detail says why)
  double statistic = 0;          // paired z of the held-out drop
  double threshold = 0;          // min_z
  double gain = 0;               // relative held-out error drop (nats per sample for signal_dependent_noise)
  double gain_threshold = 0;     // min_gain (min_nll_gain)
  std::map<std::string, double> parameters;  // the extended model's fitted parameters
  std::string detail;
};

struct EffectReport {
  std::vector<EffectEntry> entries;              // one per name of effectNames()
  std::map<std::string, CrfFitResult> fits;      // φ per channel from the extended model (empty: no refit)
  int samples = 0;                               // residual samples per channel
  double base_error = 0;                         // held-out Σe² / n of the base model (intensity units²)
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
  double exif_ratio = 0;                           // ≤ 0: unknown (exposure_ratio_mismatch not tested)
  cv::Point2d centre{-1, -1};                      // optical centre in window coordinates (< 0: window centre)
  double corner_radius = 0;                        // normalising radius (≤ 0: half-diagonal of the window)
  cv::Mat valid;                                   // optional CV_8U: usable pixels (registration overlap)
  CrfFitOptions fit;                               // the options of the base fits (refits use them)
  KernelEstimationOptions kernel_options;          // for the per-tile kernels
};

EffectReport diagnoseEffects(const EffectInputs& inputs, const EffectOptions& options = {});

}  // namespace crfcal
