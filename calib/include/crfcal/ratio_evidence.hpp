#pragma once
// The exposure ratio r from all the pair's evidence (issue 17, item 3).
//
// Along the exponential ambiguity — φ^γ with r^γ fits a plain two-exposure pair as well as φ with r (Sec. 4: only
// the blur inconsistency Γ of Sec. 3 separates them) — the images fix log r only as well as the blur fixes γ. With
// little blur, a dark and noisy sharp shot (the real regime: the sharp shot underexposed by r, footnote 4) or a JPEG
// engine's local processing, the fitted r drifts along that valley (measured: real phone pairs at EXIF^0.36–0.47).
// The nominal ratio (EXIF, footnote 4, or --ratio) is independent evidence about r, so the two are combined by
// their precisions, in log r (a Gaussian posterior, the nominal ratio as the prior):
//
//   log r = (log r_images / σ_images² + log r_nominal / σ_nominal²) / (1 / σ_images² + 1 / σ_nominal²)
//
// σ_images is measured on the pair itself, not assumed: the spread of r over refits on half-samples of the image
// blocks (a block bootstrap, curve_band.hpp: Var(log r_half − log r_full) ≈ Var(log r_full)). A blur that fixes the
// exponent gives halves that agree and the images' r stands; where the blur does not, the halves scatter along the
// ambiguity and the nominal ratio takes over. σ_nominal is the rounding of nominal EXIF values, fixed a priori (not
// fitted to any pair). The resampling sees the images' sampling error, not a bias common to every half (the sharp
// shot's noise, JPEG, registration, the model's misfit): `images_exponent_sigma_floor` stands for it (SIMEX can
// measure the noise part, off by default: see measure_noise_bias).
//
// Conflict. When the two differ by more than `conflict_sigmas` σ of their difference, one of them is wrong (a wrong
// exponent: φ^γ, r^γ; or an EXIF that does not describe the exposure: a multi-frame long shot), and averaging two
// contradicting values would give an r neither supports. The shots' brightness ratio then arbitrates. It cannot be
// averaged in: measured with an assumed curve (the EMoR mean g0, as `crfcal study ratio`) it carries that curve's
// exponent, so it only bounds r to an interval [r_b^k_min, r_b^k_max] (the camera's curve g0^k, k from the measured
// cameras; channel_verdict.hpp), widened by the verdict's factor. If the nominal ratio lies in that interval and the
// images' r does not, r is held at the nominal ratio; in the mirror case the images' r is kept; otherwise (both or
// neither inside) the combination stands. The verdict (channel_verdict.hpp) reports every conflict.
// Pure computation: numbers in, numbers out.
#include <string>
#include <utility>
#include <vector>

namespace crfcal {

struct RatioEvidenceOptions {
  bool enabled = true;  // false: r from the images alone (the fit's own r), as before issue 17
  // σ of log r_nominal. Nominal ISO and exposure times are rounded to 1/3 stop: ±1/6 stop, uniform, i.e. σ =
  // (ln 2 / 6) / √3 = 0.067 per value in log; four values (ISO and time of both shots) → 0.13. Apertures (fixed on
  // phones, usually unchanged between the two shots of a pair) add nothing.
  double nominal_log_sigma = 0.13;
  // Half-sample refits of φ_G that measure σ_images (even, ≥ 2). Each sees half the blocks (≈ half a fit's cost).
  int replicates = 4;
  // The images' error the resampling cannot see (a bias common to every half-sample), added in quadrature to the
  // measured spread, as an error of the curve's EXPONENT: along the ambiguity φ^γ, r^γ an exponent error δγ moves
  // log r by δγ·|log r|, so the floor is images_exponent_sigma_floor · |log r_images| — nothing at r = 1, where r
  // is fixed by brightness alone (a 0.5 % pull towards a wrong --ratio cost φ 0.047 on the demo pair), growing with
  // the ratio as the real regime's underexposed sharp shot does. 0.072: 0.05 in log r at r = 2, the r error scale of
  // the r = 2 bench where the blur fixes r (worst base-fit error 2.2 %, held-out r = 2 pairs 1.5 % mean), chosen
  // there and reported on r = 1, 4, 8 and the phone pairs.
  double images_exponent_sigma_floor = 0.072;
  // Combined r differing from the images' by less than this relative amount is not worth a refit.
  double min_relative_change = 0.005;
  // Conflict between the images and the nominal ratio beyond this many σ (of their difference, √(σ_i² + σ_n²)):
  // one of them is wrong (a wrong exponent, a mis-read EXIF, a multi-frame long exposure); the verdict says so.
  double conflict_sigmas = 3.0;
  int block_size = 32;  // side of the resampled blocks (twice the kernel's side when larger; curve_band.hpp)
  // The noise bias of the images' r, which every half-sample shares: measured by SIMEX (simex.hpp: refits with extra
  // noise on I, extrapolated back to none; linear, λ = 0.5 and 1) and added in quadrature to σ_images as |Δ log r|.
  // Off: measured on `bench pairs --ratio 8` (cases 1, 5, 8, 9, 13) it points the wrong way on the two pairs whose r
  // is 46–52 % high (+0.13, +0.23 in log: SIMEX raises r further), misses a 18 % low one (+0.01), and triples the
  // stage's cost (three more fits of G). Kept as an option for the record (`calibrate --ratio-noise-bias`).
  bool measure_noise_bias = false;
  void check() const;   // throws InvalidInput
};

// How `RatioEvidence::ratio` was decided.
enum class RatioDecision {
  images_alone,    // no combination (disabled, no nominal ratio, too few refits)
  combined,        // the precision-weighted combination
  nominal_held,    // conflict; the brightness interval holds the nominal ratio and not the images' r
  images_kept,     // conflict; the brightness interval holds the images' r and not the nominal ratio
};
const char* toString(RatioDecision decision);

struct RatioEvidence {
  bool combined = false;          // the posterior was formed (enabled, r fitted, a nominal ratio, ≥ 2 refits)
  RatioDecision decision = RatioDecision::images_alone;
  double brightness_low = 0, brightness_high = 0;  // the brightness interval of r (0: not measured)
  double images_ratio = 0;        // r of the full fit (images alone)
  double images_log_sigma = 0;    // measured spread of log r over the half-sample refits, floor included
  double resampled_log_sigma = 0; // the spread alone, before the floor
  double noise_bias_log = 0;      // log r_SIMEX − log r_images (0: not measured)
  std::vector<double> replicate_ratios;  // r of each half-sample refit
  int failed_replicates = 0;
  double nominal_ratio = 0;       // EXIF or --ratio
  double nominal_log_sigma = 0;
  double ratio = 0;               // the combined r (posterior mode)
  double log_sigma = 0;           // its σ in log
  double images_weight = 1;       // share of the images in the combination, in [0, 1]
  double conflict_sigmas = 0;     // |log r_images − log r_nominal| / √(σ_images² + σ_nominal²)
  bool conflict = false;          // beyond RatioEvidenceOptions::conflict_sigmas
  // Set by the pipeline (pair_stage_ratio.cpp): why the combined r was not adopted although it differs (an effect's
  // extended model already explains the misfit with its own r; the effects found EXIF off on held-back pixels).
  std::string not_adopted_reason;
  double seconds = 0;
  std::string summary() const;    // one line with the numbers
};

// The combination above. `replicate_ratios`: r of half-sample refits of the same fit (fewer than 2, a nominal ratio
// ≤ 0 or images_ratio ≤ 0: combined = false, ratio = images_ratio). `brightness_interval`: the r the shots'
// brightness allows ({0, 0}: not measured; then a conflict keeps the combination). Throws InvalidInput for bad
// options.
// `noise_bias_log`: the measured noise bias of log r_images (SIMEX), added to σ_images in quadrature.
RatioEvidence combineRatioEvidence(double images_ratio, const std::vector<double>& replicate_ratios,
                                   double nominal_ratio, const RatioEvidenceOptions& options,
                                   std::pair<double, double> brightness_interval = {0, 0}, double noise_bias_log = 0);

// The r the shots' brightness ratio r_b allows when the camera's curve is g0^k with k ∈ [k_min, k_max] (measured with
// g0, the ratio is r^(1/k)), widened by `factor` on both sides: [r_b^k_min / factor, r_b^k_max · factor] (for r_b ≥ 1;
// mirrored below 1). {0, 0} for r_b ≤ 0.
std::pair<double, double> brightnessRatioInterval(double brightness_ratio, double k_min, double k_max, double factor);

}  // namespace crfcal
