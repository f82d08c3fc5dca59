#pragma once
// A pointwise band of the inverse response φ (issue 19: the curve beyond the data).
//
// Two kinds of uncertainty, kept apart because they behave differently:
//  * the SHAPE inside the covered range (the intensities the pair's pixels constrain): the sampling error of the
//    fit, measured by refitting φ on half-samples of image blocks (a block bootstrap; the blocks are larger than
//    the kernel so that the pixels of one block share their noise, JPEG blocks and mixtures). For a half-sample
//    Var(φ_half − φ_full) ≈ Var(φ_full) (m = n/2 of n blocks), so the replicates' deviations from the full fit,
//    each after its best common scale over the covered range, estimate the full fit's pointwise variance directly.
//    The band is ± t · σ (Student t with the replicates' degrees of freedom at the band's level), widened by the
//    difference to the fitter's other candidate model (the model's own misfit, which resampling cannot see).
//  * the SCALE and the curve above / below the data: with ΣK = 1, φ → bφ leaves Eq. 4 unchanged, so inside the
//    covered range the data fix φ up to a factor, and φ(1) = 1 pins that factor only through the extrapolation
//    from the top of the data x_hi to 1. The band assumes the true local exponent g = d log φ / d log x above the
//    data lies in [g_lo, g_hi]: φ(x_hi) ∈ [x_hi^g_hi, x_hi^g_lo], which bounds the factor; above x_hi the curve lies
//    in [x^g_hi, x^g_lo]. g_lo = max(exponent_floor, min(g_top, 1)) with g_top the fit's own exponent at the top of
//    the data (a camera's inverse response rarely straightens above its data: measured inverse CRFs have local
//    exponents ≥ 0.56 and shoulders that RISE towards x = 1, CrfFitOptions::min_local_exponent/shoulder_prior);
//    g_hi = max(exponent_ceiling, exponent_rise_factor · g_top). Below the data likewise towards φ(0) = 0. This part is a bound, not a
//    probability: it is honestly wide, and it is what makes the absolute band wide inside the covered range too
//    when the data stop well below x = 1. Measured, the bound is too tight near x = 1 (measured shoulders steepen
//    there beyond any g_hi a fit's top suggests) and too loose below: the truth escaped it mostly in the last few
//    percent below x = 1. With CurveBandOptions::above_data_prior the part above the data and the scale are instead
//    the quantiles of a prior learned from measured curves, conditioned on the fit's shape inside
//    (learned_curve_prior.hpp): a probability under that prior, calibrated along x on held-out cameras
//    (docs/RESULTS.md#band-above-learned). The commands pass it by default; the library's default stays the bound.
// Pure computation: no file I/O, no printing.
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/band_ratio_term.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/learned_curve_prior.hpp"

namespace crfcal {

struct CurveBandOptions {
  double level = 0.9;      // pointwise coverage the band aims at (0.9: a 90 % band)
  // Half-sample refits per channel (in complementary pairs, so even). Each sees half the blocks, so it costs about
  // half a fit; 8 keep the band under the calibration's own time (docs/RESULTS.md#curve-band-issue-19). 0: no band.
  int replicates = 8;
  // Side of the resampled blocks in pixels; the kernel's side doubled when that is larger (the pixels of one
  // mixture must fall in one block).
  int block_size = 32;
  // Bounds of the local exponent of φ above (and below) the covered range, see the top of this file. Floor: half
  // the most concave measured inverse CRF (CrfFitOptions::min_local_exponent's rationale); ceiling: a shoulder's
  // exponent averaged over the extrapolated span (locally it reaches 4.5–19 on the ten Middlebury cameras, but only
  // in the last few percent below x = 1).
  double exponent_floor = 0.5;
  double exponent_ceiling = 4.0;
  // The upper exponent bound is also at least this times the fit's own exponent at the top of the data: a shoulder
  // that already rises there keeps rising towards x = 1 (real shoulders steepen, shoulder_prior's rationale).
  double exponent_rise_factor = 2.0;
  // Add the fitter's other candidate model (GGCM vs EMoR, crf_model_selection), scale-aligned, as a model term of
  // the shape half-width: √((t σ)² + (a φ_other − φ)²). The sampling spread misses the model's systematic misfit.
  bool include_model_spread = true;
  // The refits fit only the model the full fit chose (GGCM or EMoR; no cross-validated choice between them): the
  // choice is the model term above, and a refit that chose per half would count it twice. It also spares each
  // refit the other model and the two-fold choice (3–6 model fits of the full fitter's).
  bool refit_chosen_model = true;
  // With refit_chosen_model: each refit starts from the whole pair's fit (CrfFitOptions::start; a half's optimum
  // lies next to the whole's), 3 LM runs instead of the fitter's 5–14 from its usual starts.
  bool refits_start_from_fit = true;
  // When the reported r combines the images' r with the nominal ratio (ratio_evidence.hpp), each refit fits r from
  // its half, combines it the same way and refits φ there (ReplicateRatioRule below; one more fit per refit). false:
  // the refits keep their halves' own r (before the fix: the band then carried the images' whole spread of r,
  // 99 % shape coverage at r = 4 and 8 for a 90 % band; docs/RESULTS.md#curve-band-issue-19).
  bool replicates_combine_ratio = true;
  // Add the error of r that every half shares (the exponent floor of the images' r, the nominal ratio's own error),
  // scaled by how well the pair's two estimates of r agree, as φ's response to r held a σ away (band_ratio_term.hpp;
  // two more fits per channel when that σ is ≥ 0.5 %, none at r = 1). Off by default: measured on `bench pairs`
  // (docs/RESULTS.md#band-ratio-term) it lifts the shape coverage at r = 8 from 83.1 % to 98.9 % but also at r = 4
  // from 91.0 % (met) to 99.6 %: the a-priori σ (EXIF's 0.13) are 2–3× the bench's r errors where the estimates agree.
  bool include_ratio_term = false;
  // Which σ of log r the ratio term carries (band_ratio_term.hpp): birge (stop 32: the a-priori σ scaled by the
  // two estimates' agreement) or disagreement (EXIF's stated σ believed, the images' σ estimated from how far the
  // images' r lies from EXIF; docs/RESULTS.md#band-ratio-disagreement). Measured with disagreement: r = 4 99.3 %,
  // r = 8 98.7 % shape coverage (birge 99.6 / 98.9 %), narrower at r = 4 (0.0080 against 0.0115): still over.
  RatioTermSigma ratio_term_sigma = RatioTermSigma::birge;
  // Add the priors' share of φ (priorTermHalfWidth below): φ refitted on all the data at the fit's r without the
  // extrapolation priors, scale-aligned, its difference added like the model term. Every half-sample refit carries
  // the same priors, so where they decide φ (the affine freedom a + bφ of Eq. 4 at r = 1, the thin top of the
  // covered range under the shoulder prior) the halves agree and the band cannot see it. One more fit per channel.
  // Off: measured, it adds < 0.5 % coverage at r = 1, 4, 8 (refitted from the fit, φ does not move).
  bool include_prior_term = false;
  // Add the offset Eq. 4 leaves free at r = 1 (offsetTermHalfWidth below): with ΣK = 1 and r = 1, φ → a + bφ fits
  // the pair as well, so the offset over the covered range is set by the extrapolation to φ(0) = 0 below the data,
  // identically in every half. Only when |log r| ≤ offset_term_max_log_ratio: at r ≠ 1 the offset changes Eq. 4 by
  // a·(r − 1) and the data fix it (0.05: the offset then moves B by under 5 % of itself). On by default since stop 33:
  // `bench pairs` r = 1 shape coverage inside the covered range 82.3 → 88.5 % (r = 4, 8 untouched; no curve, r or
  // verdict changes; no value fitted — the bound is φ at the bottom of the pair's own data).
  bool include_offset_term = true;
  double offset_term_max_log_ratio = 0.05;
  // Beyond the top of the data: instead of the exponent bounds above (a bound, not a probability), the learned
  // prior's conditional spread of the curve there given its shape inside (learned_curve_prior.hpp,
  // continuationQuantiles at `level`): the band above the covered range and the scale range inside it become the
  // draws' quantiles. Needs a node x = j/64 inside the covered range; otherwise the bounds. Null (default): the
  // bounds. Measured on `bench pairs` leave-one-camera-out: docs/RESULTS.md#band-above-learned.
  std::shared_ptr<const LearnedCurvePrior> above_data_prior;
  int above_data_draws = 512;  // draws of the prior's continuation
  std::uint64_t seed = 1;  // the blocks' half-samples (deterministic)
  void check() const;      // throws InvalidInput
};

struct CurveBand {
  std::vector<double> lower, upper;       // the band of φ with φ(1) = 1 (absolute), kCurveSamples samples
  // Half-width of the SHAPE band (sampling spread and the model term, φ's scale aligned), kCurveSamples samples; meaningful
  // inside `covered`, where it is what two calibrations of one camera should agree within (compare).
  std::vector<double> shape_half_width;
  // With a ReplicateRatioRule: the same half-width from the halves' refits with their OWN r (the images alone, no
  // EXIF), model term included; empty otherwise. How well the pair's images fix φ's shape: the verdict's reading
  // (medianShapeSigma), since a shape that only EXIF's r pins is not fixed by the pair. Not a band of the reported
  // curve (those refits are not centred on it: they sit at the images' r). Also without a rule when the ratio
  // term was added: the half-width before it (the refits fitted their own r), so the verdict's reading is unchanged.
  std::vector<double> images_ratio_half_width;
  // The ratio term (band_ratio_term.hpp) inside shape_half_width: z·σ_r(x), kCurveSamples samples; empty without it.
  std::vector<double> ratio_half_width;
  // The prior term (CurveBandOptions::include_prior_term) inside shape_half_width; empty without it.
  std::vector<double> prior_half_width;
  // The offset term (CurveBandOptions::include_offset_term) inside shape_half_width; empty without it.
  std::vector<double> offset_half_width;
  double ratio_log_sigma = 0;  // σ of log r it was computed for (0: none)
  std::pair<double, double> covered{0, 1};  // the covered range the band was built for
  std::pair<double, double> scale_range{1, 1};  // factors s with φ_true ≈ s·φ on the covered range
  std::pair<double, double> exponent_above{1, 1};  // [g_lo, g_hi] used above the covered range
  // What set the band above the covered range and the scale range: the exponent bounds, or the learned prior's
  // quantiles (CurveBandOptions::above_data_prior; then exponent_above is not used).
  enum class AboveData { exponent_bounds, learned_prior } above_data = AboveData::exponent_bounds;
  int above_data_curves = 0;  // training curves of that prior
  double level = 0.9;
  int replicates = 0;         // successful refits
  std::vector<double> replicate_ratios;         // r each refit was fitted at (held by a ReplicateRatioRule, or its own)
  std::vector<double> replicate_images_ratios;  // r each refit's half alone gave
  int failed_replicates = 0;  // refits that threw (too few pixels in the half-sample)
  double seconds = 0;
  bool empty() const { return lower.empty(); }
  std::string summary() const;
};

// The band from a fit `phi` (kCurveSamples samples), the replicates' curves (half-sample refits, any number ≥ 2;
// fewer: no sampling part) and the covered range. Throws InvalidInput for a malformed curve or range.
// `alternatives`: other plausible fits of the same data (the fitter's other candidate model), each added as a
// model term when options.include_model_spread. `systematic`: half-widths of errors the replicates share (each
// kCurveSamples samples, e.g. the ratio term), added in quadrature as they are.
CurveBand bandFromReplicates(const std::vector<double>& phi, const std::vector<std::vector<double>>& replicates,
                             std::pair<double, double> covered, const CurveBandOptions& options = {},
                             const std::vector<std::vector<double>>& alternatives = {},
                             const std::vector<std::vector<double>>& systematic = {});

// The shape band's median half-width over its covered range, and as a standard deviation (divided by the band's t
// quantile at its level and number of refits; the normal quantile without refits). medianShapeSigma is what a
// verdict compares with an accuracy target of φ's shape (channel_verdict.hpp): it reads images_ratio_half_width
// when the band has one (how well the images alone fix the shape), else shape_half_width. 0 for an empty band.
double medianShapeHalfWidth(const CurveBand& band);
double medianShapeSigma(const CurveBand& band);

// Refits of φ on `replicates` half-samples of the blocks (side max(block_size, twice the kernel's side)) holding
// `used_mask`'s pixels, in complementary pairs, with the same images, kernel and fit options
// (CrfFitOptions::pixel_selection). For a half-sample Var(θ_half − θ_full) ≈ Var(θ_full), so the refits' deviations
// from the full fit estimate its sampling spread: of φ (the band) and of r (ratio_evidence.hpp). Halves without
// enough edge pixels are counted in `failed`. Fewer than 4 blocks: no refits.
struct HalfSampleRefits {
  std::vector<std::vector<double>> curves;  // φ of each successful refit, kCurveSamples samples
  std::vector<double> ratios;               // r of each successful refit (the held r with a ReplicateRatioRule)
  std::vector<double> images_ratios;        // r each refit found from its half alone (= ratios without a rule)
  std::vector<std::vector<double>> images_curves;  // with a rule: φ of each half's own-r fit (before the held-r refit)
  int failed = 0;
};

// How a half-sample refit obtains r when the reported r is not the fit's own but the images' r combined with the
// nominal one by their precisions (ratio_evidence.hpp: log r = w·log r_images + (1 − w)·log r_nominal). A bootstrap
// replicate must run the same estimator as the reported fit, so each half fits r from its images (r_half), forms
// its own combination log r = log r_reported + w·(log r_half − log r_images) and refits φ with r held there. A
// replicate that kept its images' r would carry the images' spread of r — along the exponential ambiguity φ^γ,
// r^γ a spread of φ's exponent — where the reported curve carries only w times it
// (docs/RESULTS.md#curve-band-issue-19).
struct ReplicateRatioRule {
  double images_weight = 1;  // w ∈ [0, 1] (0: r held at the nominal ratio, 1: the images' r kept)
  double images_ratio = 1;   // r of the whole pair's images alone
  double ratio = 1;          // the reported (combined) r
  void check() const;        // throws InvalidInput
  double heldRatio(double half_images_ratio) const;
};

// `ratio_rule`: with it, each half's free-r fit is followed by a refit of φ at the rule's r (start: the free fit),
// and that refit is the replicate; fit_options.fit_ratio must then be true.
HalfSampleRefits refitOnHalfSamples(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                    const CrfFitOptions& fit_options, const cv::Mat& used_mask, int replicates,
                                    int block_size, std::uint64_t seed,
                                    const std::optional<ReplicateRatioRule>& ratio_rule = std::nullopt);

// Random halves of the `block`-pixel blocks holding non-zero pixels of `used` (CV_8U), `count` of them in
// complementary pairs (every block is in exactly one half of each pair), as CV_8U pixel masks; none for fewer than
// 4 blocks. The resampling of refitOnHalfSamples (and of the joint fit's band, joint_calibration.hpp).
std::vector<cv::Mat> halfSampleMasks(const cv::Mat& used, int block, int count, std::uint64_t seed);

// Refits φ on `options.replicates` half-samples of the blocks that hold `fit`'s used pixels (fit.pixels.used_mask)
// with the same images, kernel and fit options (CrfFitOptions::pixel_selection), then bandFromReplicates.
// `ratio_rule`: the reported r is a combination of the images' r with the nominal one (see ReplicateRatioRule);
// fit_options.fit_ratio must then be true (the halves fit r from their images first).
// `ratio_log_sigma`: σ of log r that the refits cannot see (band_ratio_term.hpp's ratioLogSigmaUnseenByHalves); with
// options.include_ratio_term and σ > 0 the ratio term is added (two fits at r held σ away).
CurveBand estimateCurveBand(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                            const CrfFitOptions& fit_options, const CrfFitResult& fit,
                            std::pair<double, double> covered, const CurveBandOptions& options = {},
                            const std::optional<ReplicateRatioRule>& ratio_rule = std::nullopt,
                            double ratio_log_sigma = 0);

// The priors' share of φ (CurveBandOptions::include_prior_term): |a·φ_free − φ| with φ_free refitted with
// `fit_options` (the band's refit options: the chosen model, started from `fit`) at r held at fit.ratio and without
// the extrapolation priors (exponent_smoothness, shoulder_prior, the learned prior; min_local_exponent, which only
// removes degenerate curves, kept), a its best common scale onto φ over the covered range. Started from the fit, the
// refit moves only as far as the data pull against the priors: 0 where the data decide φ. kCurveSamples samples;
// empty when the refit throws InvalidInput or is invalid (the band then goes without the term).
std::vector<double> priorTermHalfWidth(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                       const CrfFitOptions& fit_options, const CrfFitResult& fit,
                                       std::pair<double, double> covered);

// The offset term (CurveBandOptions::include_offset_term): at r = 1 the truth may differ from φ by an offset c over
// the covered range [x_lo, x_hi] that the data cannot see. Below the data φ only has to fall monotonically to
// φ(0) = 0, so the true φ(x_lo) lies between 0 and about 2·φ(x_lo): |c| ≤ φ(x_lo), taken as uniform, whose central
// `level` interval is |c| ≤ level·φ(x_lo). After the shape band's best common scale (least squares over the covered
// range), an offset c leaves the deviation c·(1 − φ(x)·Σφ / Σφ²), so the half-width is
// level·φ(x_lo)·|1 − φ(x)·Σφ / Σφ²| (sums over the covered range). kCurveSamples samples. Pure arithmetic on φ.
std::vector<double> offsetTermHalfWidth(const std::vector<double>& phi, std::pair<double, double> covered,
                                        double level);

// How a band fares against a known truth (the benches): x samples of the truth inside the band, counted inside,
// above and below the band's covered range; inside, also the SHAPE band: |a·truth − φ| ≤ shape_half_width with a
// the truth's best common scale onto φ over the covered range (φ → bφ leaves Eq. 4 unchanged, so a shape band
// is judged after that scale; the absolute band against the truth as it is).
struct BandScore {
  int inside = 0, inside_hits = 0;  // samples in the covered range, of which the truth inside [lower, upper]
  int above = 0, above_hits = 0;    // above it
  int above_far = 0, above_far_hits = 0;  // of those, the farther half of [covered top, 1] (towards x = 1)
  int below = 0, below_hits = 0;    // below it
  int shape_hits = 0;               // covered-range samples with the scaled truth inside the shape band
  double truth_scale = 1;           // a
  double median_width_inside = 0;   // median of upper − lower over the covered range
  double median_shape_width_inside = 0;  // median of 2 · shape_half_width over the covered range
};
BandScore scoreBand(const CurveBand& band, const std::vector<double>& phi, const std::vector<double>& truth);

// Agreement of two curves judged by their bands (compare), over a common covered range [lo, hi] and with compare's
// factor a (φ_A ≈ a·φ_B, curve_comparison.hpp): the shape bands give the difference d = φ_A − a·φ_B a pointwise
// half-width w = √(h_A² + (a·h_B)²) at the bands' level, so two calibrations of one camera that differ only by
// their sampling errors have |d| ≤ w at about `level` of the samples, and (d / σ)² averages about 1 with
// σ = w / z_level. A missing band counts as half-width 0 (a truth, or a report without a band).
struct BandAgreement {
  int samples = 0;               // grid samples in the common covered range
  double fraction_within = 0;    // of them, |d| ≤ w
  double mean_z2 = 0;            // mean of (d / σ)²; ≫ 1: the curves differ beyond their sampling errors
  double fraction_absolute_overlap = 0;  // of them, the absolute bands [lower, upper] overlap (no factor a)
  double level = 0.9;
};
// phi_a/phi_b and the bands on the same grid (same sample count); band_a/band_b may be null.
BandAgreement bandAgreement(const std::vector<double>& phi_a, const CurveBand* band_a, const std::vector<double>& phi_b,
                            const CurveBand* band_b, std::pair<double, double> covered, double scale);

// Quantile of Student's t with `dof` degrees of freedom at probability p ∈ (0.5, 1) (dof ≤ 0: the normal one).
double studentQuantile(double p, double dof);

}  // namespace crfcal
