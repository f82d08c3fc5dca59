// The pointwise band of φ (curve_band.hpp): half-sample block refits for the shape, exponent bounds for the scale and
// the curve beyond the data.
#include "crfcal/curve_band.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <numeric>
#include <optional>
#include <random>

#include "crfcal/band_ratio_term.hpp"
#include "crfcal/error.hpp"
#include "crfcal/response_model.hpp"
#include "parallel_jobs.hpp"

namespace crfcal {
namespace {

int sampleIndex(double x, int n) { return std::clamp(static_cast<int>(std::lround(x * (n - 1))), 0, n - 1); }

// Least-squares factor a of a·curve ≈ target over samples [i0, i1].
double alignmentFactor(const std::vector<double>& target, const std::vector<double>& curve, int i0, int i1) {
  double num = 0, den = 0;
  for (int i = i0; i <= i1; ++i) num += target[i] * curve[i], den += curve[i] * curve[i];
  return den > 0 ? num / den : 1.0;
}

// Local exponent d log φ / d log x of the fit between samples i0 < i1 (1 when undefined).
double localExponent(const std::vector<double>& phi, int i0, int i1) {
  const int n = static_cast<int>(phi.size());
  const double x0 = double(i0) / (n - 1), x1 = double(i1) / (n - 1);
  if (i0 <= 0 || i1 <= i0 || phi[i0] <= 0 || phi[i1] <= 0) return 1.0;
  return std::log(phi[i1] / phi[i0]) / std::log(x1 / x0);
}

// The sampling half-width t·σ(x): σ² the mean squared deviation of the scale-aligned replicates from φ.
std::vector<double> shapeHalfWidth(const std::vector<double>& phi, const std::vector<std::vector<double>>& replicates,
                                   int i0, int i1, double level) {
  const int n = static_cast<int>(phi.size());
  std::vector<double> width(n, 0.0);
  if (replicates.size() < 2) return width;
  std::vector<double> sum_squares(n, 0.0);
  for (const auto& rep : replicates) {
    const double a = alignmentFactor(phi, rep, i0, i1);
    for (int i = 0; i < n; ++i) sum_squares[i] += (a * rep[i] - phi[i]) * (a * rep[i] - phi[i]);
  }
  const double t = studentQuantile(0.5 + level / 2, static_cast<double>(replicates.size()));
  for (int i = 0; i < n; ++i) width[i] = t * std::sqrt(sum_squares[i] / replicates.size());
  return width;
}

// shapeHalfWidth widened by each alternative fit's scale-aligned difference (the model term).
std::vector<double> shapeHalfWidthWithModel(const std::vector<double>& phi,
                                            const std::vector<std::vector<double>>& replicates, int i0, int i1,
                                            const CurveBandOptions& options,
                                            const std::vector<std::vector<double>>& alternatives) {
  std::vector<double> width = shapeHalfWidth(phi, replicates, i0, i1, options.level);
  const int n = static_cast<int>(phi.size());
  if (options.include_model_spread)
    for (const auto& other : alternatives) {
      if (static_cast<int>(other.size()) != n) continue;
      const double a = alignmentFactor(phi, other, i0, i1);
      for (int i = 0; i < n; ++i) width[i] = std::hypot(width[i], a * other[i] - phi[i]);
    }
  return width;
}

}  // namespace

// Random halves of the blocks holding used pixels, in complementary pairs (antithetic: every block is in exactly
// one of each pair), as pixel masks.
std::vector<cv::Mat> halfSampleMasks(const cv::Mat& used, int block, int count, std::uint64_t seed) {
  std::vector<cv::Rect> blocks;
  for (int y = 0; y < used.rows; y += block)
    for (int x = 0; x < used.cols; x += block) {
      const cv::Rect r = cv::Rect(x, y, block, block) & cv::Rect(0, 0, used.cols, used.rows);
      if (cv::countNonZero(used(r)) > 0) blocks.push_back(r);
    }
  std::vector<cv::Mat> masks;
  if (blocks.size() < 4) return masks;
  std::mt19937_64 rng(seed);
  std::vector<std::size_t> order(blocks.size());
  for (int pair = 0; pair < count / 2; ++pair) {
    std::iota(order.begin(), order.end(), 0);
    std::shuffle(order.begin(), order.end(), rng);
    cv::Mat first = cv::Mat::zeros(used.size(), CV_8U), second = first.clone();
    for (std::size_t k = 0; k < order.size(); ++k) (k % 2 ? second : first)(blocks[order[k]]).setTo(255);
    masks.push_back(first);
    masks.push_back(second);
  }
  return masks;
}

void CurveBandOptions::check() const {
  if (!(level > 0 && level < 1)) throw InvalidInput("band: level must be in (0, 1)");
  if (replicates < 0 || replicates % 2 || replicates > 200)
    throw InvalidInput("band: replicates must be even and in 0..200");
  if (block_size < 4) throw InvalidInput("band: block_size must be >= 4");
  if (!(exponent_floor > 0 && exponent_ceiling >= exponent_floor))
    throw InvalidInput("band: need 0 < exponent_floor <= exponent_ceiling");
  if (!(exponent_rise_factor >= 1)) throw InvalidInput("band: exponent_rise_factor must be >= 1");
  if (!(offset_term_max_log_ratio >= 0)) throw InvalidInput("band: offset_term_max_log_ratio must be >= 0");
  if (above_data_prior && above_data_prior->empty()) throw InvalidInput("band: above_data_prior has no training curves");
  if (above_data_draws < 2 || above_data_draws > 100000)
    throw InvalidInput("band: above_data_draws must be in 2..100000");
}

std::string CurveBand::summary() const {
  if (empty()) return "no band";
  const int n = static_cast<int>(lower.size());
  const int i0 = sampleIndex(covered.first, n), i1 = sampleIndex(covered.second, n);
  std::vector<double> widths;
  for (int i = i0; i <= i1; ++i) widths.push_back(upper[i] - lower[i]);
  std::nth_element(widths.begin(), widths.begin() + widths.size() / 2, widths.end());
  char above[120];
  if (above_data == AboveData::learned_prior)
    std::snprintf(above, sizeof above, "above the data the learned prior of %d curves", above_data_curves);
  else
    std::snprintf(above, sizeof above, "exponent above the data %.2f-%.2f", exponent_above.first, exponent_above.second);
  char buffer[360];
  std::snprintf(buffer, sizeof buffer,
                "%.0f %% band from %d half-sample refits (%d failed): median width %.4f over the covered range "
                "%.2f-%.2f, scale factor %.3f-%.3f, %s",
                100 * level, replicates, failed_replicates, widths[widths.size() / 2], covered.first, covered.second,
                scale_range.first, scale_range.second, above);
  return buffer;
}

double studentQuantile(double p, double dof) {
  if (!(p > 0.5 && p < 1)) throw InvalidInput("studentQuantile: p must be in (0.5, 1)");
  // The normal quantile by bisection on Φ(z) = ½ erfc(−z/√2), then the Cornish–Fisher expansion in 1/ν.
  double lo = 0, hi = 40;
  for (int k = 0; k < 200; ++k) {
    const double mid = 0.5 * (lo + hi);
    (0.5 * std::erfc(-mid / std::sqrt(2.0)) < p ? lo : hi) = mid;
  }
  const double z = 0.5 * (lo + hi);
  if (dof <= 0) return z;
  const double z3 = z * z * z, z5 = z3 * z * z, z7 = z5 * z * z;
  return z + (z3 + z) / (4 * dof) + (5 * z5 + 16 * z3 + 3 * z) / (96 * dof * dof) +
         (3 * z7 + 19 * z5 + 17 * z3 - 15 * z) / (384 * dof * dof * dof);
}

CurveBand bandFromReplicates(const std::vector<double>& phi, const std::vector<std::vector<double>>& replicates,
                             std::pair<double, double> covered, const CurveBandOptions& options,
                             const std::vector<std::vector<double>>& alternatives,
                             const std::vector<std::vector<double>>& systematic) {
  options.check();
  const int n = static_cast<int>(phi.size());
  if (n < 16) throw InvalidInput("band: the curve needs at least 16 samples", ErrorSubject::curve);
  for (const auto& rep : replicates)
    if (static_cast<int>(rep.size()) != n) throw InvalidInput("band: replicate of another size", ErrorSubject::curve);
  if (!(covered.first >= 0 && covered.second <= 1 && covered.first < covered.second))
    throw InvalidInput("band: covered range must satisfy 0 <= lo < hi <= 1");
  const int i0 = sampleIndex(covered.first, n), i1 = std::max(sampleIndex(covered.second, n), i0 + 1);
  const double x_lo = double(i0) / (n - 1), x_hi = double(i1) / (n - 1);
  CurveBand band;
  band.level = options.level;
  band.covered = covered;
  band.replicates = static_cast<int>(replicates.size());
  band.shape_half_width = shapeHalfWidthWithModel(phi, replicates, i0, i1, options, alternatives);
  for (const auto& term : systematic) {
    if (static_cast<int>(term.size()) != n) throw InvalidInput("band: a term of another size", ErrorSubject::curve);
    for (int i = 0; i < n; ++i) band.shape_half_width[i] = std::hypot(band.shape_half_width[i], term[i]);
  }
  const std::vector<double>& h = band.shape_half_width;

  // The exponents beyond the data, from the fit's own exponent at the edge of the data (over ~5 % of x).
  const int span = std::max(1, std::min((i1 - i0) / 2, n / 20));
  auto exponentRange = [&](double g_edge) {
    return std::pair<double, double>{std::max(options.exponent_floor, std::min(g_edge, 1.0)),
                                     std::max(options.exponent_ceiling, options.exponent_rise_factor * g_edge)};
  };
  const auto [g_lo, g_hi] = exponentRange(localExponent(phi, i1 - span, i1));
  const auto [gb_lo, gb_hi] = exponentRange(localExponent(phi, std::max(i0, 1), std::max(i0, 1) + span));
  band.exponent_above = {g_lo, g_hi};

  // The scale: φ_true(x_hi) ∈ [x_hi^g_hi, x_hi^g_lo] (φ(1) = 1 reached from the top of the data); the fit's own
  // factor 1 always inside.
  const double top = std::max(phi[i1], 1e-9);
  double s_lo = std::min(1.0, std::pow(x_hi, g_hi) / top), s_hi = std::max(1.0, std::pow(x_hi, g_lo) / top);
  // Or the learned prior's quantiles of the continuation (CurveBandOptions::above_data_prior).
  std::optional<PriorContinuation> continuation;
  if (options.above_data_prior && i1 < n - 1 && coversANode({x_lo, x_hi})) {
    continuation = continuationQuantiles(*options.above_data_prior, phi, {x_lo, x_hi}, options.level,
                                         options.above_data_draws, options.seed);
    s_lo = std::min(1.0, continuation->scale_range.first);
    s_hi = std::max(1.0, continuation->scale_range.second);
    band.above_data = CurveBand::AboveData::learned_prior;
    band.above_data_curves = options.above_data_prior->curves;
  }
  if (i1 == n - 1) s_lo = s_hi = 1;  // data up to x = 1: the normalisation itself
  band.scale_range = {s_lo, s_hi};

  band.lower.assign(n, 0.0);
  band.upper.assign(n, 1.0);
  for (int i = i0; i <= i1; ++i) {
    band.lower[i] = s_lo * phi[i] - h[i];
    band.upper[i] = s_hi * phi[i] + h[i];
  }
  for (int i = i1 + 1; i < n; ++i) {  // above the data: the prior's quantiles, or x^g between the exponent bounds
    const double x = double(i) / (n - 1);
    // The prior's draws continue the fit from its top, which is itself uncertain by the shape half-width there:
    // added like inside (s·φ ± h), so that the band does not step at the top of the data.
    band.lower[i] = continuation ? continuation->lower[i] - h[i1] : std::pow(x, g_hi);  // φ = exp(−∫_x^1 g/t dt), g ≤ g_hi
    band.upper[i] = std::max(continuation ? continuation->upper[i] + h[i1] : std::pow(x, g_lo), band.upper[i1]);
  }
  for (int i = 0; i < i0; ++i) {  // below the data: φ(x_lo)·(x/x_lo)^g towards φ(0) = 0
    const double r = (double(i) / (n - 1)) / x_lo;
    band.lower[i] = band.lower[i0] * std::pow(r, gb_hi);
    band.upper[i] = band.upper[i0] * std::pow(r, gb_lo);
  }
  for (int i = 0; i < n; ++i) {  // the fit itself inside; φ in [0, 1]; φ(0) = 0 and φ(1) = 1 by normalisation
    band.lower[i] = std::clamp(std::min(band.lower[i], phi[i]), 0.0, 1.0);
    band.upper[i] = std::clamp(std::max(band.upper[i], phi[i]), 0.0, 1.0);
  }
  band.upper[n - 1] = band.lower[n - 1] = 1;
  band.lower[0] = 0;
  // Monotone limits (φ is increasing): the running max of the lower limit, the running min of the upper from above.
  for (int i = 1; i < n; ++i) band.lower[i] = std::max(band.lower[i], band.lower[i - 1]);
  for (int i = n - 2; i >= 0; --i) band.upper[i] = std::min(band.upper[i], band.upper[i + 1]);
  return band;
}

namespace {

// The upper median (the benches' convention since the band's first table).
double upperMedian(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// Sample indices [i0, i1] of the band's covered range.
std::pair<int, int> coveredSamples(const CurveBand& band, int n) {
  const int i0 = sampleIndex(band.covered.first, n);
  return {i0, std::max(sampleIndex(band.covered.second, n), i0 + 1)};
}

}  // namespace

namespace {

double medianOverCovered(const CurveBand& band, const std::vector<double>& half_width) {
  const int n = static_cast<int>(half_width.size());
  if (n < 2) return 0;
  const auto [i0, i1] = coveredSamples(band, n);
  return upperMedian(std::vector<double>(half_width.begin() + i0, half_width.begin() + std::min(i1, n - 1) + 1));
}

}  // namespace

double medianShapeHalfWidth(const CurveBand& band) { return medianOverCovered(band, band.shape_half_width); }

double medianShapeSigma(const CurveBand& band) {
  const double dof = band.replicates >= 2 ? static_cast<double>(band.replicates) : 0.0;  // 0: the normal quantile
  const std::vector<double>& half_width =
      band.images_ratio_half_width.empty() ? band.shape_half_width : band.images_ratio_half_width;
  return medianOverCovered(band, half_width) / studentQuantile(0.5 + band.level / 2, dof);
}

BandScore scoreBand(const CurveBand& band, const std::vector<double>& phi, const std::vector<double>& truth) {
  const int n = static_cast<int>(band.lower.size());
  if (n < 16 || static_cast<int>(phi.size()) != n || static_cast<int>(truth.size()) != n)
    throw InvalidInput("band score: band, curve and truth need the same number of samples", ErrorSubject::curve);
  const auto [i0, i1] = coveredSamples(band, n);
  BandScore score;
  score.truth_scale = alignmentFactor(phi, truth, i0, i1);
  std::vector<double> widths;
  for (int i = 0; i < n; ++i) {
    const bool hit = truth[i] >= band.lower[i] - 1e-12 && truth[i] <= band.upper[i] + 1e-12;
    if (i < i0) {
      ++score.below, score.below_hits += hit;
    } else if (i > i1) {
      ++score.above, score.above_hits += hit;
      if (2 * (i - i1) > n - 1 - i1) ++score.above_far, score.above_far_hits += hit;
    } else {
      ++score.inside, score.inside_hits += hit;
      score.shape_hits += std::abs(score.truth_scale * truth[i] - phi[i]) <= band.shape_half_width[i] + 1e-12;
      widths.push_back(band.upper[i] - band.lower[i]);
    }
  }
  score.median_width_inside = upperMedian(widths);
  score.median_shape_width_inside = 2 * medianShapeHalfWidth(band);
  return score;
}

BandAgreement bandAgreement(const std::vector<double>& phi_a, const CurveBand* band_a, const std::vector<double>& phi_b,
                            const CurveBand* band_b, std::pair<double, double> covered, double scale) {
  const int n = static_cast<int>(phi_a.size());
  auto fits = [n](const CurveBand* band) { return !band || static_cast<int>(band->lower.size()) == n; };
  if (n < 2 || static_cast<int>(phi_b.size()) != n || !fits(band_a) || !fits(band_b))
    throw InvalidInput("band agreement: curves and bands need the same number of samples", ErrorSubject::curve);
  BandAgreement agreement;
  agreement.level = band_a ? band_a->level : band_b ? band_b->level : 0.9;
  const double z = studentQuantile(0.5 + agreement.level / 2, 0);
  double sum_z2 = 0;
  int within = 0, overlap = 0;
  for (int i = 0; i < n; ++i) {
    const double x = double(i) / (n - 1);
    if (x < covered.first - 1e-12 || x > covered.second + 1e-12) continue;
    const double h_a = band_a ? band_a->shape_half_width[i] : 0, h_b = band_b ? band_b->shape_half_width[i] : 0;
    const double w = std::max(std::hypot(h_a, scale * h_b), 1e-9), d = phi_a[i] - scale * phi_b[i];
    within += std::abs(d) <= w;
    sum_z2 += (d * z / w) * (d * z / w);
    const double lo_a = band_a ? band_a->lower[i] : phi_a[i], hi_a = band_a ? band_a->upper[i] : phi_a[i];
    const double lo_b = band_b ? band_b->lower[i] : phi_b[i], hi_b = band_b ? band_b->upper[i] : phi_b[i];
    overlap += lo_a <= hi_b + 1e-12 && lo_b <= hi_a + 1e-12;
    ++agreement.samples;
  }
  if (agreement.samples > 0) {
    agreement.fraction_within = double(within) / agreement.samples;
    agreement.mean_z2 = sum_z2 / agreement.samples;
    agreement.fraction_absolute_overlap = double(overlap) / agreement.samples;
  }
  return agreement;
}

void ReplicateRatioRule::check() const {
  if (!(images_weight >= 0 && images_weight <= 1)) throw InvalidInput("band: the ratio rule's weight must be in [0, 1]");
  if (!(images_ratio > 0 && ratio > 0 && std::isfinite(images_ratio) && std::isfinite(ratio)))
    throw InvalidInput("band: the ratio rule's ratios must be positive");
}

double ReplicateRatioRule::heldRatio(double half_images_ratio) const {
  if (!(half_images_ratio > 0 && std::isfinite(half_images_ratio))) return ratio;
  return ratio * std::exp(images_weight * std::log(half_images_ratio / images_ratio));
}

HalfSampleRefits refitOnHalfSamples(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                    const CrfFitOptions& fit_options, const cv::Mat& used_mask, int replicates,
                                    int block_size, std::uint64_t seed,
                                    const std::optional<ReplicateRatioRule>& ratio_rule) {
  if (ratio_rule) {
    ratio_rule->check();
    if (!fit_options.fit_ratio) throw InvalidInput("band: a ratio rule needs the halves to fit r");
  }
  HalfSampleRefits refits;
  const int block = std::max(block_size, 2 * std::max(kernel.rows, kernel.cols));
  const std::vector<cv::Mat> masks = replicates > 0 && !used_mask.empty()
                                         ? halfSampleMasks(used_mask, block, replicates, seed)
                                         : std::vector<cv::Mat>{};
  // The refits are independent: one per core (each fit's own parallel loops then run serially; its stripes, and so
  // its sums, do not depend on that, so the band is the same as from a serial loop).
  const int n = static_cast<int>(masks.size());
  std::vector<std::optional<CrfFitResult>> fits(n);
  std::vector<double> images_ratios(n, 0.0);
  std::vector<std::vector<double>> images_curves(n);
  const std::vector<std::exception_ptr> errors = detail::runInParallel(n, [&](int i) {
    CrfFitOptions o = fit_options;
    o.pixel_selection = masks[i];
    o.progress = nullptr;
    try {
      if (ratio_rule) {  // the half's own combination of r, then φ at it (from the free fit, the same moments)
        CrfFitAtHeldRatio both = fitInverseCrfThenHoldRatio(
            sharp, blurred, kernel, o, [&](double fitted) { return ratio_rule->heldRatio(fitted); });
        images_ratios[i] = both.free_ratio.ratio;
        images_curves[i] = std::move(both.free_ratio.inverse_crf);
        fits[i] = std::move(both.held_ratio);
      } else {
        fits[i] = fitInverseCrf(sharp, blurred, kernel, o);
        images_ratios[i] = fits[i]->ratio;
      }
    } catch (const InvalidInput&) {
      fits[i].reset();  // a half without enough edge pixels: the estimate rests on the others
    }
  });
  for (int i = 0; i < n; ++i) {
    if (errors[i]) std::rethrow_exception(errors[i]);
    if (!fits[i]) {
      ++refits.failed;
      continue;
    }
    refits.curves.push_back(fits[i]->inverse_crf);
    refits.ratios.push_back(fits[i]->ratio);
    refits.images_ratios.push_back(images_ratios[i]);
    if (ratio_rule) refits.images_curves.push_back(images_curves[i]);
  }
  return refits;
}

std::vector<double> priorTermHalfWidth(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                       const CrfFitOptions& fit_options, const CrfFitResult& fit,
                                       std::pair<double, double> covered) {
  const int n = static_cast<int>(fit.inverse_crf.size());
  if (n < 16 || !(fit.ratio > 0)) return {};
  CrfFitOptions o = fit_options;
  o.exponent_smoothness = 0;
  o.shoulder_prior = 0;
  o.learned_prior.reset();
  o.progress = nullptr;
  std::vector<CrfFitResult> free;
  try {
    free = fitInverseCrfAtHeldRatios(sharp, blurred, kernel, o, {fit.ratio});
  } catch (const InvalidInput&) {
    return {};
  }
  if (free.size() != 1 || static_cast<int>(free[0].inverse_crf.size()) != n) return {};
  const std::vector<double>& curve = free[0].inverse_crf;
  const int i0 = sampleIndex(covered.first, n), i1 = std::max(sampleIndex(covered.second, n), i0 + 1);
  const double a = alignmentFactor(fit.inverse_crf, curve, i0, i1);
  std::vector<double> half_width(n);
  for (int i = 0; i < n; ++i) half_width[i] = std::abs(a * curve[i] - fit.inverse_crf[i]);
  return half_width;
}

std::vector<double> offsetTermHalfWidth(const std::vector<double>& phi, std::pair<double, double> covered,
                                        double level) {
  const int n = static_cast<int>(phi.size());
  if (n < 16) throw InvalidInput("band: the curve needs at least 16 samples", ErrorSubject::curve);
  const int i0 = sampleIndex(covered.first, n), i1 = std::max(sampleIndex(covered.second, n), i0 + 1);
  double sum = 0, sum_squares = 0;
  for (int i = i0; i <= i1; ++i) sum += phi[i], sum_squares += phi[i] * phi[i];
  std::vector<double> half_width(n, 0.0);
  if (!(sum_squares > 0)) return half_width;
  const double offset = level * std::max(phi[i0], 0.0);  // the uniform bound's central interval
  for (int i = 0; i < n; ++i) half_width[i] = offset * std::abs(1 - phi[i] * sum / sum_squares);
  return half_width;
}

CurveBand estimateCurveBand(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                            const CrfFitOptions& fit_options, const CrfFitResult& fit,
                            std::pair<double, double> covered, const CurveBandOptions& options,
                            const std::optional<ReplicateRatioRule>& ratio_rule, double ratio_log_sigma) {
  options.check();
  const auto start = std::chrono::steady_clock::now();
  CrfFitOptions refit_options = fit_options;
  if (options.refit_chosen_model && fit_options.model == CrfModelChoice::automatic) {
    if (fit.chosen == "ggcm") refit_options.model = CrfModelChoice::ggcm;
    else if (fit.chosen == "emor") refit_options.model = CrfModelChoice::emor;
    if (options.refits_start_from_fit && refit_options.model != CrfModelChoice::automatic)
      refit_options.start = CrfFitOptions::Start{fit.model, fit.ratio};
  }
  const HalfSampleRefits refits = refitOnHalfSamples(sharp, blurred, kernel, refit_options, fit.pixels.used_mask,
                                                     options.replicates, options.block_size, options.seed,
                                                     ratio_rule);
  const std::vector<std::vector<double>>& curves = refits.curves;
  const int failed = refits.failed;
  std::vector<std::vector<double>> alternatives;
  for (const auto& candidate : fit.candidates)
    if (candidate.valid && candidate.kind != fit.chosen && !candidate.inverse_crf.empty())
      alternatives.push_back(candidate.inverse_crf);
  // The r error every half shares, as φ's response to r held σ away (band_ratio_term.hpp): the refits' options
  // (chosen model, from the fit), so that it measures the estimator the band resamples.
  std::vector<double> ratio_term;
  if (options.include_ratio_term && ratio_log_sigma > 0)
    ratio_term = ratioTermHalfWidth(sharp, blurred, kernel, refit_options, fit, covered, ratio_log_sigma,
                                    options.level);
  std::vector<std::vector<double>> systematic;
  if (!ratio_term.empty()) systematic.push_back(ratio_term);
  // The priors' share, which every half carries alike (from the refits' options: the estimator the band resamples).
  std::vector<double> prior_term;
  if (options.include_prior_term)
    prior_term = priorTermHalfWidth(sharp, blurred, kernel, refit_options, fit, covered);
  if (!prior_term.empty()) systematic.push_back(prior_term);
  // The offset Eq. 4 leaves free at r = 1, which the halves' shared extrapolation to φ(0) = 0 fixes alike.
  std::vector<double> offset_term;
  if (options.include_offset_term && fit.ratio > 0 &&
      std::abs(std::log(fit.ratio)) <= options.offset_term_max_log_ratio)
    offset_term = offsetTermHalfWidth(fit.inverse_crf, covered, options.level);
  if (!offset_term.empty()) systematic.push_back(offset_term);
  CurveBand band = bandFromReplicates(fit.inverse_crf, curves, covered, options, alternatives, systematic);
  band.failed_replicates = failed;
  if (!ratio_term.empty()) {
    band.ratio_half_width = std::move(ratio_term);
    band.ratio_log_sigma = ratio_log_sigma;
  }
  band.prior_half_width = std::move(prior_term);
  band.offset_half_width = std::move(offset_term);
  const int n = static_cast<int>(fit.inverse_crf.size());
  const int i0 = sampleIndex(covered.first, n), i1 = std::max(sampleIndex(covered.second, n), i0 + 1);
  if (ratio_rule && refits.images_curves.size() >= 2) {
    band.images_ratio_half_width =
        shapeHalfWidthWithModel(fit.inverse_crf, refits.images_curves, i0, i1, options, alternatives);
  } else if (!systematic.empty()) {
    // Without a rule the refits fitted their own r: their half-width before the ratio and prior terms is the
    // images' own (the verdict's reading, unchanged by the terms).
    band.images_ratio_half_width = shapeHalfWidthWithModel(fit.inverse_crf, curves, i0, i1, options, alternatives);
  }
  band.replicate_ratios = refits.ratios;
  band.replicate_images_ratios = refits.images_ratios;
  band.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return band;
}

}  // namespace crfcal
