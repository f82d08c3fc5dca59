#include "crf_preparation.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>

#include <opencv2/imgproc.hpp>

#include "crf_censored.hpp"
#include "crfcal/blur_model.hpp"
#include "crfcal/chroma_subsampling.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/noise_estimation.hpp"
#include "noise_debias_cache.hpp"

namespace crfcal::crf_fit {
namespace {

// σ of I: per level (given), single (given), else estimated when an objective or the noise handling needs it.
double noiseSigma(const cv::Mat& sharp, const cv::Mat& sharp_unit, int L, const CrfFitOptions& options,
                  CrfFitResult& result) {
  const bool seed_objective = options.experimental.objective == CrfObjective::seed_intensity;
  const bool need_sigma = options.experimental.noise != NoiseHandling::none || !seed_objective;
  double sigma = 0;
  if (!options.noise_sigma_per_level.empty()) {
    if (static_cast<int>(options.noise_sigma_per_level.size()) != L)
      throw InvalidInput("fit options: noise_sigma_per_level has " + std::to_string(options.noise_sigma_per_level.size()) +
                         " entries, the level grid has " + std::to_string(L));
    sigma = std::accumulate(options.noise_sigma_per_level.begin(), options.noise_sigma_per_level.end(), 0.0) / L;
  } else if (options.noise_sigma >= 0) {
    sigma = options.noise_sigma;
  } else if (need_sigma && sharp.rows >= 9 && sharp.cols >= 9) {
    sigma = estimateNoiseSigma(sharp_unit).sigma;
    result.noise_sigma_estimated = true;
  }
  result.noise_sigma = sigma;
  return sigma;
}

// Edge-preserving denoising of I: a bilateral filter (5×5, range σ_r = 2σ, spatial σ_s = 1.5), twice.
cv::Mat denoiseSharp(const cv::Mat& unit, double sigma) {
  if (!(sigma > 0.5 / 255)) return unit.clone();
  cv::Mat a, b;
  unit.convertTo(a, CV_32F);
  cv::bilateralFilter(a, b, 5, 2.0 * sigma, 1.5, cv::BORDER_REFLECT);
  cv::bilateralFilter(b, a, 5, 2.0 * sigma, 1.5, cv::BORDER_REFLECT);
  cv::Mat out;
  a.convertTo(out, CV_64F);
  cv::min(cv::max(out, 0.0), 1.0, out);
  return out;
}

// Pixels within the kernel's support of a marked pixel (the window of Eq. 4's mixture at each pixel).
cv::Mat dilateBySupport(const cv::Mat& marked, const cv::Mat& kernel) {
  const cv::Size ks((kernel.cols | 1) + (kernel.cols % 2 == 0 ? 1 : 0), (kernel.rows | 1) + (kernel.rows % 2 == 0 ? 1 : 0));
  cv::Mat out;
  cv::dilate(marked, out, cv::getStructuringElement(cv::MORPH_RECT, ks));
  return out;
}

// Whether I's noise reaches black, so that a black pixel there is noise, not clipped signal: σ̂ above one 8-bit level
// at full resolution, or at half resolution (estimateNoiseSigmaAtHalfResolution: a JPEG hides the noise from the
// full-resolution estimate). The ablation experimental.black_per_pixel_when_clean reads the full resolution only.
// A given σ (noise_sigma, noise_sigma_per_level) is taken as it is.
bool noiseReachesBlack(const Prepared& prep, bool noisy, const CrfFitOptions& options) {
  if (noisy) return true;
  const bool sigma_given = options.noise_sigma >= 0 || !options.noise_sigma_per_level.empty();
  if (sigma_given || options.experimental.black_per_pixel_when_clean || prep.sharp_unit.rows < 18 ||
      prep.sharp_unit.cols < 18)
    return false;
  return estimateNoiseSigmaAtHalfResolution(prep.sharp_unit).sigma * 255.0 > 1.0;
}

// Saturated or censored pixels of B or I inside the interior, dilated by the kernel's support.
//
// I's black end. A black pixel of a clean I is clipped signal, and at r = 8 the irradiance it hides is not small
// through B's steep toe: its support is dropped (measured: a noise-free, JPEG-coded dark sharp shot gave r 0.85 × the
// truth when black pixels were kept as data, 1.08 / 1.00 when dropped). Where I's noise reaches black, a black pixel
// outside a black region (5×5 median) is noise; dropping its support would drop the dark side of every edge near
// which the noise reaches black, so only black regions are censored there. Whether the noise reaches black is read
// at full resolution and, since a JPEG quantises away the finest scale, at half resolution too (noiseReachesBlack;
// measured on `bench pairs --ratio 8`: σ̂ 0.49 levels at full resolution, 1.61 at half, for a shot with 2.2 levels of
// noise; reading the full resolution alone raised r by 15–17 % on three pairs; docs/RESULTS.md#black-end). Kept dark
// pixels carry I's noise bias (Jensen), as a noisy I's always did.
// White: an irradiance above φ(1) is unbounded, so a clean I drops every white pixel's support; a noisy I (σ above
// one 8-bit level) clips at white by noise alone, and then only regions whose local median is white are saturated.
cv::Mat saturationMask(const Prepared& prep, const cv::Mat& interior, const CrfFitOptions& options) {
  const cv::Mat& kernel = prep.kernel;
  const bool noisy = prep.sigma * 255.0 > 1.0;  // more than one 8-bit level
  cv::Mat bad = (prep.blurred_unit >= options.saturation_high) | (prep.blurred_unit <= options.saturation_low);
  const bool black_is_noise = noiseReachesBlack(prep, noisy, options);
  cv::Mat sharp_median;
  if (black_is_noise || noisy) {
    cv::Mat sharp32;
    prep.sharp_unit.convertTo(sharp32, CV_32F);
    cv::medianBlur(sharp32, sharp_median, 5);
  }
  bad |= (black_is_noise ? sharp_median : prep.sharp_unit) <= options.saturation_low;
  bad |= (noisy ? sharp_median : prep.sharp_unit) >= options.saturation_high;
  bad = dilateBySupport(bad, kernel);
  bad &= interior;
  return bad;
}

// Pixels whose mixture φ(I) ⊗ K may be off by more than max_sharp_error (CrfFitOptions::sharp_error_bound, weighted
// by the kernel), among the candidates (inside the interior, not saturated, weight > 0), with a floor of kept pixels
// per level of I (sharp_error_floor; chroma_subsampling.hpp excludedByErrorBound).
cv::Mat unmodelledMask(const Prepared& prep, const cv::Mat& interior, const cv::Mat& saturated, const cv::Mat& weight,
                       const CrfFitOptions& options) {
  if (options.sharp_error_bound.empty()) return cv::Mat::zeros(interior.size(), CV_8U);
  if (options.sharp_error_bound.size() != interior.size() || options.sharp_error_bound.type() != CV_32F)
    throw InvalidInput("fit options: sharp_error_bound must be a CV_32F map of the pair's size");
  const cv::Mat candidates = interior & ~saturated & (weight > 0);
  return excludedByErrorBound(convolve(options.sharp_error_bound, prep.kernel), prep.sharp_used, candidates,
                              options.max_sharp_error, options.sharp_error_floor);
}

// The selection weight of every pixel: seed Eq. 23 (Γ = B − I ⊗ K > τ1, r = 1) or Eq. 24 (I's local range > τ2,
// r ≠ 1); moments: B's local range over the support > edge_threshold.
cv::Mat selectionWeight(const Prepared& prep, const CrfFitOptions& options) {
  const cv::Mat& kernel = prep.kernel;
  cv::Mat weight(prep.sharp_unit.size(), CV_64F, cv::Scalar(0));
  if (options.experimental.objective == CrfObjective::seed_intensity) {
    const bool unit_ratio = std::abs(options.nominal_ratio - 1.0) < 1e-9;
    if (unit_ratio) {
      const cv::Mat gamma = prep.blurred_unit - convolve(prep.sharp_used, kernel);  // Γ = B − I ⊗ K
      weight.setTo(0);
      gamma.copyTo(weight, gamma > options.experimental.tau1);  // Eq. 23
    } else {
      const LocalRange range = localRange(prep.sharp_used, kernel);
      const cv::Mat spread = range.max - range.min;
      spread.copyTo(weight, spread > options.experimental.tau2);  // Eq. 24
    }
  } else {
    const LocalRange& range = prep.blurred_range;
    const cv::Mat spread = range.max - range.min;
    spread.copyTo(weight, spread > options.edge_threshold);
  }
  return weight;
}

// The usable pixels (inside, not saturated, weight > 0), subsampled deterministically to max_pixels.
void selectPixels(Prepared& prep, const cv::Rect& inside, const cv::Mat& bad, const cv::Mat& weight,
                  const CrfFitOptions& options, CrfPixelAccounting& acc) {
  std::vector<cv::Point> candidates_px;
  const cv::Mat& selection = options.pixel_selection;
  if (!selection.empty() && (selection.size() != bad.size() || selection.type() != CV_8U))
    throw InvalidInput("fit: pixel_selection must be a CV_8U mask of the images' size");
  for (int y = inside.y; y < inside.y + inside.height; ++y)
    for (int x = inside.x; x < inside.x + inside.width; ++x) {
      if (bad.at<std::uint8_t>(y, x)) continue;
      if (!selection.empty() && !selection.at<std::uint8_t>(y, x)) continue;  // not in this resample
      if (weight.at<double>(y, x) > 0) candidates_px.emplace_back(x, y);
      else ++acc.low_weight;
    }
  if (options.max_pixels > 0 && static_cast<int>(candidates_px.size()) > options.max_pixels) {
    const double step = double(candidates_px.size()) / options.max_pixels;
    std::vector<cv::Point> sub;
    sub.reserve(options.max_pixels);
    for (int i = 0; i < options.max_pixels; ++i) sub.push_back(candidates_px[static_cast<std::size_t>(i * step)]);
    acc.subsampled = static_cast<int>(candidates_px.size() - sub.size());
    candidates_px = std::move(sub);
  }
  prep.pixels = std::move(candidates_px);
  acc.used = static_cast<int>(prep.pixels.size());
  acc.used_mask = cv::Mat::zeros(prep.sharp_unit.size(), CV_8U);
  for (const auto& p : prep.pixels) acc.used_mask.at<std::uint8_t>(p) = 255;
  if (acc.used < options.min_pixels)
    throw InvalidInput("fit: no usable edges: only " + std::to_string(acc.used) + " usable edge pixels (need " +
                       std::to_string(options.min_pixels) + "); the pair needs blurred edges away from saturation");
  for (const auto& p : prep.pixels) prep.seed_weight.push_back(weight.at<double>(p));
}

// Second-order Jensen correction (NoiseHandling::jensen): g = φ − ½ σ²(v) φ''(v), so that E[g(I) | c] = φ(c) up
// to O(σ⁴). A tridiagonal operator on the level grid (g = J f, applied to the moment rows as H J like R): local,
// so it does not amplify the noise the way the deconvolution R does.
// σ(v): given, else estimated per level from I (the sharp shot's noise grows with the signal: one σ for all levels
// over-corrects the shadows and under-corrects the highlights), else the single given σ.
Eigen::MatrixXd jensenOperator(const Prepared& prep, const CrfFitOptions& options) {
  const int L = prep.levels;
  std::vector<double> sigma_v = options.noise_sigma_per_level;
  if (sigma_v.empty() && options.noise_sigma < 0 && prep.sharp_unit.rows >= 9 && prep.sharp_unit.cols >= 9) {
    const NoiseProfile profile = estimateNoiseProfile(prep.sharp_unit);
    sigma_v = noiseSigmaPerLevel(profile.level, profile.sigma, L);
  }
  if (sigma_v.empty()) sigma_v.assign(L, prep.sigma);
  Eigen::MatrixXd jensen = Eigen::MatrixXd::Identity(L, L);
  for (int v = 0; v < L; ++v) {
    const double sv = sigma_v[v];
    const double s = 0.5 * sv * sv * double(L - 1) * double(L - 1);  // ½σ²/h², h = 1/(L−1)
    const int c = std::clamp(v, 1, L - 2);  // the ends use the nearest interior second difference
    jensen(v, c - 1) -= s;  // row v: g_v = f_v − s (f_{c+1} − 2 f_c + f_{c−1})
    jensen(v, c) += 2 * s;
    jensen(v, c + 1) -= s;
  }
  return jensen;
}

}  // namespace

Prepared preparePair(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel_in,
                     const CrfFitOptions& options, CrfFitResult& result) {
  if (sharp.empty() || blurred.empty()) throw InvalidInput("fit: empty image");
  if (sharp.size() != blurred.size()) throw InvalidInput("fit: sharp and blurred images differ in size");
  if (sharp.channels() != 1 || blurred.channels() != 1) throw InvalidInput("fit: images must be single-channel");
  Prepared prep;
  prep.kernel = normalizeKernel(kernel_in);
  prep.sharp_unit = toUnitGray(sharp);
  prep.blurred_unit = toUnitGray(blurred);
  const int L = std::max(naturalLevels(sharp), naturalLevels(blurred));
  prep.levels = L;
  result.levels = L;
  prep.sigma = noiseSigma(sharp, prep.sharp_unit, L, options, result);

  prep.sharp_used = prep.sharp_unit;
  if (options.experimental.noise == NoiseHandling::denoise) prep.sharp_used = denoiseSharp(prep.sharp_unit, prep.sigma);
  prep.sharp = toLevels(prep.sharp_used, L);
  prep.blurred = toLevels(prep.blurred_unit, L);
  if (options.experimental.objective != CrfObjective::seed_intensity)
    prep.blurred_range = localRange(prep.blurred_unit, prep.kernel);

  // Pixel accounting: border, saturation (dilated by the support), edges.
  CrfPixelAccounting& acc = result.pixels;
  acc.total = static_cast<int>(sharp.total());
  const cv::Rect inside = interiorRect(sharp.size(), prep.kernel);
  cv::Mat interior = cv::Mat::zeros(sharp.size(), CV_8U);
  if (inside.area() > 0) interior(inside).setTo(255);
  acc.border = acc.total - cv::countNonZero(interior);
  cv::Mat bad = saturationMask(prep, interior, options);
  acc.saturated = cv::countNonZero(bad);
  if (acc.saturated > 0 && acc.saturated == cv::countNonZero(interior))
    throw InvalidInput("fit: every pixel is saturated or censored (in B or I, dilated by the kernel support)");
  const cv::Mat weight = selectionWeight(prep, options);
  const cv::Mat unmodelled = unmodelledMask(prep, interior, bad, weight, options);
  acc.unmodelled = cv::countNonZero(unmodelled);
  bad |= unmodelled;
  selectPixels(prep, inside, bad, weight, options, acc);
  selectCensoredPixels(prep, inside, unmodelled, options, acc);
  return prep;
}

NoiseOperators makeNoiseOperators(const Prepared& prep, const CrfFitOptions& options) {
  const int L = prep.levels;
  const double sigma = prep.sigma;
  const bool seed_objective = options.experimental.objective == CrfObjective::seed_intensity;
  const NoiseHandling noise = options.experimental.noise;
  NoiseOperators ops;
  const bool use_debias = noise == NoiseHandling::debias && (sigma > 0 || !options.noise_sigma_per_level.empty());
  if (use_debias) {
    NoiseDebiasOptions dopt;
    dopt.levels = L;
    dopt.sigma = std::min(sigma, 0.5);
    dopt.sigma_per_level = options.noise_sigma_per_level;
    dopt.regularization = options.experimental.debias_regularization;
    dopt.regularizer = options.experimental.debias_regularizer;
    ops.debias = detail::cachedNoiseDebias(dopt);
  }
  ops.debias_active = use_debias && !ops.debias.identity();
  if (noise == NoiseHandling::jensen && !seed_objective && (sigma > 0 || !options.noise_sigma_per_level.empty()))
    ops.jensen = jensenOperator(prep, options);
  // the noise transition matrix (for the CUE variances) also without debiasing
  if (!ops.debias_active && !seed_objective && noise == NoiseHandling::none && sigma * (L - 1) >= 0.05) {
    NoiseDebiasOptions dopt;
    dopt.levels = L;
    dopt.sigma = std::min(sigma, 0.5);
    dopt.sigma_per_level = options.noise_sigma_per_level;
    ops.noise_only = detail::cachedNoiseDebias(dopt);
    ops.noise_only_active = true;
  }
  return ops;
}

}  // namespace crfcal::crf_fit
