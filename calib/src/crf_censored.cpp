#include "crf_censored.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

#include "crf_curve.hpp"
#include "crf_preparation.hpp"
#include "crfcal/emor.hpp"

namespace crfcal::crf_fit {
namespace {

constexpr double kSqrt2 = 1.4142135623730951;
constexpr double kLogSqrt2Pi = 0.91893853320467274;

cv::Mat dilateBySupport(const cv::Mat& marked, const cv::Mat& kernel) {
  const cv::Size ks((kernel.cols | 1) + (kernel.cols % 2 == 0 ? 1 : 0), (kernel.rows | 1) + (kernel.rows % 2 == 0 ? 1 : 0));
  cv::Mat out;
  cv::dilate(marked, out, cv::getStructuringElement(cv::MORPH_RECT, ks));
  return out;
}

// Where φ(I) ⊗ K cannot be trusted for a censored observation: I near its own clip or at black (a noisy I: its
// local median, and within 3σ of the clip, since the noise clipped at 1 biases φ(I) low there), B at black (also
// the frame outside the overlap), all dilated by the kernel's support.
cv::Mat untrustedMixture(const Prepared& prep, const CrfFitOptions& options) {
  const double high = options.saturation_high, low = options.saturation_low;
  cv::Mat bad = (prep.blurred_unit <= low) | (prep.sharp_unit >= high);
  if (prep.sigma * 255.0 > 1.0) {
    cv::Mat s32, med;
    prep.sharp_unit.convertTo(s32, CV_32F);
    cv::medianBlur(s32, med, 5);
    bad |= (med >= high - 3 * prep.sigma) | (med <= low);
  } else {
    bad |= prep.sharp_unit <= low;
  }
  return dilateBySupport(bad, prep.kernel);
}

// A deterministic subsample of at most `cap` points (every (n/cap)-th), as selectPixels does for the data.
void thin(std::vector<cv::Point>& points, int cap) {
  if (cap <= 0 || static_cast<int>(points.size()) <= cap) return;
  const double step = double(points.size()) / cap;
  std::vector<cv::Point> sub;
  sub.reserve(cap);
  for (int i = 0; i < cap; ++i) sub.push_back(points[static_cast<std::size_t>(i * step)]);
  points = std::move(sub);
}

// The inverse Mills ratio φ(t) / Φ(t) of the standard normal, accurate for t ≪ 0 (asymptotic series below −20).
double millsRatio(double t) {
  if (t > -20) return std::exp(-0.5 * t * t - kLogSqrt2Pi) / (0.5 * std::erfc(-t / kSqrt2));
  const double u = 1 / (t * t);
  return -t / (1 - u + 3 * u * u - 15 * u * u * u);
}

}  // namespace

double negativeLogNormalCdf(double t) {
  if (t > -20) return -std::log(0.5 * std::erfc(-t / kSqrt2));
  const double u = 1 / (t * t);
  return 0.5 * t * t + kLogSqrt2Pi + std::log(-t) - std::log(1 - u + 3 * u * u - 15 * u * u * u);
}

double negativeLogNormalCdfDerivative(double t) { return -millsRatio(t); }

void selectCensoredPixels(Prepared& prep, const cv::Rect& inside, const cv::Mat& unmodelled,
                          const CrfFitOptions& options, CrfPixelAccounting& acc) {
  prep.censored_pixels.clear();
  prep.censored_side.clear();
  if (!(options.censored_weight > 0) || options.experimental.objective != CrfObjective::moments) return;
  const cv::Mat clipped = prep.blurred_unit >= options.saturation_high;
  if (cv::countNonZero(clipped(inside)) == 0) return;
  // The clipped pixels within the kernel's support of an unclipped one: where z crosses φ(s) (deep inside a clipped
  // region z is mostly far above it and says nothing).
  const cv::Mat rim = clipped & dilateBySupport(~clipped, prep.kernel);
  const cv::Mat untrusted = untrustedMixture(prep, options);
  const cv::Mat& selection = options.pixel_selection;
  std::vector<cv::Point> above;
  for (int y = inside.y; y < inside.y + inside.height; ++y)
    for (int x = inside.x; x < inside.x + inside.width; ++x) {
      if (!rim.at<std::uint8_t>(y, x) || untrusted.at<std::uint8_t>(y, x) || unmodelled.at<std::uint8_t>(y, x)) continue;
      if (!selection.empty() && !selection.at<std::uint8_t>(y, x)) continue;
      above.emplace_back(x, y);
    }
  thin(above, options.max_censored_pixels);
  acc.censored_clipped = static_cast<int>(above.size());
  prep.censored_pixels = std::move(above);
  prep.censored_side.assign(prep.censored_pixels.size(), 1);
}

CensoredRows buildCensoredRows(const Prepared& prep, const CrfFitOptions& options) {
  CensoredRows out;
  const int L = prep.levels;
  out.weight = options.censored_weight;
  out.margin = options.censored_margin;
  out.sat_level = std::clamp(options.saturation_high, 0.0, 1.0) * (L - 1);
  out.slope_v1 = L - 1;
  out.slope_v0 = std::max(0, L - 1 - std::max(2, 2 * (L - 1) / options.level_bins));
  const int n = static_cast<int>(prep.censored_pixels.size());
  out.h.resize(n, L);
  if (n == 0) return out;
  // σ_p: I's noise through the kernel and a stand-in φ (the EMoR mean curve g0), in B's intensity units.
  const std::vector<double> g0 = onLevelGrid(emor::inverseMean(), L);
  std::vector<double> gain2(L);  // (g0'(v) σ_v)²
  for (int v = 0; v < L; ++v) {
    const int a = std::max(0, v - 1), b = std::min(L - 1, v + 1);
    const double slope = (g0[b] - g0[a]) * (L - 1) / double(b - a);
    const double sv = options.noise_sigma_per_level.empty() ? prep.sigma : options.noise_sigma_per_level[v];
    gain2[v] = slope * slope * sv * sv;
  }
  const double top_slope = (g0[out.slope_v1] - g0[out.slope_v0]) * (L - 1) / double(out.slope_v1 - out.slope_v0);
  const double floor2 = options.censored_sigma_floor * options.censored_sigma_floor;
  const double r2 = options.nominal_ratio * options.nominal_ratio;
  const cv::Mat& kernel = prep.kernel;
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  const bool frac = !prep.sharp.frac.empty();
  std::vector<Eigen::Triplet<double>> triplets;
  std::vector<double> row(L, 0.0);
  std::vector<int> touched;
  for (int i = 0; i < n; ++i) {
    const cv::Point p = prep.censored_pixels[i];
    double var = 0;
    touched.clear();
    auto add = [&](int v, double mass) {
      if (row[v] == 0.0) touched.push_back(v);
      row[v] += mass;
    };
    for (int ky = 0; ky < kernel.rows; ++ky)
      for (int kx = 0; kx < kernel.cols; ++kx) {
        const double k = kernel.at<double>(ky, kx);
        if (!(k > 0)) continue;
        const int y = p.y + cy - ky, x = p.x + cx - kx;
        const int lo = prep.sharp.lo.at<std::uint16_t>(y, x);
        const double fr = frac ? prep.sharp.frac.at<float>(y, x) : 0.0;
        add(lo, k * (1 - fr));
        if (fr > 0) add(lo + 1, k * fr);
        var += k * k * gain2[lo];
      }
    for (int v : touched) {
      triplets.emplace_back(i, v, row[v]);
      row[v] = 0.0;
    }
    out.side.push_back(prep.censored_side[i]);
    out.sigma.push_back(std::sqrt(floor2 + r2 * var / (top_slope * top_slope)));
    out.fold.push_back(((p.x / 16) + (p.y / 16)) & 1);
  }
  out.h.setFromTriplets(triplets.begin(), triplets.end());
  out.h.makeCompressed();
  return out;
}

CensoredRows CensoredRows::select(int f) const {
  if (f < 0) return *this;
  CensoredRows out = *this;
  out.side.clear();
  out.sigma.clear();
  out.fold.clear();
  std::vector<Eigen::Triplet<double>> triplets;
  int k = 0;
  for (int i = 0; i < rows(); ++i) {
    if (fold[i] != f) continue;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(h, i); it; ++it)
      triplets.emplace_back(k, it.col(), it.value());
    out.side.push_back(side[i]);
    out.sigma.push_back(sigma[i]);
    out.fold.push_back(f);
    ++k;
  }
  out.h = Eigen::SparseMatrix<double, Eigen::RowMajor>(k, h.cols());
  out.h.setFromTriplets(triplets.begin(), triplets.end());
  out.h.makeCompressed();
  return out;
}

bool CensoredResiduals::terms(const std::vector<double>& f, double r, Terms& t) const {
  const int L = static_cast<int>(f.size());
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
  t.z = r * (rows_.h * fv);
  const int lo = std::min(L - 2, static_cast<int>(rows_.sat_level));
  const double w = rows_.sat_level - lo;
  t.f_sat = (1 - w) * f[lo] + w * f[lo + 1];
  t.slope = (f[rows_.slope_v1] - f[rows_.slope_v0]) * (L - 1) / double(rows_.slope_v1 - rows_.slope_v0);
  return t.slope > 1e-9;
}

bool CensoredResiduals::residuals(const std::vector<double>& f, double r, Eigen::VectorXd& res, int offset) const {
  const int n = count();
  if (n == 0) return true;
  Terms t;
  if (!terms(f, r, t)) return false;
  const double scale = norm_ * std::sqrt(rows_.weight);
  for (int i = 0; i < n; ++i) {
    const double s = rows_.sigma[i];
    const double arg = rows_.side[i] * (t.z[i] - t.f_sat) / (t.slope * s) + rows_.margin;
    res[offset + i] = scale * s * std::sqrt(2 * std::max(0.0, negativeLogNormalCdf(arg)));
  }
  return true;
}

void CensoredResiduals::jacobian(const std::vector<double>& f, const Eigen::MatrixXd& jm, double r, bool fit_ratio,
                                 const Eigen::VectorXd& res, int offset, Eigen::MatrixXd& jac) const {
  const int n = count();
  if (n == 0) return;
  Terms t;
  if (!terms(f, r, t)) return;
  const int L = static_cast<int>(f.size());
  const int d = static_cast<int>(jm.rows());
  const Eigen::MatrixXd dz = r * (rows_.h * jm.transpose());  // n × d
  const int lo = std::min(L - 2, static_cast<int>(rows_.sat_level));
  const double w = rows_.sat_level - lo;
  const double slope_scale = (L - 1) / double(rows_.slope_v1 - rows_.slope_v0);
  const double scale = norm_ * std::sqrt(rows_.weight);
  for (int i = 0; i < n; ++i) {
    const double rho = res[offset + i] / (scale * rows_.sigma[i]);  // √(2 nll)
    if (!(rho > 1e-12)) continue;                                   // far inside its side: no gradient
    const double s = rows_.sigma[i], side = rows_.side[i];
    const double u = t.z[i] - t.f_sat;
    const double arg = side * u / (t.slope * s) + rows_.margin;
    const double drho = negativeLogNormalCdfDerivative(arg) / rho;  // d√(2 nll)/d arg
    const double k = scale * s * drho * side / (t.slope * s);
    for (int j = 0; j < d; ++j) {
      const double dfs = (1 - w) * jm(j, lo) + w * jm(j, lo + 1);
      const double dslope = (jm(j, rows_.slope_v1) - jm(j, rows_.slope_v0)) * slope_scale;
      jac(offset + i, j) = k * (dz(i, j) - dfs - u * dslope / t.slope);
    }
    if (fit_ratio) jac(offset + i, d) = k * t.z[i];
  }
}

}  // namespace crfcal::crf_fit
