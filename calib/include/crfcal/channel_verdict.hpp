#pragma once
// The verdict per channel (issue 17, item 4): "ok", "weak" or "unreliable", with short reasons that carry the
// numbers. It judges a finished calibration against what the pair says independently of the fit, so that a user is
// never shown a wrong curve without being told. The grounds:
//  * r against the evidence about r: the nominal ratio (EXIF, footnote 4, or --ratio) and the brightness ratio of
//    the two shots (estimateExposureRatio, exposure_fit.hpp, quantile matching with the EMoR mean curve — the measurement of
//    `crfcal study ratio` — widened to the range of exponents real curves have relative to that mean curve). Along the exponential ambiguity φ → φ^γ, r → r^γ (Sec. 4: only the blur fixes γ) the
//    fit can land on a wrong exponent; its r then leaves both. r further than `max_ratio_factor` from every
//    available source → unreliable; from some of them → weak (either the source is off or the fit is).
//  * r on the wrong side of 1: EXIF gives the blurred shot more light (beyond EXIF's tolerance) but r < 1, or the
//    mirror case → unreliable (a physical impossibility, not a matter of precision).
//  * r held at EXIF because the blur was too small to fix it (pair_calibration.hpp): the images disagreed → weak.
//  * the images' r and the nominal ratio contradict each other beyond their precisions (ratio_evidence.hpp) → weak,
//    saying which source the shots' brightness sided with.
//  * r consistent across channels: r is a property of the exposure (time, ISO, aperture), the same for every
//    channel; a channel outside a band of ±max_channel_ratio_spread/2 (in log) around the channels' median r → weak.
//  * the covered range: data spanning less than min_covered_span of the intensities → weak (φ is mostly
//    extrapolated).
//  * the band (curve_band.hpp): its median shape σ over the covered range above max_shape_sigma → weak (the data do
//    not fix φ's shape to the accuracy a calibration is for; issue 19 asks the verdict to use the band's width).
//  * a flat fit: φ's local exponent d log φ / d log x below flat_local_exponent (or φ ≤ 0) over at least
//    max_flat_fraction of the covered range → unreliable (no real inverse response is nearly constant over data).
//  * the effect diagnostics' refit (effect_refit_guard.cpp): adopted only when plausible and no worse than the base
//    fit on held-back pixels; the verdict says which fit is reported and why (a note, not a downgrade: the guard
//    already kept the better of the two).
// Pure computation: numbers in, verdicts out.
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace crfcal {

enum class VerdictLevel { ok = 0, weak = 1, unreliable = 2 };
const char* toString(VerdictLevel level);  // "ok", "weak", "unreliable"

struct VerdictOptions {
  // Largest factor between the reported r and a source of evidence about r for that source to agree. EXIF's nominal
  // ISO, shutter time and f-number are rounded to 1/3 stop (±1/6 stop each), which for ISO and time of both shots
  // gives σ(log r) ≈ 0.13; log 1.5 = 0.41 ≈ 3σ. The shots' brightness ratio, measured with the EMoR mean curve
  // instead of the camera's, deviated from EXIF by 0.20 in log on the phone pairs (`crfcal study ratio`), also well
  // inside. Issue 17 states the same factor 1.5.
  double max_ratio_factor = 1.5;
  // The shots' brightness ratio is measured with the EMoR mean curve g0, not the camera's: if the camera's
  // curve is g0^k, the measured ratio is r^(1/k), so the shots say r ∈ [r_b^k_min, r_b^k_max] (then the
  // factor above on either side). k_min = 1: g0 is the mean of 201 measured curves (DoRF). k_max = 1.6: the ten
  // measured cameras of samples/camera_curves are g0^k with k = 1.18–1.61 (least squares of log φ on log g0 over
  // x 0.06–0.92, the estimator's range; all more convex than g0).
  double brightness_ratio_exponent_min = 1.0;
  double brightness_ratio_exponent_max = 1.6;
  // r on the wrong side of 1 counts only when the nominal ratio is further from 1 than this (EXIF's tolerance, the
  // effects' ratio_tolerance).
  double ratio_side_tolerance = 0.10;
  // Channels' r: largest spread allowed (max/min − 1). r is the exposure's ratio, common to all channels; a white
  // balance that changes between the shots moves single channels. Issue 17: within 10 %.
  double max_channel_ratio_spread = 0.10;
  // Covered intensity span below which φ is mostly extrapolated (the pipeline's own warning, min_covered_span).
  double min_covered_span = 0.5;
  // Local exponent d log φ / d log x below which φ counts as flat. Measured inverse responses have local exponents
  // ≥ 0.56 (the ten Middlebury cameras) and the fitter bounds them at 0.25 (min_local_exponent); 0.1 is far below
  // both: only a degenerate curve goes there.
  double flat_local_exponent = 0.1;
  // φ also counts as flat where it rises less than this fraction of what any real curve rises there: the smallest
  // rise of g0^k over the sub-interval for k in [brightness_ratio_exponent_min, _max] (the EMoR mean and the most
  // convex measured camera). A tenth: an order of magnitude, beyond the scale error of φ(1) = 1 extrapolated from
  // data that stop early. It catches a curve nearly 0 over the data with all its rise above them (a steep power law
  // has a large local exponent, so the rule above misses it).
  double flat_slope_fraction = 0.1;
  // Fraction of the covered span over which a flat φ makes the channel unreliable (a tenth: more than a local dip).
  double max_flat_fraction = 0.1;
  // Largest median σ of the band's shape over the covered range (curve_band.hpp medianShapeSigma: the half-sample
  // spread and the model term, φ's scale aligned) for an "ok": issue 17's accuracy target for φ's shape over the
  // covered range, RMSE ≤ 0.01 after the best common scale. A band wider than that says the pair does not determine
  // the shape to the accuracy asked of it. Derived from the target, not fitted to any pair; measured on the benches
  // and the phone pairs in docs/RESULTS.md#verdict.
  double max_shape_sigma = 0.01;
  // Largest shape difference between a pointwise R or B of a subsampled sharp JPEG and its fit where that shot's
  // chroma is flat for the subsampling not to make the channel weak: the same shape target (issue 17's 0.01), not
  // fitted to any pair. Measured: docs/RESULTS.md#chroma-now.
  double max_chroma_shape_difference = 0.01;
  void check() const;  // throws InvalidInput
};

// The effect diagnostics' refit (EffectReport's guard fields), shared by all channels.
struct RefitEvidence {
  bool tried = false;
  bool adopted = false;
  std::string rejected_reason;
  double heldout_error_base_fit = 0, heldout_error_refit = 0;
  double heldout_error_base_fit_selected_model = 0;  // the base φ under the refit's model (0: not compared)
};

// What one channel's verdict is judged on.
struct ChannelEvidence {
  std::string channel;                 // "R", "G", "B"
  double ratio = 1;                    // r as reported
  double nominal_ratio = 0;            // EXIF or --ratio; ≤ 0: unknown
  std::string nominal_source = "EXIF"; // how the reasons name it ("EXIF" or "--ratio")
  bool ratio_fixed = false;            // r was not fitted (--fix-ratio): r = nominal_ratio by construction
  bool ratio_held_small_blur = false;  // r held at the nominal ratio because the blur was too small
  double ratio_images_small_blur = 0;  // then: the r of the free fit
  // The images' r against the nominal ratio (ratio_evidence.hpp): their difference beyond the conflict threshold,
  // and what was decided. A conflict makes the channel weak whatever was decided: one source is wrong, and with
  // nominal_held the curve's exponent rests on EXIF, not on the blur.
  bool ratio_conflict = false;
  // toString(RatioDecision) when a conflict was decided, or "not adopted: <reason>" when the pipeline kept the fits'
  // own r (RatioEvidence::not_adopted_reason); empty otherwise
  std::string ratio_decision;
  bool ratio_held_at_nominal = false;  // r = nominal_ratio by that decision (the EXIF comparison says nothing)
  double ratio_images = 0;             // the images' r (the free fit)
  double ratio_conflict_sigmas = 0;    // their difference in σ
  double brightness_ratio = 0;               // the shots' brightness ratio (quantile matching, EMoR mean curve); ≤ 0: not measured
  std::optional<std::pair<double, double>> covered;  // intensities the data constrain
  std::vector<double> inverse_crf;     // φ(i/(n−1)) as reported
  double shape_band_sigma = -1;        // the band's median shape σ over the covered range (medianShapeSigma); < 0: no band
  // R or B fitted by the pointwise model from a sharp shot whose JPEG chroma is subsampled (e.g. "4:2:0"; empty:
  // not the case). Its R and B at edges are rebuilt from chroma averaged over blocks after the tone curve; measured
  // on the bundled demo pair: φ_B 0.133 and φ_R 0.028 against G 0.0049 (docs/RESULTS.md#chroma) → weak.
  std::string pointwise_from_subsampled_chroma;
  // Then: the shape RMSE (best common scale, over the range both cover) between this fit and the channel's fit where
  // the sharp shot's chroma is flat (the chroma model's pixels); < 0: not measured. Within max_chroma_shape_difference
  // the lost chroma did not bias this pair's curve, and the reason above is a note instead.
  double chroma_check_shape_difference = -1;
  int chroma_check_pixels_left_out = 0;  // the pixels that fit left out (0: no block's chroma varies, nothing to miss)
  // The least-squares factor a of (flat-chroma fit) ≈ a · (this fit) over the range both cover; 0: not measured.
  // The bias the lost chroma puts into a pointwise fit has a known sign (chroma_subsampling.hpp ChromaModelChoice:
  // it lowers φ over the data), so a flat-chroma fit that removes it lies above this one: a > 1. A difference beyond
  // max_chroma_shape_difference with a <= 1 moved against that bias (the thinner data's noise): a note, not weak.
  double chroma_check_scale = 0;
  // The chroma check replaced this channel's pointwise fit by its fit where the sharp shot's chroma is flat
  // (PairCalibrationOptions::replace_chroma_biased_fits; the difference and scale above are the pointwise fit's): a
  // note saying so.
  bool chroma_check_replaced = false;
  // Why a flat-chroma fit that differs beyond the target and lies above was not reported instead (e.g. it does not
  // fix the curve's exponent by itself); empty: none, or it was replaced.
  std::string chroma_check_not_replaced;
  // PairCalibrationResult::kernel_sharp_black_admitted: > 0 → weak (the kernel rests on edges into black).
  double kernel_sharp_black_admitted = 0;
  // PairCalibrationResult::kernel_grown_to: > 0 → weak (a blur beyond the default limit, at the estimator's reach);
  // kernel_size_start: the limit it outgrew.
  int kernel_grown_to = 0;
  int kernel_size_start = 0;
};

struct ChannelVerdict {
  VerdictLevel level = VerdictLevel::ok;
  // Short sentences with the numbers: first those that set the level, then notes. An "ok" channel gets one
  // sentence with the checks it passed.
  std::vector<std::string> reasons;
  std::string summary() const;  // "weak: reason; reason"
};

// One verdict per channel of `channels`. `refit`: the effect diagnostics' refit (default: none tried).
std::map<std::string, ChannelVerdict> judgeChannels(const std::vector<ChannelEvidence>& channels,
                                                    const RefitEvidence& refit, const VerdictOptions& options = {});

// Worst level over the channels (ok for none).
VerdictLevel worstLevel(const std::map<std::string, ChannelVerdict>& verdicts);

// Fraction of the covered range [lo, hi] over which φ (samples on [0, 1]) is flat: on each of 32 equal
// sub-intervals, φ ≤ 0, a local exponent below options.flat_local_exponent, or a rise below
// options.flat_slope_fraction of the smallest rise of the real-curve family g0^k there.
double flatFraction(const std::vector<double>& inverse_crf, std::pair<double, double> covered,
                    const VerdictOptions& options = {});

}  // namespace crfcal
