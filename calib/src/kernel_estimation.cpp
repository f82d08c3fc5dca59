#include "crfcal/kernel_estimation.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <mutex>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"

namespace crfcal {
namespace {

int oddAtLeast(double v, int minimum) {
  int n = static_cast<int>(std::ceil(v));
  if (n % 2 == 0) ++n;
  return std::max(n, minimum);
}

struct NormalEquations {
  Eigen::MatrixXd M;
  Eigen::VectorXd c;
  double yy = 0;
  long long pixels = 0;
};

// Adds one gradient pair (X = ∂I, Y = ∂B, both CV_64F, same size) with validity `m` (CV_8U, p usable) to the
// normal equations of a kernel of size n = 2r + 1.
void accumulate(const cv::Mat& X, const cv::Mat& Y, const cv::Mat& m, int n, NormalEquations& eq) {
  const int r = n / 2;
  const int h = X.rows, w = X.cols;
  if (h <= 2 * r + 2 || w <= 2 * r + 2) return;
  cv::Mat usable = cv::Mat::zeros(h, w, CV_8U);
  m(cv::Rect(r, r, w - 2 * r, h - 2 * r)).copyTo(usable(cv::Rect(r, r, w - 2 * r, h - 2 * r)));
  // M is approximated by the auto-correlation of ∂I, which is exact only when every pixel of I that enters a
  // usable prediction is itself counted once. Masking ∂I by the usable set and ∂B by that set eroded by half the
  // kernel keeps M and c consistent in scale (holes from saturation would otherwise inflate M and shrink k).
  cv::Mat inner;
  cv::erode(usable, inner, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(r + 1, r + 1)), cv::Point(-1, -1), 1,
            cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::Mat Xm = cv::Mat::zeros(h, w, CV_64F), Ym = cv::Mat::zeros(h, w, CV_64F);
  X.copyTo(Xm, usable);
  Y.copyTo(Ym, inner);
  usable = inner;
  const int ph = cv::getOptimalDFTSize(h + 2 * n), pw = cv::getOptimalDFTSize(w + 2 * n);
  cv::Mat px = cv::Mat::zeros(ph, pw, CV_64F), py = cv::Mat::zeros(ph, pw, CV_64F);
  Xm.copyTo(px(cv::Rect(0, 0, w, h)));
  Ym.copyTo(py(cv::Rect(0, 0, w, h)));
  cv::Mat fx, fy, auto_spec, cross_spec, R, C;
  cv::dft(px, fx, cv::DFT_COMPLEX_OUTPUT, h);
  cv::dft(py, fy, cv::DFT_COMPLEX_OUTPUT, h);
  cv::mulSpectrums(fx, fx, auto_spec, 0, true);
  cv::mulSpectrums(fy, fx, cross_spec, 0, true);
  cv::idft(auto_spec, R, cv::DFT_REAL_OUTPUT | cv::DFT_SCALE);
  cv::idft(cross_spec, C, cv::DFT_REAL_OUTPUT | cv::DFT_SCALE);
  auto at = [&](const cv::Mat& F, int dy, int dx) {
    return F.at<double>((dy + ph) % ph, (dx + pw) % pw);
  };
  const int nn = n * n;
  for (int j = 0; j < nn; ++j) {
    const int dy = j / n - r, dx = j % n - r;
    eq.c(j) += at(C, dy, dx);  // Σ_p Y(p) X(p − d)
  }
  // M(d1, d2) = R(d1 − d2); R is symmetric in the lag.
  for (int a = 0; a < nn; ++a) {
    const int ay = a / n - r, ax = a % n - r;
    for (int b = a; b < nn; ++b) {
      const int by = b / n - r, bx = b % n - r;
      const double v = at(R, ay - by, ax - bx);
      eq.M(a, b) += v;
      if (b != a) eq.M(b, a) += v;
    }
  }
  eq.yy += Ym.dot(Ym);
  eq.pixels += cv::countNonZero(usable);
}

NormalEquations buildLevel(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& valid,
                           const std::vector<cv::Rect>& regions, int n) {
  NormalEquations total;
  total.M = Eigen::MatrixXd::Zero(n * n, n * n);
  total.c = Eigen::VectorXd::Zero(n * n);
  std::mutex lock;
  cv::parallel_for_(cv::Range(0, static_cast<int>(regions.size())), [&](const cv::Range& range) {
    for (int t = range.start; t < range.end; ++t) {
      const cv::Rect rect = regions[t] & cv::Rect(0, 0, sharp.cols, sharp.rows);
      if (rect.width < 8 || rect.height < 8) continue;
      NormalEquations eq;
      eq.M = Eigen::MatrixXd::Zero(n * n, n * n);
      eq.c = Eigen::VectorXd::Zero(n * n);
      const cv::Mat x = sharp(rect), y = blurred(rect), m = valid(rect);
      const cv::Rect hx(0, 0, rect.width - 1, rect.height), hx1(1, 0, rect.width - 1, rect.height);
      const cv::Rect vy(0, 0, rect.width, rect.height - 1), vy1(0, 1, rect.width, rect.height - 1);
      cv::Mat mx, my;
      cv::bitwise_and(m(hx), m(hx1), mx);
      cv::bitwise_and(m(vy), m(vy1), my);
      accumulate(x(hx1) - x(hx), y(hx1) - y(hx), mx, n, eq);
      accumulate(x(vy1) - x(vy), y(vy1) - y(vy), my, n, eq);
      std::lock_guard<std::mutex> guard(lock);
      total.M += eq.M;
      total.c += eq.c;
      total.yy += eq.yy;
      total.pixels += eq.pixels;
    }
  });
  return total;
}

// FISTA on min kᵀMk − 2cᵀk + λ wᵀk, k ≥ 0, k = 0 outside `support`.
Eigen::VectorXd solve(const NormalEquations& eq, Eigen::VectorXd k, const std::vector<char>& support, double lambda,
                      int iterations, int rounds) {
  const int nn = static_cast<int>(eq.c.size());
  // Largest eigenvalue of M by power iteration.
  Eigen::VectorXd v = Eigen::VectorXd::Ones(nn) / std::sqrt(static_cast<double>(nn));
  double eig = 1;
  for (int i = 0; i < 40; ++i) {
    Eigen::VectorXd u = eq.M * v;
    eig = u.norm();
    if (!(eig > 0)) break;
    v = u / eig;
  }
  const double L = 2 * std::max(eig, 1e-30) * 1.05;
  const double lam = lambda * std::max(eq.c.maxCoeff(), 1e-30);
  Eigen::VectorXd w = Eigen::VectorXd::Ones(nn);
  for (int round = 0; round <= rounds; ++round) {
    Eigen::VectorXd z = k, previous = k;
    double t = 1;
    for (int it = 0; it < iterations; ++it) {
      Eigen::VectorXd grad = 2 * (eq.M * z - eq.c) + lam * w;
      Eigen::VectorXd next = z - grad / L;
      for (int j = 0; j < nn; ++j) next(j) = support[j] ? std::max(0.0, next(j)) : 0.0;
      const double t_next = 0.5 * (1 + std::sqrt(1 + 4 * t * t));
      z = next + ((t - 1) / t_next) * (next - previous);
      previous = next;
      t = t_next;
    }
    k = previous;
    const double peak = k.maxCoeff();
    if (!(peak > 0)) break;
    for (int j = 0; j < nn; ++j) w(j) = 1.0 / (k(j) / peak + 0.1);
    w /= w.minCoeff();
  }
  return k;
}

cv::Mat toKernel(const Eigen::VectorXd& k, int n) {
  cv::Mat K(n, n, CV_64F);
  for (int j = 0; j < n * n; ++j) K.at<double>(j / n, j % n) = k(j);
  return K;
}

double borderMass(const cv::Mat& K) {
  const int n = K.rows;
  const int ring = n >= 15 ? 2 : 1;
  const double total = cv::sum(K)[0];
  if (!(total > 0)) return 0;
  const double inner = cv::sum(K(cv::Rect(ring, ring, n - 2 * ring, n - 2 * ring)))[0];
  return (total - inner) / total;
}

cv::Mat padTo(const cv::Mat& K, int n) {
  cv::Mat out = cv::Mat::zeros(n, n, CV_64F);
  const int oy = (n - K.rows) / 2, ox = (n - K.cols) / 2;
  K.copyTo(out(cv::Rect(ox, oy, K.cols, K.rows)));
  return out;
}

}  // namespace

void KernelEstimationOptions::check() const {
  if (kernel_size < 3 || kernel_size % 2 == 0 || kernel_size > 151)
    throw InvalidInput("kernel size must be odd, between 3 and 151");
  if (!(lambda >= 0)) throw InvalidInput("kernel estimation: lambda must be >= 0");
  if (pyramid_levels < 0 || pyramid_levels > 8) throw InvalidInput("kernel estimation: pyramid_levels in 0..8");
  if (iterations < 1 || reweight_rounds < 0) throw InvalidInput("kernel estimation: bad iteration counts");
  if (!(prune_threshold >= 0 && prune_threshold < 1)) throw InvalidInput("kernel estimation: prune_threshold in [0,1)");
  if (!(border_limit > 0 && border_limit < 1)) throw InvalidInput("kernel estimation: border_limit in (0,1)");
}

std::string KernelEstimate::summary() const {
  char buffer[300];
  std::snprintf(buffer, sizeof buffer,
                "%dx%d kernel, %d non-zero, centroid (%.2f, %.2f) px, gain %.4g, residual %.3f, border mass %.3f%s",
                kernel.cols, kernel.rows, support, centroid.x, centroid.y, gain, relative_residual, border_mass,
                hit_size_limit ? " (HIT SIZE LIMIT)" : "");
  return buffer;
}

KernelEstimate estimateKernel(const cv::Mat& sharp_in, const cv::Mat& blurred_in, const std::vector<cv::Rect>& regions_in,
                              const cv::Mat& valid_in, const KernelEstimationOptions& options) {
  options.check();
  if (sharp_in.empty() || blurred_in.empty()) throw InvalidInput("kernel estimation: empty image");
  if (sharp_in.size() != blurred_in.size())
    throw InvalidInput("kernel estimation: the sharp and blurred images differ in size");
  const cv::Mat sharp = toUnitGray(sharp_in), blurred = toUnitGray(blurred_in);
  cv::Mat valid = valid_in.empty() ? cv::Mat(sharp.size(), CV_8U, cv::Scalar(255)) : valid_in;
  if (valid.size() != sharp.size() || valid.type() != CV_8U) throw InvalidInput("kernel estimation: bad validity mask");
  std::vector<cv::Rect> regions = regions_in;
  if (regions.empty()) regions.push_back(cv::Rect(0, 0, sharp.cols, sharp.rows));

  const int n_full = options.kernel_size;
  int levels = options.pyramid_levels;
  if (levels == 0) {
    levels = 1;
    while (levels < 6 && oddAtLeast(n_full / std::pow(2.0, levels), 3) >= 9) ++levels;
  }
  // The coarsest level must still hold a usable image.
  int min_side = sharp.cols;
  for (const auto& r : regions) min_side = std::min({min_side, r.width, r.height});
  while (levels > 1 && min_side / std::pow(2.0, levels - 1) < 48) --levels;

  KernelEstimate result;
  Eigen::VectorXd k;
  cv::Mat previous;  // kernel of the coarser level
  for (int level = levels - 1; level >= 0; --level) {
    const double scale = std::pow(0.5, level);
    const int n = level == 0 ? n_full : oddAtLeast(n_full * scale, 3);
    cv::Mat s = sharp, b = blurred, m = valid;
    std::vector<cv::Rect> rects = regions;
    if (level > 0) {
      cv::resize(sharp, s, cv::Size(), scale, scale, cv::INTER_AREA);
      cv::resize(blurred, b, cv::Size(), scale, scale, cv::INTER_AREA);
      cv::resize(valid, m, s.size(), 0, 0, cv::INTER_AREA);
      cv::threshold(m, m, 254, 255, cv::THRESH_BINARY);
      for (auto& r : rects)
        r = cv::Rect(cv::Point(static_cast<int>(r.x * scale), static_cast<int>(r.y * scale)),
                     cv::Point(static_cast<int>((r.x + r.width) * scale), static_cast<int>((r.y + r.height) * scale)));
    }
    if (options.progress) options.progress(static_cast<double>(levels - 1 - level) / levels, "kernel level " + std::to_string(level));
    const NormalEquations eq = buildLevel(s, b, m, rects, n);
    if (eq.pixels < 50 || !(eq.yy > 1e-12) || !(eq.M.trace() > 1e-12))
      throw InvalidInput("no edges: too little texture (or too many saturated pixels) to estimate the blur kernel");
    std::vector<char> support(n * n, 1);
    Eigen::VectorXd start = Eigen::VectorXd::Zero(n * n);
    if (!previous.empty()) {
      // Upsample the coarser kernel about the centre (×2), as the start and a (dilated) support.
      const int rp = previous.rows / 2, r = n / 2;
      const double f = static_cast<double>(n) / previous.rows > 1.5 ? 2.0 : static_cast<double>(n) / previous.rows;
      cv::Mat A = (cv::Mat_<double>(2, 3) << f, 0, r - f * rp, 0, f, r - f * rp);
      cv::Mat up;
      cv::warpAffine(previous, up, A, cv::Size(n, n), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
      double peak = 0;
      cv::minMaxLoc(up, nullptr, &peak);
      cv::Mat mask = up > 0.02 * peak, dilated;
      cv::dilate(mask, dilated, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(7, 7)));
      const double sum = cv::sum(up)[0];
      for (int j = 0; j < n * n; ++j) {
        support[j] = dilated.at<uchar>(j / n, j % n) ? 1 : 0;
        start(j) = sum > 0 ? up.at<double>(j / n, j % n) / sum * result.gain : 0;
      }
    }
    k = solve(eq, start, support, options.lambda, options.iterations, options.reweight_rounds);
    const double gain = k.sum();
    if (!(gain > 0)) throw InvalidInput("kernel estimation failed: the blurred image does not correlate with the sharp one");
    const double residual = (k.dot(eq.M * k) - 2 * eq.c.dot(k) + eq.yy) / eq.yy;
    result.levels.push_back({level, scale, n, residual});
    result.gain = gain;
    result.relative_residual = residual;
    previous = toKernel(k, n) / gain;
  }
  cv::Mat K = previous.clone();
  double peak = 0;
  cv::minMaxLoc(K, nullptr, &peak);
  K.setTo(0, K < options.prune_threshold * peak);
  {
    // Keep the connected parts of the support that carry real mass: isolated specks are noise ([27] likewise
    // removes them by hysteresis thresholding). Components with < 10 % of the largest one's mass are dropped.
    cv::Mat labels;
    const cv::Mat support8 = K > 0;
    const int count = cv::connectedComponents(support8, labels, 8, CV_32S);
    std::vector<double> mass(count, 0);
    for (int y = 0; y < K.rows; ++y)
      for (int x = 0; x < K.cols; ++x) mass[labels.at<int>(y, x)] += K.at<double>(y, x);
    double largest = 0;
    for (int l = 1; l < count; ++l) largest = std::max(largest, mass[l]);
    for (int y = 0; y < K.rows; ++y)
      for (int x = 0; x < K.cols; ++x)
        if (mass[labels.at<int>(y, x)] < 0.1 * largest) K.at<double>(y, x) = 0;
  }
  K /= cv::sum(K)[0];
  result.kernel = K;
  result.border_mass = borderMass(K);
  result.hit_size_limit = result.border_mass > options.border_limit;
  result.support = cv::countNonZero(K);
  const int r = K.rows / 2;
  for (int y = 0; y < K.rows; ++y)
    for (int x = 0; x < K.cols; ++x) {
      result.centroid.x += K.at<double>(y, x) * (x - r);
      result.centroid.y += K.at<double>(y, x) * (y - r);
    }
  if (options.progress) options.progress(1.0, "kernel");
  if (result.hit_size_limit && options.throw_on_size_limit) {
    char buffer[300];
    std::snprintf(buffer, sizeof buffer,
                  "the blur kernel reaches its size limit (%dx%d px, %.0f%% of its mass on the border): the blur or "
                  "the residual misregistration is larger; try a larger --kernel-size",
                  K.cols, K.rows, 100 * result.border_mass);
    throw InvalidInput(buffer);
  }
  return result;
}

KernelEstimate estimateKernel(const cv::Mat& sharp, const cv::Mat& blurred, const KernelEstimationOptions& options) {
  return estimateKernel(sharp, blurred, {}, {}, options);
}

double kernelRelativeError(const cv::Mat& estimate, const cv::Mat& truth) {
  const int n = std::max({estimate.rows, estimate.cols, truth.rows, truth.cols}) | 1;
  cv::Mat a = padTo(estimate, n), b = padTo(truth, n);
  return cv::norm(a - b) / std::max(cv::norm(b), 1e-300);
}

double kernelShapeError(const cv::Mat& estimate, const cv::Mat& truth, int max_shift) {
  const int n = (std::max({estimate.rows, estimate.cols, truth.rows, truth.cols}) + 2 * max_shift) | 1;
  cv::Mat a = padTo(estimate, n), b = padTo(truth, n);
  double best = 1e300;
  for (int dy = -max_shift; dy <= max_shift; ++dy)
    for (int dx = -max_shift; dx <= max_shift; ++dx) {
      cv::Mat shifted;
      cv::Mat A = (cv::Mat_<double>(2, 3) << 1, 0, dx, 0, 1, dy);
      cv::warpAffine(a, shifted, A, a.size(), cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
      best = std::min(best, cv::norm(shifted - b) / std::max(cv::norm(b), 1e-300));
    }
  return best;
}

}  // namespace crfcal
