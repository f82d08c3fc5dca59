// The band's ratio term (band_ratio_term.hpp): the r error the half-sample refits cannot see, through refits at held r.
#include "crfcal/band_ratio_term.hpp"

#include <algorithm>
#include <cmath>

#include "crfcal/curve_band.hpp"
#include "crfcal/error.hpp"

namespace crfcal {

namespace {

// What the halves carry of log r: w·σ_resampled when they combine as the pair did, else their own spread.
double carriedByHalves(const RatioEvidence& evidence, const RatioTermInputs& inputs) {
  return (inputs.reported_from_evidence && inputs.halves_combine ? evidence.images_weight : 1.0) *
         evidence.resampled_log_sigma;
}

// RatioTermSigma::disagreement (band_ratio_term.hpp): EXIF's σ believed, the images' σ from |Δ|.
double unseenFromDisagreement(const RatioEvidence& evidence, const RatioTermInputs& inputs) {
  if (!(evidence.images_ratio > 0 && evidence.nominal_ratio > 0 && evidence.nominal_log_sigma > 0)) return 0;
  const double delta = std::log(evidence.images_ratio / evidence.nominal_ratio);
  const double var_nominal = evidence.nominal_log_sigma * evidence.nominal_log_sigma;
  const double resampled = evidence.resampled_log_sigma;
  const double var_images = std::max(resampled * resampled, delta * delta - var_nominal);
  const double images_weight = var_nominal / (var_images + var_nominal);  // ŵ, the weight those σ would give
  // The reported r's weight on the images: the combination's, or 1 when the images' own r was reported.
  const double reported_weight = inputs.reported_from_evidence ? evidence.images_weight : 1.0;
  const double mean = (reported_weight - images_weight) * delta;
  const double variance = var_images * var_nominal / (var_images + var_nominal);
  const double carried = carriedByHalves(evidence, inputs);
  const double z = studentQuantile(0.5 + inputs.level / 2, 0);
  if (inputs.sigma == RatioTermSigma::disagreement_shift) return std::abs(mean) / z;
  return std::abs(mean) / z + std::sqrt(std::max(0.0, variance - carried * carried));
}

}  // namespace

double ratioLogSigmaUnseenByHalves(const RatioEvidence& evidence, const RatioTermInputs& inputs) {
  if (!evidence.combined) return 0;
  const bool combined = evidence.decision == RatioDecision::combined;
  if (inputs.sigma != RatioTermSigma::birge && combined) {
    const double unseen = unseenFromDisagreement(evidence, inputs);
    return std::isfinite(unseen) ? unseen : 0.0;
  }
  // The reported r: the evidence's posterior, or the images' own r (the combination did not move it enough to refit).
  const double reported = inputs.reported_from_evidence ? evidence.log_sigma : evidence.images_log_sigma;
  const double carried = carriedByHalves(evidence, inputs);
  double unseen = std::sqrt(std::max(0.0, reported * reported - carried * carried));
  if (inputs.consistency_scale && combined) unseen *= evidence.conflict_sigmas;
  return std::isfinite(unseen) ? unseen : 0.0;
}

std::vector<double> ratioTermHalfWidth(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                       const CrfFitOptions& fit_options, const CrfFitResult& fit,
                                       std::pair<double, double> covered, double log_sigma, double level) {
  const int n = static_cast<int>(fit.inverse_crf.size());
  if (!(log_sigma > 0) || n < 16 || !(fit.ratio > 0)) return {};
  std::vector<CrfFitResult> shifted;
  try {
    shifted = fitInverseCrfAtHeldRatios(sharp, blurred, kernel, fit_options,
                                        {fit.ratio * std::exp(-log_sigma), fit.ratio * std::exp(log_sigma)});
  } catch (const InvalidInput&) {
    return {};  // the band goes without the term rather than the calibration failing
  }
  const std::vector<double>& phi = fit.inverse_crf;
  const int i0 = std::clamp(static_cast<int>(std::lround(covered.first * (n - 1))), 0, n - 1);
  const int i1 = std::clamp(static_cast<int>(std::lround(covered.second * (n - 1))), i0, n - 1);
  std::vector<double> variance(n, 0.0);
  for (const CrfFitResult& other : shifted) {
    const std::vector<double>& curve = other.inverse_crf;
    if (static_cast<int>(curve.size()) != n) return {};
    double num = 0, den = 0;  // the deviation after its best common scale over the covered range (φ → bφ is free)
    for (int i = i0; i <= i1; ++i) num += phi[i] * curve[i], den += curve[i] * curve[i];
    const double a = den > 0 ? num / den : 1.0;
    for (int i = 0; i < n; ++i) variance[i] += (a * curve[i] - phi[i]) * (a * curve[i] - phi[i]) / shifted.size();
  }
  const double z = studentQuantile(0.5 + level / 2, 0);
  std::vector<double> half_width(n);
  for (int i = 0; i < n; ++i) half_width[i] = z * std::sqrt(variance[i]);
  return half_width;
}

}  // namespace crfcal
