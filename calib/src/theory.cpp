#include "crfcal/theory.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal::theory {
namespace {

std::string format(const char* fmt, auto... args) {
  char buffer[512];
  std::snprintf(buffer, sizeof buffer, fmt, args...);
  return buffer;
}

// Raised cosine from 0 (t = 0) to 1 (t = 1), C¹ at both ends.
double smoothStep(double t) { return 0.5 - 0.5 * std::cos(std::numbers::pi * std::clamp(t, 0.0, 1.0)); }

std::vector<double> rowOf(const cv::Mat& m) { return {m.ptr<double>(0), m.ptr<double>(0) + m.cols}; }

}  // namespace

// ---------------------------------------------------------------------------------------------------------

std::vector<double> fig1Signal() {
  std::vector<double> signal(1000);
  for (int x = 0; x < 1000; ++x) {
    double v = 0;
    if (x < 100) v = 0.15;
    else if (x < 250) v = 0.15 + 0.5 * smoothStep((x - 100) / 150.0);
    else if (x < 350) v = 0.65;
    else if (x < 500) v = 0.65 - 0.2 * (0.5 - 0.5 * std::cos(2 * std::numbers::pi * (x - 350) / 150.0));
    else if (x < 600) v = 0.65;
    else if (x < 700) v = 0.45;
    else if (x < 820) v = 0.05;
    else v = 0.95;
    signal[static_cast<size_t>(x)] = v;
  }
  return signal;
}

void ProfileOptions::check() const {
  if (kernel_lengths.empty()) throw InvalidInput("profile: no kernel lengths");
  for (int length : kernel_lengths)
    if (length < 1) throw InvalidInput("profile: kernel lengths must be positive");
  if (!(jump_threshold > 0)) throw InvalidInput("profile: jump threshold must be positive");
  if (auto validity = checkValidity(model); !validity) throw InvalidInput("profile: invalid curve: " + validity.reason);
}

ProfileResult blurProfiles(const std::vector<double>& signal, const ProfileOptions& options) {
  options.check();
  if (signal.size() < 2) throw InvalidInput("profile: the signal needs at least 2 samples");
  const ResponseCurve curve(options.model);
  const int n = static_cast<int>(signal.size());
  cv::Mat sharp(1, n, CV_64F);
  std::copy(signal.begin(), signal.end(), sharp.ptr<double>(0));
  std::vector<unsigned char> jump(signal.size(), 0);  // jump[j]: step between j − 1 and j
  for (int j = 1; j < n; ++j)
    jump[static_cast<size_t>(j)] = std::abs(signal[static_cast<size_t>(j)] - signal[static_cast<size_t>(j) - 1]) >
                                   options.jump_threshold;

  ProfileResult result;
  result.sharp = signal;
  for (int length : options.kernel_lengths) {
    const cv::Mat kernel = boxKernel(length);
    GammaProfile profile;
    profile.kernel_length = length;
    const cv::Mat blurred = irradianceBlur(sharp, curve, kernel);
    const cv::Mat intensity = intensityBlur(sharp, kernel);
    profile.blurred = rowOf(blurred);
    profile.intensity_blurred = rowOf(intensity);
    profile.gamma = rowOf(blurInconsistency(blurred, intensity));
    // (I ⊗ K)(x) = Σ_q K(q) I(x − q + c) reads I over [x + c − L + 1, x + c] (c = L / 2, borders replicate).
    const int c = length / 2;
    profile.near_edge.assign(signal.size(), 0);
    double sum_smooth = 0;
    int smooth = 0;
    profile.max_gamma = -1e300;
    profile.min_gamma = 1e300;
    for (int x = 0; x < n; ++x) {
      const int lo = std::max(1, x + c - length + 2), hi = std::min(n - 1, x + c);
      bool edge = false;
      for (int j = lo; j <= hi && !edge; ++j) edge = jump[static_cast<size_t>(j)] != 0;
      const double g = profile.gamma[static_cast<size_t>(x)];
      profile.near_edge[static_cast<size_t>(x)] = edge;
      profile.max_gamma = std::max(profile.max_gamma, g);
      profile.min_gamma = std::min(profile.min_gamma, g);
      if (edge) {
        profile.max_gamma_edge = std::max(profile.max_gamma_edge, g);
      } else {
        profile.max_abs_gamma_smooth = std::max(profile.max_abs_gamma_smooth, std::abs(g));
        sum_smooth += std::abs(g);
        ++smooth;
      }
    }
    profile.mean_abs_gamma_smooth = smooth > 0 ? sum_smooth / smooth : 0.0;
    result.profiles.push_back(std::move(profile));
  }
  return result;
}

std::string ProfileResult::summary() const {
  std::string text = "kernel  max_gamma  max|gamma|_smooth  mean|gamma|_smooth  max_gamma_edge\n";
  for (const auto& p : profiles)
    text += format("%4d px  %9.5f  %17.3e  %18.3e  %14.5f\n", p.kernel_length, p.max_gamma, p.max_abs_gamma_smooth,
                   p.mean_abs_gamma_smooth, p.max_gamma_edge);
  return text;
}

// ---------------------------------------------------------------------------------------------------------

void PatternOptions::check() const {
  if (block_values.empty()) throw InvalidInput("pattern: no blocks");
  for (double v : block_values)
    if (!(v >= 0 && v <= 1)) throw InvalidInput("pattern: block values must be in [0,1]");
  if (!(background >= 0 && background <= 1)) throw InvalidInput("pattern: background must be in [0,1]");
  if (block_width < 1 || gap < 1 || height < 3) throw InvalidInput("pattern: bad geometry");
  if (motion_length < 1) throw InvalidInput("pattern: motion length must be positive");
  if (auto validity = checkValidity(model); !validity) throw InvalidInput("pattern: invalid curve: " + validity.reason);
}

cv::Mat blockPattern(const PatternOptions& options) {
  options.check();
  const int blocks = static_cast<int>(options.block_values.size());
  const int width = options.gap + blocks * (options.block_width + options.gap);
  cv::Mat image(options.height, width, CV_64F, cv::Scalar(options.background));
  const int top = options.height / 3, bottom = options.height - options.height / 3;
  for (int i = 0; i < blocks; ++i) {
    const int x0 = options.gap + i * (options.block_width + options.gap);
    image(cv::Rect(x0, top, options.block_width, bottom - top)).setTo(options.block_values[static_cast<size_t>(i)]);
  }
  return image;
}

PatternResult analyzePattern(const PatternOptions& options) {
  options.check();
  const ResponseCurve curve(options.model);
  const cv::Mat kernel = boxKernel(options.motion_length);
  PatternResult result;
  result.sharp = blockPattern(options);
  result.blurred = irradianceBlur(result.sharp, curve, kernel);
  result.intensity_blurred = intensityBlur(result.sharp, kernel);
  result.gamma = blurInconsistency(result.blurred, result.intensity_blurred);
  cv::minMaxLoc(result.gamma, &result.min_gamma, &result.max_gamma);

  // Partial sums S_m = Σ_{q ≤ m} K(q), m = −1 … L − 1: the fraction t of the bright side under the kernel.
  std::vector<double> partial{0.0};
  for (int q = 0; q < kernel.cols; ++q) partial.push_back(partial.back() + kernel.at<double>(0, q));
  const auto predicted = [&](double a, double b) {
    double best = -1e300;
    for (double t : partial) {
      const double intensity = (1 - t) * a + t * b;
      best = std::max(best, curve.forward((1 - t) * curve.inverse(a) + t * curve.inverse(b)) - intensity);
    }
    return best;
  };

  const int row = options.height / 2;
  const double* g = result.gamma.ptr<double>(row);
  // A step between columns x − 1 and x enters (I ⊗ K)(p) for p ∈ [x − c, x − c + L − 2] (c = L / 2).
  const int length = options.motion_length, c = length / 2;
  for (int i = 0; i < static_cast<int>(options.block_values.size()); ++i) {
    const double value = options.block_values[static_cast<size_t>(i)];
    const int x0 = options.gap + i * (options.block_width + options.gap);
    for (int side = 0; side < 2; ++side) {
      EdgeStat edge;
      edge.block = i;
      edge.rising = side == 0;
      edge.x = side == 0 ? x0 : x0 + options.block_width;
      edge.contrast = std::abs(value - options.background);
      edge.predicted_max_gamma =
          side == 0 ? predicted(options.background, value) : predicted(value, options.background);
      edge.max_gamma = -1e300;
      for (int x = std::max(0, edge.x - c - 1); x <= std::min(result.gamma.cols - 1, edge.x - c + length - 1); ++x)
        edge.max_gamma = std::max(edge.max_gamma, g[x]);
      result.edges.push_back(edge);
    }
  }
  return result;
}

std::string PatternResult::summary() const {
  std::string text = "block  edge     contrast  max_gamma  predicted(Eq.12)\n";
  for (const auto& e : edges)
    text += format("%5d  %-7s  %8.3f  %9.5f  %9.5f\n", e.block, e.rising ? "rising" : "falling", e.contrast,
                   e.max_gamma, e.predicted_max_gamma);
  return text;
}

// ---------------------------------------------------------------------------------------------------------

void Theorem1Options::check() const {
  if (!(tolerance >= 0)) throw InvalidInput("theorem 1: tolerance must be non-negative");
  if (!(smooth_range > 0) || !(edge_range >= smooth_range))
    throw InvalidInput("theorem 1: need 0 < smooth_range <= edge_range");
}

BlurContext makeBlurContext(const cv::Mat& sharp, const cv::Mat& kernel) {
  if (sharp.empty() || sharp.channels() != 1) throw InvalidInput("theorem 1: need a single-channel image");
  BlurContext context;
  sharp.convertTo(context.sharp, CV_64F);
  double lo = 0, hi = 0;
  cv::minMaxLoc(context.sharp, &lo, &hi);
  if (!cv::checkRange(context.sharp) || lo < 0 || hi > 1) throw InvalidInput("theorem 1: image values must be in [0,1]");
  context.kernel = normalizeKernel(kernel);
  context.intensity_blurred = intensityBlur(context.sharp, context.kernel);
  context.range = localRange(context.sharp, context.kernel);
  return context;
}

Theorem1Check checkTheorem1(const BlurContext& context, const ResponseCurve& curve, const Theorem1Options& options) {
  options.check();
  Theorem1Check check;
  check.curve_convex = curve.isConvex();
  const cv::Mat blurred = irradianceBlur(context.sharp, curve, context.kernel);
  const cv::Mat gamma = blurInconsistency(blurred, context.intensity_blurred);
  const cv::Mat range = context.range.max - context.range.min;

  check.min_gamma = 1e300;
  check.max_gamma = -1e300;
  check.max_upper_excess = -1e300;
  check.max_blurred_above_max = -1e300;
  check.min_intensity_above_min = 1e300;
  double sum_gamma = 0, sum_smooth = 0, sum_edge = 0;
  double sum_r = 0, sum_rr = 0, sum_gg = 0, sum_gr = 0;
  for (int y = 0; y < gamma.rows; ++y) {
    const double* g = gamma.ptr<double>(y);
    const double* r = range.ptr<double>(y);
    const double* b = blurred.ptr<double>(y);
    const double* bh = context.intensity_blurred.ptr<double>(y);
    const double* lo = context.range.min.ptr<double>(y);
    const double* hi = context.range.max.ptr<double>(y);
    for (int x = 0; x < gamma.cols; ++x) {
      const double gv = g[x], rv = r[x];
      check.min_gamma = std::min(check.min_gamma, gv);
      check.max_gamma = std::max(check.max_gamma, gv);
      check.max_upper_excess = std::max(check.max_upper_excess, gv - rv);
      check.max_blurred_above_max = std::max(check.max_blurred_above_max, b[x] - hi[x]);
      check.min_intensity_above_min = std::min(check.min_intensity_above_min, bh[x] - lo[x]);
      if (gv < -options.tolerance) ++check.lower_violations;
      if (gv > rv + options.tolerance) ++check.upper_violations;
      if (rv == 0) {
        ++check.uniform_pixels;
        check.max_abs_gamma_uniform = std::max(check.max_abs_gamma_uniform, std::abs(gv));
      } else {
        check.max_tightness = std::max(check.max_tightness, gv / rv);
      }
      if (rv < options.smooth_range) {
        ++check.smooth_pixels;
        check.max_abs_gamma_smooth = std::max(check.max_abs_gamma_smooth, std::abs(gv));
        sum_smooth += std::abs(gv);
      }
      if (rv >= options.edge_range) {
        ++check.edge_pixels;
        check.max_gamma_edge = std::max(check.max_gamma_edge, gv);
        sum_edge += gv;
      }
      sum_gamma += gv;
      sum_r += rv;
      sum_rr += rv * rv;
      sum_gg += gv * gv;
      sum_gr += gv * rv;
    }
  }
  const double n = static_cast<double>(gamma.total());
  check.pixels = static_cast<long long>(gamma.total());
  check.mean_gamma = sum_gamma / n;
  check.mean_abs_gamma_smooth = check.smooth_pixels > 0 ? sum_smooth / double(check.smooth_pixels) : 0.0;
  check.mean_gamma_edge = check.edge_pixels > 0 ? sum_edge / double(check.edge_pixels) : 0.0;
  const double cov = sum_gr / n - (sum_gamma / n) * (sum_r / n);
  const double var_g = sum_gg / n - (sum_gamma / n) * (sum_gamma / n);
  const double var_r = sum_rr / n - (sum_r / n) * (sum_r / n);
  check.correlation = var_g > 0 && var_r > 0 ? cov / std::sqrt(var_g * var_r) : 0.0;
  if (options.keep_maps) {
    check.blurred = blurred;
    check.intensity_blurred = context.intensity_blurred;
    check.gamma = gamma;
    check.range = range;
  }
  return check;
}

Theorem1Check checkTheorem1(const cv::Mat& sharp, const ResponseCurve& curve, const cv::Mat& kernel,
                            const Theorem1Options& options) {
  return checkTheorem1(makeBlurContext(sharp, kernel), curve, options);
}

std::string Theorem1Check::summary() const {
  return format(
      "phi convex: %s; min Gamma %.3e, max Gamma %.4f, max(Gamma-(Imax-Imin)) %.3e; violations: lower %lld, upper "
      "%lld of %lld; uniform pixels %lld (max|Gamma| %.1e); smooth max|Gamma| %.2e, edge max Gamma %.4f; "
      "corr(Gamma, Imax-Imin) %.3f",
      curve_convex ? "yes" : "no", min_gamma, max_gamma, max_upper_excess, lower_violations, upper_violations, pixels,
      uniform_pixels, max_abs_gamma_uniform, max_abs_gamma_smooth, max_gamma_edge, correlation);
}

// ---------------------------------------------------------------------------------------------------------

std::vector<double> convexMinorant(const std::vector<double>& phi) {
  const size_t n = phi.size();
  if (n < 2) throw InvalidInput("convex minorant: need at least 2 samples");
  const auto xAt = [n](size_t i) { return double(i) / double(n - 1); };
  // Lower hull (Andrew's monotone chain; x is already sorted).
  std::vector<size_t> hull;
  for (size_t i = 0; i < n; ++i) {
    while (hull.size() >= 2) {
      const size_t a = hull[hull.size() - 2], b = hull.back();
      const double cross = (xAt(b) - xAt(a)) * (phi[i] - phi[a]) - (phi[b] - phi[a]) * (xAt(i) - xAt(a));
      if (cross <= 0) hull.pop_back();  // b lies on or above the chord a–i
      else break;
    }
    hull.push_back(i);
  }
  std::vector<double> out(n);
  for (size_t h = 0; h + 1 < hull.size(); ++h) {
    const size_t a = hull[h], b = hull[h + 1];
    for (size_t i = a; i <= b; ++i)
      out[i] = phi[a] + (phi[b] - phi[a]) * (xAt(i) - xAt(a)) / (xAt(b) - xAt(a));
  }
  return out;
}

std::vector<NamedCurve> referenceCurves() {
  std::vector<NamedCurve> curves;
  curves.push_back({"gamma2.2", GammaModel{2.2}, "phi(x) = x^2.2 (Fig. 1), convex"});
  curves.push_back({"gamma1.8", GammaModel{1.8}, "phi(x) = x^1.8, convex"});
  const std::vector<double> mean(emor::inverseMean().begin(), emor::inverseMean().end());
  curves.push_back({"emor-mean", EmorModel{}, "EMoR mean inverse g0 (DoRF average): concave near 0 and near 1"});
  curves.push_back({"emor-mean-convex", TableModel{convexMinorant(mean)}, "convex minorant of the EMoR mean"});
  curves.push_back({"ggcm-emor-mean", ggcm::fitInverse(mean).model, "GGCM (Eq. 19, n = 4) fit of the EMoR mean"});
  for (const auto& c : std::vector<std::vector<double>>{{0.5, 0.5}, {1.0, 0.5}}) {
    const auto samples = sampleInverse(EmorModel{c}, kCurveSamples);
    curves.push_back({format("ggcm-emor-%g_%g", c[0], c[1]), ggcm::fitInverse(samples).model,
                      format("GGCM fit of the EMoR curve c = (%g, %g)", c[0], c[1])});
  }
  curves.push_back({"gamma0.45", GammaModel{1 / 2.2}, "phi(x) = x^(1/2.2), concave: the converse of Theorem 1"});
  return curves;
}

}  // namespace crfcal::theory
