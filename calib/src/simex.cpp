#include "crfcal/simex.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>

#include <Eigen/Dense>
#include <opencv2/core.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/level_mixture.hpp"

namespace crfcal {

void SimexOptions::check() const {
  if (added_variance_multiples.empty()) throw InvalidInput("simex: no added-noise multiples");
  for (double lambda : added_variance_multiples)
    if (!(lambda > 0) || !std::isfinite(lambda)) throw InvalidInput("simex: added-noise multiples must be > 0");
  if (replicates < 1) throw InvalidInput("simex: replicates must be ≥ 1");
  if (extrapolation_degree < 1 || extrapolation_degree > 3) throw InvalidInput("simex: extrapolation degree must be 1–3");
  if (static_cast<int>(added_variance_multiples.size()) < extrapolation_degree)
    throw InvalidInput("simex: need at least as many added-noise multiples as the extrapolation degree");
}

namespace {

// I + N(0, λσ̂²), clipped to [0, 1] and quantised to I's own level grid (the refit then sees the data kind the
// naive fit saw: 8-bit stays 8-bit).
cv::Mat perturbedSharp(const cv::Mat& sharp_unit, int levels, double added_sigma, std::uint64_t seed) {
  cv::Mat noise(sharp_unit.size(), CV_64F);
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, added_sigma);
  cv::Mat out = sharp_unit + noise;
  const double top = levels - 1;
  out.forEach<double>([top](double& v, const int*) { v = std::round(std::clamp(v, 0.0, 1.0) * top) / top; });
  return out;
}

// Weights w_k with Σ_k w_k y_k = the least-squares polynomial of degree d through (λ_k, y_k), evaluated at λ = −1.
std::vector<double> extrapolationWeights(const std::vector<double>& lambdas, int degree) {
  const int n = static_cast<int>(lambdas.size());
  Eigen::MatrixXd design(n, degree + 1);
  for (int k = 0; k < n; ++k)
    for (int p = 0; p <= degree; ++p) design(k, p) = std::pow(lambdas[k], p);
  Eigen::RowVectorXd at_minus_one(degree + 1);
  for (int p = 0; p <= degree; ++p) at_minus_one(p) = (p % 2 == 0) ? 1.0 : -1.0;
  const Eigen::MatrixXd pinv = design.completeOrthogonalDecomposition().pseudoInverse();
  const Eigen::RowVectorXd w = at_minus_one * pinv;
  return std::vector<double>(w.data(), w.data() + n);
}

// A valid inverse CRF from extrapolated samples: inside [0, 1], non-decreasing, φ(0) = 0, φ(1) = 1.
std::vector<double> validInverse(std::vector<double> phi) {
  for (double& v : phi) v = std::clamp(v, 0.0, 1.0);
  phi.front() = 0;
  phi.back() = 1;
  std::partial_sum(phi.begin(), phi.end(), phi.begin(), [](double a, double b) { return std::max(a, b); });
  return phi;
}

struct Refits {
  std::vector<double> lambdas;
  std::vector<std::vector<double>> curves;
  std::vector<double> log_ratios;
  int succeeded = 0, failed = 0, evaluations = 0;
};

Refits runRefits(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel, const CrfFitOptions& options,
                 const SimexOptions& simex, const CrfFitResult& naive) {
  const cv::Mat sharp_unit = toUnitGray(sharp);
  const int levels = naturalLevels(sharp);
  const double sigma = naive.noise_sigma;
  Refits out;
  for (std::size_t m = 0; m < simex.added_variance_multiples.size(); ++m) {
    const double lambda = simex.added_variance_multiples[m];
    CrfFitOptions refit = options;
    refit.progress = nullptr;
    refit.noise_sigma = sigma * std::sqrt(1.0 + lambda);  // the refit's data carry (1 + λ)σ̂²
    for (double& s : refit.noise_sigma_per_level) s = std::sqrt(s * s + lambda * sigma * sigma);
    std::vector<double> sum(kCurveSamples, 0.0);
    double log_ratio_sum = 0;
    int count = 0;
    for (int b = 0; b < simex.replicates; ++b) {
      const std::uint64_t seed = simex.seed * 1000003ULL + 7919ULL * m + b;
      try {
        const CrfFitResult fit = fitInverseCrf(perturbedSharp(sharp_unit, levels, std::sqrt(lambda) * sigma, seed),
                                               blurred, kernel, refit);
        for (int i = 0; i < kCurveSamples; ++i) sum[i] += fit.inverse_crf[i];
        log_ratio_sum += std::log(fit.ratio);
        out.evaluations += fit.evaluations;
        ++count;
        ++out.succeeded;
      } catch (const InvalidInput&) {
        ++out.failed;  // e.g. the extra noise left too few usable edge pixels
      }
    }
    if (count == 0) continue;
    for (double& v : sum) v /= count;
    out.lambdas.push_back(lambda);
    out.curves.push_back(std::move(sum));
    out.log_ratios.push_back(log_ratio_sum / count);
  }
  return out;
}

}  // namespace

CrfFitResult fitInverseCrfSimex(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                const CrfFitOptions& options, const SimexOptions& simex, SimexSummary* summary) {
  simex.check();
  CrfFitResult result = fitInverseCrf(sharp, blurred, kernel, options);
  Refits refits = runRefits(sharp, blurred, kernel, options, simex, result);
  refits.lambdas.insert(refits.lambdas.begin(), 0.0);
  refits.curves.insert(refits.curves.begin(), result.inverse_crf);
  refits.log_ratios.insert(refits.log_ratios.begin(), std::log(result.ratio));
  SimexSummary local;
  SimexSummary& info = summary ? *summary : local;
  info = SimexSummary{};
  info.noise_sigma = result.noise_sigma;
  info.multiples = refits.lambdas;
  info.curves = refits.curves;
  for (double lr : refits.log_ratios) info.ratios.push_back(std::exp(lr));
  info.refits = refits.succeeded;
  info.failed_refits = refits.failed;
  result.evaluations += refits.evaluations;
  // The polynomial needs more points than coefficients, or it merely interpolates the noise of the refits.
  if (static_cast<int>(refits.lambdas.size()) < simex.extrapolation_degree + 2 || !(result.noise_sigma > 0)) {
    result.choice_reason += "; SIMEX skipped (" + std::to_string(refits.succeeded) + " refits)";
    return result;
  }
  const std::vector<double> w = extrapolationWeights(refits.lambdas, simex.extrapolation_degree);
  std::vector<double> phi(kCurveSamples, 0.0);
  double log_ratio = 0;
  for (std::size_t k = 0; k < w.size(); ++k) {
    for (int i = 0; i < kCurveSamples; ++i) phi[i] += w[k] * refits.curves[k][i];
    log_ratio += w[k] * refits.log_ratios[k];
  }
  result.inverse_crf = validInverse(std::move(phi));
  result.model = TableModel{result.inverse_crf};
  if (options.fit_ratio) result.ratio = std::exp(log_ratio);
  result.chosen += "+simex";
  result.choice_reason += "; SIMEX: " + std::to_string(refits.succeeded) + " refits extrapolated to zero noise";
  info.extrapolated = true;
  return result;
}

}  // namespace crfcal
