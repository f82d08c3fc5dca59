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

// How the reported r and the band's refits relate to the evidence (pair_stage_band.cpp fills it).
struct RatioTermInputs {
  bool reported_from_evidence = false;  // the reported r is the evidence's combination (else the images' own r)
  bool halves_combine = false;          // the refits combine their r as the pair did (ReplicateRatioRule)
  bool consistency_scale = true;        // scale by S (above); false: the a-priori σ as they are (an ablation)
};

// σ_unseen of log r (above) for `evidence`; 0 when no evidence was combined (r from the images alone without a
// nominal ratio, a given --ratio held, r = 1 with the images' r kept: the floor is 0 at r = 1).
double ratioLogSigmaUnseenByHalves(const RatioEvidence& evidence, const RatioTermInputs& inputs);

// z·σ_r(x) (above), kCurveSamples samples: φ refitted with `fit_options` (the band's refit options: the chosen
// model, started from `fit`) at r·e^{±log_sigma}, r = fit.ratio. Empty when log_sigma ≤ 0 or a refit throws
// InvalidInput (the band then goes without the term).
std::vector<double> ratioTermHalfWidth(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                       const CrfFitOptions& fit_options, const CrfFitResult& fit,
                                       std::pair<double, double> covered, double log_sigma, double level);

}  // namespace crfcal
