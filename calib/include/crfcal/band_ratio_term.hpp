#pragma once
// The band's ratio term (issue 19, docs/RESULTS.md#band-ratio-term): the error of the reported exposure ratio r that
// the half-sample refits cannot see, carried into φ's shape band.
//
// The half-sample refits (curve_band.hpp) see the images' sampling spread of r (each half combines its own r with
// the nominal one by the pair's weight w: ReplicateRatioRule), so the band carries w·σ_resampled of log r. The
// reported r's whole error (ratio_evidence.hpp, a Gaussian posterior in log r) is larger by what every half shares:
// the images' exponent floor (a bias common to every half: the sharp shot's noise, JPEG, the model) and the nominal
// ratio's own error (EXIF rounding), weighted (1 − w):
//     σ_unseen² = σ_reported² − w²·σ_resampled²   (σ_reported: the posterior's σ, or σ_images when r is the images').
// Those σ are assumed a priori (the floor, EXIF's 1/3-stop rounding), not measured on the pair; what the pair does
// measure is how well its two estimates of r agree. Their difference has σ_Δ² = σ_images² + σ_nominal², so
// S = |log r_images − log r_nominal| / σ_Δ (the evidence's conflict_sigmas) estimates the factor by which the assumed
// σ are off, the Birge ratio of two measurements (one degree of freedom): σ_unseen is scaled by S. Agreeing estimates
// (S < 1) shrink the term, disagreeing ones widen it. When the conflict was arbitrated by the shots' brightness
// (nominal_held, images_kept) the disagreement is explained by the estimate that was set aside, so S = 1.
//
// Propagation: along the exponential ambiguity φ^γ with r^γ (Sec. 4) an error of log r moves φ's exponent, but how
// far the pair's φ follows depends on how much the blur fixes the exponent on its own. So the term is measured on
// the pair: φ refitted on all the data with r held at r·e^{±σ_unseen} (the chosen model, starting from the fit), each
// deviation scale-aligned to φ over the covered range, σ_r(x)² = (δ₊(x)² + δ₋(x)²) / 2, and the band's half-width
// gains z·σ_r(x) in quadrature (z the normal quantile at the band's level: σ_r is not estimated from the replicates).
// Pure computation: no file I/O, no printing.
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/crf_fitter.hpp"
#include "crfcal/ratio_evidence.hpp"

namespace crfcal {

// Which σ_unseen (above) the term carries.
//  * birge: the a-priori σ scaled by S (above; stop 32). Over-covers where the estimates agree: S·σ_post equals
//    √(w(1 − w))·|Δ| whatever the a-priori σ, so it charges the combination with a share of the disagreement even
//    when one estimate is right.
//  * disagreement: EXIF's σ_nominal (its rounding, stated a priori) is believed, and the images' whole σ (their
//    exponent bias included, which no half sees) is estimated from the pair's disagreement Δ = log r_images −
//    log r_nominal: E[Δ²] = σ_i² + σ_n², so σ̂_i² = max(σ_resampled², Δ² − σ_n²) (one degree of freedom, never below
//    what the halves measured). With those σ the reported r = r_nominal·e^{w_rep·Δ} has, given Δ, the error
//        e | Δ ~ N((w_rep − ŵ)·Δ, ŵ(1 − ŵ)(σ̂_i² + σ_n²)),   ŵ = σ_n² / (σ̂_i² + σ_n²)
//    (the Gaussian conditional of e_nominal given e_images − e_nominal = Δ, and e = e_nominal + w_rep·Δ), and
//    a shift the reported r carries plus a spread, of which the halves carry w_rep·σ_resampled. A band covering a
//    shift μ and a spread s at level p reaches |μ| + z·s (z the normal quantile), so the term is returned as the
//    σ that gives that half-width, σ_unseen = |μ| / z + √(s² − carried²), and propagated like birge's. The images
//    agreeing with EXIF within its σ are taken as right up to their resampled spread (ŵ ≈ 1): the shift is then the
//    pull towards EXIF, (1 − w)·Δ; a disagreement beyond EXIF's σ is charged to the images (their bias at high r:
//    the noisy underexposed sharp shot) and the spread grows with it. No value is fitted to a bench.
//  * disagreement_shift: the disagreement rule's shift alone, σ_unseen = |μ| / z (the band reaches the reported r's
//    expected error given Δ, not the spread around it, which the a-priori σ_nominal states larger than a camera
//    whose EXIF agrees with its images shows).
enum class RatioTermSigma { birge, disagreement, disagreement_shift };

// How the reported r and the band's refits relate to the evidence (pair_stage_band.cpp fills it).
struct RatioTermInputs {
  bool reported_from_evidence = false;  // the reported r is the evidence's combination (else the images' own r)
  bool halves_combine = false;          // the refits combine their r as the pair did (ReplicateRatioRule)
  bool consistency_scale = true;        // birge: scale by S (above); false: the a-priori σ as they are (an ablation)
  RatioTermSigma sigma = RatioTermSigma::birge;
  double level = 0.9;                   // disagreement: the band's level (z of the shift, above)
};

// σ_unseen of log r (above) for `evidence`; 0 when no evidence was combined (r from the images alone without a
// nominal ratio, a given --ratio held, r = 1 with the images' r kept: the floor is 0 at r = 1). With
// RatioTermSigma::disagreement and a conflict the brightness arbitrated (nominal_held, images_kept), the birge rule
// (S = 1 there): the disagreement is then explained by the estimate set aside, not evidence about σ.
double ratioLogSigmaUnseenByHalves(const RatioEvidence& evidence, const RatioTermInputs& inputs);

// z·σ_r(x) (above), kCurveSamples samples: φ refitted with `fit_options` (the band's refit options: the chosen
// model, started from `fit`) at r·e^{±log_sigma}, r = fit.ratio. Empty when log_sigma ≤ 0 or a refit throws
// InvalidInput (the band then goes without the term).
std::vector<double> ratioTermHalfWidth(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                       const CrfFitOptions& fit_options, const CrfFitResult& fit,
                                       std::pair<double, double> covered, double log_sigma, double level);

}  // namespace crfcal
