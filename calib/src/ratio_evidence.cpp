#include "crfcal/ratio_evidence.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "crfcal/error.hpp"

namespace crfcal {

void RatioEvidenceOptions::check() const {
  if (!(nominal_log_sigma > 0) || !std::isfinite(nominal_log_sigma))
    throw InvalidInput("ratio evidence: nominal_log_sigma must be positive");
  if (replicates < 2 || replicates % 2 || replicates > 200)
    throw InvalidInput("ratio evidence: replicates must be even and in 2..200");
  if (!(images_exponent_sigma_floor >= 0) || !std::isfinite(images_exponent_sigma_floor))
    throw InvalidInput("ratio evidence: images_exponent_sigma_floor must be >= 0");
  if (!(min_relative_change >= 0)) throw InvalidInput("ratio evidence: min_relative_change must be >= 0");
  if (!(conflict_sigmas > 0)) throw InvalidInput("ratio evidence: conflict_sigmas must be positive");
  if (block_size < 4) throw InvalidInput("ratio evidence: block_size must be >= 4");
}

const char* toString(RatioDecision decision) {
  switch (decision) {
    case RatioDecision::images_alone: return "images alone";
    case RatioDecision::combined: return "combined";
    case RatioDecision::nominal_held: return "nominal held (images contradicted)";
    case RatioDecision::images_kept: return "images kept (nominal contradicted)";
  }
  return "?";
}

std::pair<double, double> brightnessRatioInterval(double brightness_ratio, double k_min, double k_max, double factor) {
  if (!(brightness_ratio > 0) || !std::isfinite(brightness_ratio)) return {0, 0};
  const double log_b = std::log(brightness_ratio), a = log_b * k_min, b = log_b * k_max;
  return {std::exp(std::min(a, b)) / factor, std::exp(std::max(a, b)) * factor};
}

RatioEvidence combineRatioEvidence(double images_ratio, const std::vector<double>& replicate_ratios,
                                   double nominal_ratio, const RatioEvidenceOptions& options,
                                   std::pair<double, double> brightness_interval, double noise_bias_log) {
  options.check();
  RatioEvidence e;
  e.images_ratio = e.ratio = images_ratio;
  e.replicate_ratios = replicate_ratios;
  e.nominal_ratio = nominal_ratio;
  e.nominal_log_sigma = options.nominal_log_sigma;
  int usable = 0;
  double sum_squares = 0;
  for (const double r : replicate_ratios)
    if (r > 0 && std::isfinite(r) && images_ratio > 0) {
      const double d = std::log(r / images_ratio);
      sum_squares += d * d;
      ++usable;
    }
  if (!(images_ratio > 0 && std::isfinite(images_ratio)) || !(nominal_ratio > 0 && std::isfinite(nominal_ratio)) ||
      usable < 2)
    return e;
  // Half-samples: Var(log r_half − log r_full) ≈ Var(log r_full), so the mean square deviation is the variance.
  e.resampled_log_sigma = std::sqrt(sum_squares / usable);
  e.noise_bias_log = std::isfinite(noise_bias_log) ? noise_bias_log : 0;
  const double floor = options.images_exponent_sigma_floor * std::abs(std::log(images_ratio));
  e.images_log_sigma = std::sqrt(e.resampled_log_sigma * e.resampled_log_sigma +
                                 e.noise_bias_log * e.noise_bias_log + floor * floor);
  const double log_images = std::log(images_ratio), log_nominal = std::log(nominal_ratio);
  if (!(e.images_log_sigma > 0)) {  // a noise-free exact fit: the images fix r
    e.combined = true;
    e.log_sigma = 0;
    return e;
  }
  const double w_images = 1 / (e.images_log_sigma * e.images_log_sigma);
  const double w_nominal = 1 / (options.nominal_log_sigma * options.nominal_log_sigma);
  e.images_weight = w_images / (w_images + w_nominal);
  e.ratio = std::exp(e.images_weight * log_images + (1 - e.images_weight) * log_nominal);
  e.log_sigma = 1 / std::sqrt(w_images + w_nominal);
  e.conflict_sigmas = std::abs(log_images - log_nominal) / std::hypot(e.images_log_sigma, options.nominal_log_sigma);
  e.conflict = e.conflict_sigmas > options.conflict_sigmas;
  e.combined = true;
  e.decision = RatioDecision::combined;
  e.brightness_low = brightness_interval.first;
  e.brightness_high = brightness_interval.second;
  if (e.conflict && brightness_interval.second > 0) {
    auto inside = [&](double r) { return r >= brightness_interval.first && r <= brightness_interval.second; };
    if (inside(nominal_ratio) && !inside(images_ratio)) {
      e.decision = RatioDecision::nominal_held;
      e.ratio = nominal_ratio;
      e.log_sigma = options.nominal_log_sigma;
      e.images_weight = 0;
    } else if (inside(images_ratio) && !inside(nominal_ratio)) {
      e.decision = RatioDecision::images_kept;
      e.ratio = images_ratio;
      e.log_sigma = e.images_log_sigma;
      e.images_weight = 1;
    }
  }
  return e;
}

std::string RatioEvidence::summary() const {
  char buffer[400];
  if (!combined) {
    std::snprintf(buffer, sizeof buffer, "r %.4g from the images alone (no combination)", images_ratio);
    return buffer;
  }
  std::snprintf(buffer, sizeof buffer,
                "r %.4g (sigma %.3f in log) = images %.4g (sigma %.3f: half-sample spread %.3f, %zu refits; noise "
                "bias %+.3f) with nominal %.4g (sigma %.3f); images' weight %.2f; their difference %.1f sigma%s",
                ratio, log_sigma, images_ratio, images_log_sigma, resampled_log_sigma, replicate_ratios.size(),
                noise_bias_log,
                nominal_ratio, nominal_log_sigma, images_weight, conflict_sigmas, conflict ? " (conflict)" : "");
  std::string text = buffer;
  if (brightness_high > 0) {
    std::snprintf(buffer, sizeof buffer, "; brightness allows r %.3g-%.3g", brightness_low, brightness_high);
    text += buffer;
  }
  text += "; " + std::string(toString(decision));
  if (!not_adopted_reason.empty()) text += "; not adopted: " + not_adopted_reason;
  return text;
}

}  // namespace crfcal
