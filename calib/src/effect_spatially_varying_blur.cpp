// spatially_varying_blur: a kernel that varies with the position, K₀ + u K_x + v K_y + c R(u, v), vs one kernel K₀.
// Handheld blur varies across the frame mostly through the camera's roll: the path of a point at p is the
// translation T(t) plus θ(t)·R90·(p − c), so the kernel at p is the distribution of T + θ R90 (p − c). Expanded in p
// (u, v the position relative to the centre, over the half-diagonal): the first-order terms u K_x + v K_y carry a
// roll that moves with the translation, and the second-order term ½ E[θ²] (R90 p · ∇)² K carries a roll spread
// about the centre, which no first-order term sees (its kernel is even in p: measured on a planted rotation, the
// first-order model explained the held-back pixels 69 % worse than one kernel, the roll term 70 % better;
// docs/RESULTS.md#effects-roll). With θ independent of T that term is c R(u, v), R = (−v ∂x + u ∂y)² K, one
// parameter c on the global kernel's second derivatives. A kernel whose centroid moves linearly across the frame is
// a misregistration the registration left (a residual turn), not a varying blur: both models carry that shift field
// d(u, v) · ∇K (four parameters). Base: one kernel K₀ and the shift field; extended: (K₀, K_x, K_y, c) and the shift
// field; both estimated by least squares in the irradiance domain on the same fold (support: the global kernel's,
// dilated by one pixel) from Y = φ(B) and φ(I) (debiased when the base fit debiases), residuals weighted 1/φ'(B)
// like every other test. Tested around the selected model's φ, only when the pipeline estimated the kernel.
#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <limits>

#include "crfcal/kernel.hpp"
#include "crfcal/kernel_estimation.hpp"
#include "effect_problem.hpp"
#include "gram_products.hpp"
#include "parallel_jobs.hpp"

namespace crfcal::effect {

cv::Mat kernelAt(const BlurTest& bt, double u, double v) {
  cv::Mat k = bt.K0 + u * bt.Kx + v * bt.Ky;
  if (bt.roll != 0) k += bt.roll * (v * v * bt.Kxx - 2 * u * v * bt.Kxy + u * u * bt.Kyy);
  const auto& d = bt.shift;
  if (!bt.Kdx.empty()) k += (d[0] * u + d[1] * v) * bt.Kdx + (d[2] * u + d[3] * v) * bt.Kdy;
  k = cv::max(k, 0.0);
  const double sum = cv::sum(k)[0];
  if (!(sum > 0)) return normalizeKernel(bt.K0.clone() + 1e-12);
  return k / sum;
}

namespace {

// The least-squares problem of the kernel entries: rows are weighted samples, columns [K₀ entries | the shift field's
// four | u K₀ | v K₀ entries | the roll's c]. The shift field (column a · ∂K times u or v, ∂K on the support) is the
// kernel's centroid moving linearly across the frame: a residual misregistration (a turn of the blurred shot that
// the registration left), not a blur that varies, so the base model carries it too (measured: clean handheld pairs
// named a varying blur in 4 of 10 without it, 0 of 10 without the handheld turn; docs/RESULTS.md#effects-roll).
// Every solve goes through the normal equations of one fold (or both): the per-fold Gram matrices DᵀD and Dᵀt are
// accumulated once (normalEquations), and the base fit (the first m + 4 columns) reads their leading block, so the
// 3m × 3m products, the test's whole cost, are formed once per fold instead of once per solve. Only the m weighted
// kernel-footprint values a of each row are stored; the row [a | s | u a | v a | ρ] is formed in chunks while the Gram
// matrices accumulate (the whole design, n × 3m, was ~100 MB for a 189-entry support at 0.1 MP, most of a real
// pair's peak memory and page faults).
struct KernelDesign {
  std::vector<cv::Point> support;   // kernel entries fitted
  std::vector<std::size_t> idx;     // the samples used
  Eigen::MatrixXd A;                // n × m: the weighted footprint values a of each row
  Eigen::VectorXd u, v;             // the rows' positions relative to the centre, over the half-diagonal
  Eigen::MatrixXd shift;            // n × 4: the shift field's columns u a·∂ₓK, v a·∂ₓK, u a·∂ᵧK, v a·∂ᵧK
  Eigen::VectorXd roll;             // ρ: the roll term's column
  Eigen::VectorXd t;
  std::vector<int> fold;
  std::array<Eigen::MatrixXd, 2> gram;  // per fold: DᵀD (lower triangle filled, symmetric)
  std::array<Eigen::VectorXd, 2> rhs;   // per fold: Dᵀt
  int m() const { return static_cast<int>(support.size()); }
  int n() const { return static_cast<int>(idx.size()); }
  static constexpr int kShift = 4;
  int base() const { return m() + kShift; }           // one kernel and the shift field
  int extended() const { return 3 * m() + kShift + 1; }  // the varying kernel

  // Row r's prediction: [a | s | u a | v a | ρ] · θ, or [a | s] · θ for the base model.
  double predict(int r, const Eigen::VectorXd& theta) const {
    const int cols = static_cast<int>(theta.size()), k = m();
    double p = A.row(r).dot(theta.head(k)) + shift.row(r).dot(theta.segment(k, kShift));
    if (cols == extended())
      p += u(r) * A.row(r).dot(theta.segment(base(), k)) + v(r) * A.row(r).dot(theta.segment(base() + k, k)) +
           roll(r) * theta(cols - 1);
    return p;
  }

  // The folds' Gram matrices (n·(3m)²/2 each, the test's main cost) are independent: one per core.
  void normalEquations() {
    const int k = m(), cols = extended();
    const detail::VectorUnits units = detail::widestVectorUnits();
    const auto errors = detail::runInParallel(2, [&](int f) {
      std::vector<Eigen::Index> rows;
      for (int r = 0; r < n(); ++r)
        if (fold[r] == f) rows.push_back(r);
      gram[f] = Eigen::MatrixXd::Zero(cols, cols);
      rhs[f] = Eigen::VectorXd::Zero(cols);
      constexpr std::size_t kChunk = 512;  // rows per rank update: large enough for Eigen's blocked product
      Eigen::MatrixXd chunk;
      for (std::size_t start = 0; start < rows.size(); start += kChunk) {
        const Eigen::Index count = static_cast<Eigen::Index>(std::min(kChunk, rows.size() - start));
        chunk.resize(count, cols);
        Eigen::VectorXd target(count);
        for (Eigen::Index i = 0; i < count; ++i) {
          const Eigen::Index r = rows[start + static_cast<std::size_t>(i)];
          chunk.row(i).head(k) = A.row(r);
          chunk.row(i).segment(k, kShift) = shift.row(r);
          chunk.row(i).segment(base(), k) = u(r) * A.row(r);
          chunk.row(i).segment(base() + k, k) = v(r) * A.row(r);
          chunk(i, cols - 1) = roll(r);
          target(i) = t(r);
        }
        detail::addLowerGram(chunk.data(), static_cast<int>(count), cols, static_cast<int>(count), gram[f].data(),
                             units);
        rhs[f].noalias() += chunk.transpose() * target;
      }
      gram[f] = gram[f].selfadjointView<Eigen::Lower>();
    });
    for (const auto& e : errors)
      if (e) std::rethrow_exception(e);
  }

  // Least squares on one fold (−1: all rows) with the first `cols` columns.
  Eigen::VectorXd solve(int f, int cols) const {
    Eigen::MatrixXd G = f < 0 ? Eigen::MatrixXd(gram[0].topLeftCorner(cols, cols) + gram[1].topLeftCorner(cols, cols))
                              : Eigen::MatrixXd(gram[f].topLeftCorner(cols, cols));
    const Eigen::VectorXd b = f < 0 ? Eigen::VectorXd(rhs[0].head(cols) + rhs[1].head(cols)) : rhs[f].head(cols);
    G.diagonal().array() += 1e-9 * G.diagonal().mean() + 1e-300;
    return Eigen::VectorXd(G.ldlt().solve(b));
  }
};

// The support (the global kernel's, dilated by one pixel) and the samples whose kernel footprint lies inside g.
// Empty `problem`: ready to fill.
std::string selectDesign(const Samples& s, const cv::Mat& g, const cv::Mat& K, int max_samples, KernelDesign& kd) {
  double kmax = 0;
  cv::minMaxLoc(K, nullptr, &kmax);
  cv::Mat support = K > 0.01 * kmax;
  cv::dilate(support, support, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
  for (int y = 0; y < K.rows; ++y)
    for (int x = 0; x < K.cols; ++x)
      if (support.at<uchar>(y, x)) kd.support.emplace_back(x, y);
  const int m = kd.m();
  if (m > 500) return "kernel support too large for the varying kernel (" + std::to_string(m) + " entries)";
  const int cx = K.cols / 2, cy = K.rows / 2;
  // A regular subsample of the samples (every k-th keeps both folds and all regions).
  const std::size_t step = std::max<std::size_t>(1, s.size() / static_cast<std::size_t>(max_samples));
  for (std::size_t i = 0; i < s.size(); i += step) {
    const cv::Point p = s.pos[i];
    if (p.x - (K.cols - 1 - cx) < 0 || p.y - (K.rows - 1 - cy) < 0 || p.x + cx >= g.cols || p.y + cy >= g.rows)
      continue;
    kd.idx.push_back(i);
  }
  if (kd.n() < 6 * m) return "too few samples for " + std::to_string(kd.extended()) + " kernel parameters";
  return {};
}

// The shift field's and the roll term's parts: the first and second derivatives of the normalised global kernel
// (3×3 Sobel) on its grid.
void derivativeParts(const cv::Mat& K, BlurTest& bt) {
  const cv::Mat unit = K / cv::sum(K)[0];
  cv::Sobel(unit, bt.Kdx, CV_64F, 1, 0, 3, 1, 0, cv::BORDER_CONSTANT);
  cv::Sobel(unit, bt.Kdy, CV_64F, 0, 1, 3, 1, 0, cv::BORDER_CONSTANT);
  cv::Sobel(unit, bt.Kxx, CV_64F, 2, 0, 3, 1, 0, cv::BORDER_CONSTANT);
  cv::Sobel(unit, bt.Kxy, CV_64F, 1, 1, 3, 1, 0, cv::BORDER_CONSTANT);
  cv::Sobel(unit, bt.Kyy, CV_64F, 0, 2, 3, 1, 0, cv::BORDER_CONSTANT);
}

void fillDesign(const Samples& s, const cv::Mat& g, const cv::Mat& K, const BlurTest& parts, cv::Point2d centre,
                double radius, double min_derivative, KernelDesign& kd) {
  const int m = kd.m(), n = kd.n();
  const int cx = K.cols / 2, cy = K.rows / 2;
  Eigen::MatrixXd derivatives(m, 5);  // ∂x K, ∂y K, ∂xx K, ∂xy K, ∂yy K on the support
  for (int j = 0; j < m; ++j) {
    int col = 0;
    for (const cv::Mat* d : {&parts.Kdx, &parts.Kdy, &parts.Kxx, &parts.Kxy, &parts.Kyy})
      derivatives(j, col++) = d->at<double>(kd.support[j]);
  }
  kd.A.resize(n, m);
  kd.u.resize(n);
  kd.v.resize(n);
  kd.shift.resize(n, KernelDesign::kShift);
  kd.roll.resize(n);
  kd.t.resize(n);
  kd.fold.resize(n);
  for (int r = 0; r < n; ++r) {
    const std::size_t i = kd.idx[r];
    const cv::Point p = s.pos[i];
    kd.u(r) = (p.x - centre.x) / radius;
    kd.v(r) = (p.y - centre.y) / radius;
    const double w = 1.0 / std::max(s.d[i], min_derivative);
    kd.t(r) = w * s.Y[i];
    kd.fold[r] = s.fold[i];
    for (int j = 0; j < m; ++j)  // convolve(): out(p) = Σ_j K(j) in(p − (j − c))
      kd.A(r, j) = w * g.at<double>(p.y - (kd.support[j].y - cy), p.x - (kd.support[j].x - cx));
  }
  // Each row's footprint against the derivatives: the shift field's and the roll term's columns.
  const Eigen::MatrixXd a = kd.A * derivatives;
  const Eigen::ArrayXd u = kd.u.array(), v = kd.v.array();
  kd.shift.col(0) = (u * a.col(0).array()).matrix();
  kd.shift.col(1) = (v * a.col(0).array()).matrix();
  kd.shift.col(2) = (u * a.col(1).array()).matrix();
  kd.shift.col(3) = (v * a.col(1).array()).matrix();
  // R(u, v) = v² K_xx − 2uv K_xy + u² K_yy
  kd.roll = (v * v * a.col(2).array() - 2 * u * v * a.col(3).array() + u * u * a.col(4).array()).matrix();
}

BlurTest spatialBlurTest(const Samples& s, const cv::Mat& g, const cv::Mat& K, cv::Point2d centre, double radius,
                         int blocks, double min_derivative, int max_samples) {
  BlurTest bt;
  KernelDesign kd;
  bt.problem = selectDesign(s, g, K, max_samples, kd);
  if (!bt.problem.empty()) return bt;
  derivativeParts(K, bt);
  fillDesign(s, g, K, bt, centre, radius, min_derivative, kd);
  kd.normalEquations();
  const int m = kd.m(), n = kd.n();
  std::array<Eigen::VectorXd, 2> base, ext;
  for (int f = 0; f < 2; ++f) {
    base[f] = kd.solve(f, kd.base());
    ext[f] = kd.solve(f, kd.extended());
    if (!base[f].allFinite() || !ext[f].allFinite()) {
      bt.problem = "kernel fit failed";
      return bt;
    }
  }
  // Held-out residuals and the score test of the drop (see scoreTest).
  double e2 = 0, sum_d = 0, sum_delta2 = 0, total = 0;
  std::vector<double> block_sum(blocks, 0.0);
  for (int r = 0; r < n; ++r) {
    const int held = 1 - kd.fold[r];
    const double eb = kd.t(r) - kd.predict(r, base[held]);
    const double ee = kd.t(r) - kd.predict(r, ext[held]);
    e2 += eb * eb;
    sum_d += eb * eb - ee * ee;
    sum_delta2 += (eb - ee) * (eb - ee);
    block_sum[s.block[kd.idx[r]]] += eb;
  }
  total = e2;
  if (!(e2 > 0) || !(sum_delta2 > 0)) {
    bt.problem = "no residual";
    return bt;
  }
  double A = 0;
  for (double v : block_sum) A += v * v;
  A = std::max(1.0, A / e2);
  bt.heldout_error = (e2 - sum_d) / n;
  bt.cmp.gain = sum_d / total;
  bt.cmp.z = sum_d / (2 * std::sqrt(e2 / n * A * sum_delta2));
  const Eigen::VectorXd all = kd.solve(-1, kd.extended());
  bt.K0 = cv::Mat::zeros(K.size(), CV_64F);
  bt.Kx = cv::Mat::zeros(K.size(), CV_64F);
  bt.Ky = cv::Mat::zeros(K.size(), CV_64F);
  for (int j = 0; j < m; ++j) {
    bt.K0.at<double>(kd.support[j]) = all(j);
    bt.Kx.at<double>(kd.support[j]) = all(kd.base() + j);
    bt.Ky.at<double>(kd.support[j]) = all(kd.base() + m + j);
  }
  for (int i = 0; i < KernelDesign::kShift; ++i) bt.shift[static_cast<std::size_t>(i)] = all(m + i);
  bt.roll = all(kd.extended() - 1);
  const double n0 = cv::norm(bt.K0);
  bt.variation = n0 > 0 ? (cv::norm(bt.Kx) + cv::norm(bt.Ky)) / n0 : 0;
  bt.ok = true;
  return bt;
}

constexpr int kMaxKernelRows = 15000;  // samples the kernel's least squares reads (a regular subsample)

// φ(I) of the reported channel for the curve (debiased as p.debias says).
cv::Mat phiOfSharp(const EffectSearch& search, const Curve& curve) {
  const int gi = search.g_index;
  std::vector<double> f = onLevels(curve.phi, search.p.levels[gi]);
  if (!search.p.debias[gi].identity()) f = search.p.debias[gi].apply(f);
  return applyTable(search.p.I[gi], f);
}

void run(EffectSearch& search) {
  const EffectInputs& in = search.in;
  const EffectOptions& options = search.options;
  auto& e = search.entry("spatially_varying_blur");
  if (!(options.test_spatial_blur && in.kernel_estimated)) {
    e.detail = in.kernel_estimated ? "disabled" : "kernel given (not estimated)";
    return;
  }
  const int gi = search.g_index;
  search.blur = spatialBlurTest(search.problem.samples()[gi], phiOfSharp(search, search.curves[gi]), search.K,
                                search.centre, search.radius, search.blocks, options.min_derivative, kMaxKernelRows);
  const BlurTest& blur = search.blur;
  if (!blur.ok) {
    e.detail = blur.problem;
    return;
  }
  e.tested = true;
  e.gain = blur.cmp.gain;
  e.statistic = blur.cmp.z;
  e.detected = blur.cmp.gain >= options.min_gain && blur.cmp.z >= options.min_z;
  BlurTest roll_alone = blur;  // the corner's change from the roll term alone (no first-order terms, no shift)
  roll_alone.Kx = cv::Mat::zeros(blur.Kx.size(), CV_64F);
  roll_alone.Ky = roll_alone.Kx;
  roll_alone.shift = {};
  const cv::Mat centre_kernel = kernelAt(blur, 0, 0);
  e.parameters = {{"variation", blur.variation},
                  {"roll", blur.roll},
                  {"corner_kernel_difference", kernelRelativeError(kernelAt(blur, 0.7071, 0.7071), centre_kernel)},
                  {"corner_roll_difference", kernelRelativeError(kernelAt(roll_alone, 0.7071, 0.7071), centre_kernel)}};
  e.detail = fmt("kernel varying with the position: it changes by %.3f (relative) from the centre to a corner, %.3f "
                 "by the roll term alone",
                 e.parameters["corner_kernel_difference"], e.parameters["corner_roll_difference"]);
}

}  // namespace

double varyingKernelHeldoutError(const EffectSearch& search, const std::vector<Curve>& curves,
                                 const std::vector<double>& ratios) {
  EffectOptions phi_as_given = search.options;
  phi_as_given.phi_terms = 0;
  const int gi = search.g_index;
  const std::vector<Samples> samples = collect(search.p, curves, ratios, search.K, search.layout, phi_as_given);
  const BlurTest bt = spatialBlurTest(samples[gi], phiOfSharp(search, curves[gi]), search.K, search.centre,
                                      search.radius, search.blocks, search.options.min_derivative, kMaxKernelRows);
  return bt.ok ? bt.heldout_error : std::numeric_limits<double>::infinity();
}

const ModelCheck& spatiallyVaryingBlurCheck() {
  static const ModelCheck check{"spatially_varying_blur", run};
  return check;
}

}  // namespace crfcal::effect
