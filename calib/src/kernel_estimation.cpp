#include "crfcal/kernel_estimation.hpp"
#include "kernel_pieces.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <limits>
#include <numeric>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "gram_products.hpp"

namespace crfcal {
namespace {

int oddAtLeast(double v, int minimum) {
  int n = static_cast<int>(std::ceil(v));
  if (n % 2 == 0) ++n;
  return std::max(n, minimum);
}

// Normal equations of  Σ_p (Y(p) − Σ_{j∈S} k_j X(p − d_j))²  over the selected pixels p, for the active
// offsets S (the kernel's support at this level).
struct NormalEquations {
  Eigen::MatrixXd M;
  Eigen::VectorXd c;
  double yy = 0;
  long long pixels = 0;
};

// One gradient direction at one pyramid level: X = ∂I, Y = ∂B and the pixels p whose equation is used.
struct Direction {
  cv::Mat X, Y;                   // CV_64F
  cv::Mat W;                      // CV_64F weight of each pixel's equation (empty: 1)
  std::vector<cv::Point> pixels;  // selected equations
};

// Forward differences along x (dir 0) or y (dir 1); `ok` marks the pixels whose difference uses two valid pixels.
void forwardDifference(const cv::Mat& image, const cv::Mat& valid, int dir, cv::Mat& diff, cv::Mat& ok) {
  diff = cv::Mat::zeros(image.size(), CV_64F);
  ok = cv::Mat::zeros(image.size(), CV_8U);
  const cv::Rect a = dir == 0 ? cv::Rect(0, 0, image.cols - 1, image.rows) : cv::Rect(0, 0, image.cols, image.rows - 1);
  const cv::Rect b = dir == 0 ? cv::Rect(1, 0, image.cols - 1, image.rows) : cv::Rect(0, 1, image.cols, image.rows - 1);
  cv::Mat d = image(b) - image(a);
  d.copyTo(diff(a));
  cv::Mat both;
  cv::bitwise_and(valid(a), valid(b), both);
  both.copyTo(ok(a));
}

// Robust std of a zero-centred quantity over a mask (1.4826 · median |v|).
double robustSigma(const cv::Mat& v, const cv::Mat& mask) {
  std::vector<double> values;
  values.reserve(static_cast<std::size_t>(cv::countNonZero(mask)));
  for (int y = 0; y < v.rows; ++y) {
    const double* p = v.ptr<double>(y);
    const uchar* m = mask.ptr<uchar>(y);
    for (int x = 0; x < v.cols; ++x)
      if (m[x]) values.push_back(std::abs(p[x]));
  }
  if (values.empty()) return 0;
  auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  return 1.4826 * *mid;
}

// Selects the equations of one direction. A pixel p is usable when ∂B(p) and every ∂I(p − d), |d|∞ ≤ r, are
// valid (so that the normal equations are exact whatever the shape of the mask: no approximation of the masked
// Gram matrix by an auto-correlation), p lies in one of the regions, and ∂I carries structure around p: the
// energy of ∂I over the (2r+1)² window exceeds `texture_factor` times what the noise alone gives there (the
// noise level from the image's own robust gradient statistics). Flat pixels add only the noise of ∂I to the
// Gram matrix (errors in variables: a shrunk, spread kernel) and nothing to the cross term.
Direction selectEquations(const cv::Mat& s, const cv::Mat& b, const cv::Mat& valid, const cv::Mat& weights,
                          const cv::Mat& region_mask, int dir, int r, const KernelEstimationOptions& options,
                          int max_equations, std::uint64_t salt) {
  Direction d;
  d.W = weights;
  cv::Mat okx, oky;
  forwardDifference(s, valid, dir, d.X, okx);
  forwardDifference(b, valid, dir, d.Y, oky);
  cv::Mat ok;
  cv::bitwise_and(okx, oky, ok);
  cv::Mat inner;
  cv::erode(ok, inner, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 1, 2 * r + 1)), cv::Point(-1, -1), 1,
            cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::bitwise_and(inner, region_mask, inner);
  if (cv::countNonZero(inner) == 0) return d;
  cv::Mat energy;
  {
    cv::Mat x2 = d.X.mul(d.X);
    x2.setTo(0, ~ok);
    cv::boxFilter(x2, energy, CV_64F, cv::Size(2 * r + 1, 2 * r + 1), cv::Point(-1, -1), false, cv::BORDER_CONSTANT);
  }
  const double sigma = robustSigma(d.X, ok);
  const double floor = options.texture_factor * (2 * r + 1) * (2 * r + 1) * sigma * sigma;
  std::vector<cv::Point> candidates;
  for (int y = 0; y < inner.rows; ++y) {
    const uchar* m = inner.ptr<uchar>(y);
    const double* e = energy.ptr<double>(y);
    for (int x = 0; x < inner.cols; ++x)
      if (m[x] && e[x] > floor) candidates.emplace_back(x, y);
  }
  if (static_cast<int>(candidates.size()) > max_equations) {
    // Deterministic uniform subsample (a fixed pseudo-random order): keeps the spatial spread of the equations.
    std::vector<std::pair<std::uint64_t, int>> order(candidates.size());
    for (std::size_t i = 0; i < candidates.size(); ++i) {
      std::uint64_t h = (static_cast<std::uint64_t>(candidates[i].y) << 32) ^ static_cast<std::uint64_t>(candidates[i].x) ^ salt;
      h ^= h >> 33;
      h *= 0xff51afd7ed558ccdULL;
      h ^= h >> 33;
      h *= 0xc4ceb9fe1a85ec53ULL;
      h ^= h >> 33;
      order[i] = {h, static_cast<int>(i)};
    }
    std::nth_element(order.begin(), order.begin() + max_equations, order.end());
    std::vector<cv::Point> kept;
    kept.reserve(static_cast<std::size_t>(max_equations));
    for (int i = 0; i < max_equations; ++i) kept.push_back(candidates[static_cast<std::size_t>(order[i].second)]);
    std::sort(kept.begin(), kept.end(), [](const cv::Point& a, const cv::Point& b) { return a.y != b.y ? a.y < b.y : a.x < b.x; });
    candidates.swap(kept);
  }
  d.pixels = std::move(candidates);
  return d;
}

// Exact normal equations over the selected pixels, restricted to the offsets in `offsets` (dy, dx relative to the
// kernel centre): M = Aᵀ A, c = Aᵀ y with A(p, j) = X(p − d_j). Built in blocks of rows (a single-precision Gram
// product per block, AVX2 + FMA where the CPU has it, gram_products.hpp; the image data carry far less precision;
// the blocks are summed in double), in parallel: one contiguous run
// of blocks per thread, each summed in block order, the runs added in run order. (Adding each worker's sum as it
// finished made the result depend on which finished first: two runs of one calibration differed by ~1e-10.)
void accumulate(const Direction& d, const std::vector<cv::Point>& offsets, NormalEquations& eq) {
  const int ns = static_cast<int>(offsets.size());
  const int total = static_cast<int>(d.pixels.size());
  constexpr int block = 1024;
  const int blocks = (total + block - 1) / block;
  const int runs = std::max(1, std::min(blocks, cv::getNumThreads()));
  std::vector<Eigen::MatrixXd> run_M(static_cast<std::size_t>(runs));
  std::vector<Eigen::VectorXd> run_c(static_cast<std::size_t>(runs));
  std::vector<double> run_yy(static_cast<std::size_t>(runs), 0.0);
  const detail::VectorUnits units = detail::widestVectorUnits();
  cv::parallel_for_(cv::Range(0, runs), [&](const cv::Range& run_range) {
    for (int run = run_range.start; run < run_range.end; ++run) {
      Eigen::MatrixXd M = Eigen::MatrixXd::Zero(ns, ns);
      Eigen::VectorXd c = Eigen::VectorXd::Zero(ns);
      double yy = 0;
      Eigen::MatrixXf A(block, ns);
      Eigen::MatrixXf G(ns, ns);
      Eigen::VectorXf y(block), w(block);
      const int first = static_cast<int>(static_cast<long long>(blocks) * run / runs);
      const int last = static_cast<int>(static_cast<long long>(blocks) * (run + 1) / runs);
      for (int bi = first; bi < last; ++bi) {
        const int start = bi * block, rows = std::min(block, total - start);
        for (int j = 0; j < ns; ++j) {
          const cv::Point o = offsets[static_cast<std::size_t>(j)];
          float* column = A.col(j).data();
          for (int i = 0; i < rows; ++i) {
            const cv::Point p = d.pixels[static_cast<std::size_t>(start + i)];
            column[i] = static_cast<float>(d.X.at<double>(p.y - o.y, p.x - o.x));
          }
        }
        for (int i = 0; i < rows; ++i) {
          const cv::Point p = d.pixels[static_cast<std::size_t>(start + i)];
          y(i) = static_cast<float>(d.Y.at<double>(p.y, p.x));
        }
        if (!d.W.empty()) {  // weighted least squares: each equation (row of A and y) scaled by its pixel's weight
          for (int i = 0; i < rows; ++i) {
            const cv::Point p = d.pixels[static_cast<std::size_t>(start + i)];
            w(i) = static_cast<float>(d.W.at<double>(p.y, p.x));
          }
          A.topRows(rows) = w.head(rows).asDiagonal() * A.topRows(rows);
          y.head(rows).array() *= w.head(rows).array();
        }
        const auto Ab = A.topRows(rows);
        G.setZero();
        detail::addLowerGram(A.data(), rows, ns, block, G.data(), units);
        M += G.cast<double>();
        c += (Ab.transpose() * y.head(rows)).cast<double>();
        yy += static_cast<double>(y.head(rows).squaredNorm());
      }
      run_M[static_cast<std::size_t>(run)] = M.selfadjointView<Eigen::Lower>().toDenseMatrix();
      run_c[static_cast<std::size_t>(run)] = c;
      run_yy[static_cast<std::size_t>(run)] = yy;
    }
  });
  for (int run = 0; run < runs && blocks > 0; ++run) {
    eq.M += run_M[static_cast<std::size_t>(run)];
    eq.c += run_c[static_cast<std::size_t>(run)];
    eq.yy += run_yy[static_cast<std::size_t>(run)];
  }
  eq.pixels += total;
}

// Adds μ‖∇k‖² (4-neighbour differences on the kernel grid, k = 0 outside the active offsets) to M.
void addSmoothness(Eigen::MatrixXd& M, const std::vector<cv::Point>& offsets, double mu) {
  if (!(mu > 0)) return;
  std::map<std::pair<int, int>, int> index;
  for (std::size_t j = 0; j < offsets.size(); ++j) index[{offsets[j].x, offsets[j].y}] = static_cast<int>(j);
  for (std::size_t j = 0; j < offsets.size(); ++j) {
    const cv::Point p = offsets[j];
    for (const cv::Point d : {cv::Point(1, 0), cv::Point(-1, 0), cv::Point(0, 1), cv::Point(0, -1)}) {
      M(static_cast<int>(j), static_cast<int>(j)) += mu;
      const auto it = index.find({p.x + d.x, p.y + d.y});
      if (it != index.end()) M(static_cast<int>(j), it->second) -= mu;
    }
  }
}

// FISTA on min kᵀMk − 2cᵀk + λ wᵀk, k ≥ 0 (all entries are active offsets).
Eigen::VectorXd solve(const NormalEquations& eq, Eigen::VectorXd k, double lambda, int iterations, int rounds) {
  const int nn = static_cast<int>(eq.c.size());
  // Largest eigenvalue of M by power iteration (Lipschitz constant of the gradient).
  Eigen::VectorXd v = Eigen::VectorXd::Ones(nn) / std::sqrt(static_cast<double>(nn));
  double eig = 1;
  for (int i = 0; i < 60; ++i) {
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
      const Eigen::VectorXd grad = 2 * (eq.M * z - eq.c) + lam * w;
      Eigen::VectorXd next = (z - grad / L).cwiseMax(0.0);
      const double t_next = 0.5 * (1 + std::sqrt(1 + 4 * t * t));
      z = next + ((t - 1) / t_next) * (next - previous);
      previous = std::move(next);
      t = t_next;
    }
    k = previous;
    const double peak = k.maxCoeff();
    if (!(peak > 0)) break;
    // Re-weighted L1 (Candès, Wakin, Boyd 2008): small entries are pushed harder towards 0.
    for (int j = 0; j < nn; ++j) w(j) = 1.0 / (k(j) / peak + 0.1);
    w /= w.minCoeff();
  }
  return k;
}

cv::Mat padTo(const cv::Mat& K, int n) {
  cv::Mat out = cv::Mat::zeros(n, n, CV_64F);
  const int oy = (n - K.rows) / 2, ox = (n - K.cols) / 2;
  K.copyTo(out(cv::Rect(ox, oy, K.cols, K.rows)));
  return out;
}

cv::Rect scaleRect(const cv::Rect& r, double scale) {
  return cv::Rect(cv::Point(static_cast<int>(std::floor(r.x * scale)), static_cast<int>(std::floor(r.y * scale))),
                  cv::Point(static_cast<int>(std::ceil((r.x + r.width) * scale)),
                            static_cast<int>(std::ceil((r.y + r.height) * scale))));
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
  if (!(smoothness >= 0)) throw InvalidInput("kernel estimation: smoothness must be >= 0");
  if (!(texture_factor >= 0)) throw InvalidInput("kernel estimation: texture_factor must be >= 0");
  if (max_equations < 100) throw InvalidInput("kernel estimation: max_equations must be >= 100");
  if (support_dilation < 1 || support_dilation % 2 == 0) throw InvalidInput("kernel estimation: support_dilation must be odd");
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
                              const cv::Mat& valid_in, const KernelEstimationOptions& options, const cv::Mat& weights_in) {
  options.check();
  if (sharp_in.empty() || blurred_in.empty()) throw InvalidInput("kernel estimation: empty image");
  if (sharp_in.size() != blurred_in.size())
    throw InvalidInput("kernel estimation: the sharp and blurred images differ in size");
  if (!valid_in.empty() && (valid_in.size() != sharp_in.size() || valid_in.type() != CV_8U))
    throw InvalidInput("kernel estimation: bad validity mask");
  if (!weights_in.empty() && (weights_in.size() != sharp_in.size() || weights_in.type() != CV_64F))
    throw InvalidInput("kernel estimation: bad weight map");
  std::vector<cv::Rect> regions = regions_in;
  const cv::Rect frame(0, 0, sharp_in.cols, sharp_in.rows);
  if (regions.empty()) regions.push_back(frame);
  const int n_full = options.kernel_size;

  // Each region is processed in its own crop (the region plus the kernel's reach): only those pixels are ever
  // converted, resampled or scanned, whatever the size of the frame.
  struct Patch {
    cv::Mat s, b, m, w;
    cv::Rect region;  // in crop coordinates, full resolution
  };
  std::vector<Patch> patches;
  for (const auto& rect_in : regions) {
    const cv::Rect rect = rect_in & frame;
    if (rect.width < 8 || rect.height < 8) continue;
    const int margin = n_full + 2;
    const cv::Rect crop = cv::Rect(rect.x - margin, rect.y - margin, rect.width + 2 * margin, rect.height + 2 * margin) & frame;
    Patch p;
    p.s = toUnitGray(sharp_in(crop));
    p.b = toUnitGray(blurred_in(crop));
    p.m = valid_in.empty() ? cv::Mat(crop.size(), CV_8U, cv::Scalar(255)) : valid_in(crop).clone();
    if (!weights_in.empty()) p.w = weights_in(crop);  // read only: a view
    p.region = rect - crop.tl();
    patches.push_back(std::move(p));
  }
  if (patches.empty()) throw InvalidInput("no edges: the kernel regions are empty");
  const int per_patch = std::max(1000, options.max_equations / static_cast<int>(patches.size()));

  int levels = options.pyramid_levels;
  if (levels == 0) {
    levels = 1;
    while (levels < 6 && oddAtLeast(n_full / std::pow(2.0, levels), 3) >= 9) ++levels;
  }
  // The coarsest level must still hold a usable image.
  int min_side = std::numeric_limits<int>::max();
  for (const auto& p : patches) min_side = std::min({min_side, p.s.cols, p.s.rows});
  while (levels > 1 && min_side / std::pow(2.0, levels - 1) < 48) --levels;

  KernelEstimate result;
  cv::Mat previous;  // kernel of the coarser level (normalised)
  for (int level = levels - 1; level >= 0; --level) {
    const double scale = std::pow(0.5, level);
    const int n = level == 0 ? n_full : oddAtLeast(n_full * scale, 3);
    const int r = n / 2;
    if (options.progress)
      options.progress(static_cast<double>(levels - 1 - level) / levels, "kernel level " + std::to_string(level));

    // Active offsets: the whole window at the coarsest level, else the (dilated) support of the upsampled
    // coarser kernel (coarse-to-fine: the finer level only refines where the coarse kernel has mass).
    std::vector<cv::Point> offsets;
    std::vector<double> start;
    if (previous.empty()) {
      for (int dy = -r; dy <= r; ++dy)
        for (int dx = -r; dx <= r; ++dx) {
          offsets.emplace_back(dx, dy);
          start.push_back(0.0);
        }
    } else {
      const int rp = previous.rows / 2;
      const double f = static_cast<double>(n) / previous.rows > 1.5 ? 2.0 : static_cast<double>(n) / previous.rows;
      const cv::Mat A = (cv::Mat_<double>(2, 3) << f, 0, r - f * rp, 0, f, r - f * rp);
      cv::Mat up;
      cv::warpAffine(previous, up, A, cv::Size(n, n), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
      double peak = 0;
      cv::minMaxLoc(up, nullptr, &peak);
      const cv::Mat mask = up > 0.02 * peak;
      cv::Mat dilated;
      cv::dilate(mask, dilated,
                 cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(options.support_dilation, options.support_dilation)));
      const double sum = cv::sum(up)[0];
      for (int y = 0; y < n; ++y)
        for (int x = 0; x < n; ++x)
          if (dilated.at<uchar>(y, x)) {
            offsets.emplace_back(x - r, y - r);
            start.push_back(sum > 0 ? up.at<double>(y, x) / sum * result.gain : 0.0);
          }
    }
    const int ns = static_cast<int>(offsets.size());
    NormalEquations eq;
    eq.M = Eigen::MatrixXd::Zero(ns, ns);
    eq.c = Eigen::VectorXd::Zero(ns);
    for (std::size_t pi = 0; pi < patches.size(); ++pi) {
      const Patch& patch = patches[pi];
      cv::Mat s = patch.s, b = patch.b, m = patch.m, w = patch.w;
      if (level > 0) {
        if (!w.empty()) cv::resize(patch.w, w, cv::Size(), scale, scale, cv::INTER_AREA);
        cv::resize(patch.s, s, cv::Size(), scale, scale, cv::INTER_AREA);
        cv::resize(patch.b, b, s.size(), 0, 0, cv::INTER_AREA);
        cv::resize(patch.m, m, s.size(), 0, 0, cv::INTER_AREA);
        cv::threshold(m, m, 254, 255, cv::THRESH_BINARY);
      }
      cv::Mat region_mask = cv::Mat::zeros(s.size(), CV_8U);
      region_mask(scaleRect(patch.region, scale) & cv::Rect(0, 0, s.cols, s.rows)).setTo(255);
      for (int dir = 0; dir < 2; ++dir) {
        const std::uint64_t salt = 0x9e3779b97f4a7c15ULL * (level + 1) + 0x632be59bd9b4e019ULL * pi + dir;
        const Direction d = selectEquations(s, b, m, w, region_mask, dir, r, options, per_patch, salt);
        accumulate(d, offsets, eq);
      }
    }
    if (eq.pixels < std::max<long long>(50, ns) || !(eq.yy > 1e-12) || !(eq.M.trace() > 1e-12)) {
      // A coarse level sees a pixel only where its whole block is usable, and a kernel window only where all of
      // the window's blocks are: clipped highlights in B and black in a dark sharp shot, interleaved, can leave a
      // coarse level without equations while the finer ones have thousands. Then the estimate starts at the next
      // finer level from the whole window, as it would have with fewer levels (result.levels then starts there);
      // only the finest level must hold.
      if (previous.empty() && level > 0) continue;
      throw InvalidInput("no edges: too little texture (or too many saturated pixels) to estimate the blur kernel");
    }
    NormalEquations regularised = eq;
    addSmoothness(regularised.M, offsets, options.smoothness * eq.M.trace() / ns);
    Eigen::VectorXd k0 = Eigen::Map<const Eigen::VectorXd>(start.data(), ns);
    const Eigen::VectorXd k = solve(regularised, k0, options.lambda, options.iterations, options.reweight_rounds);
    const double gain = k.sum();
    if (!(gain > 0)) throw InvalidInput("kernel estimation failed: the blurred image does not correlate with the sharp one");
    const double residual = (k.dot(eq.M * k) - 2 * eq.c.dot(k) + eq.yy) / eq.yy;
    result.levels.push_back({level, scale, n, residual});
    result.gain = gain;
    result.relative_residual = residual;
    result.equations = eq.pixels;
    previous = cv::Mat::zeros(n, n, CV_64F);
    for (int j = 0; j < ns; ++j) previous.at<double>(offsets[static_cast<std::size_t>(j)].y + r, offsets[static_cast<std::size_t>(j)].x + r) = k(j) / gain;
  }
  cv::Mat K = previous.clone();
  double peak = 0;
  cv::minMaxLoc(K, nullptr, &peak);
  K.setTo(0, K < options.prune_threshold * peak);
  const detail::KernelPieces pieces = detail::keepMassivePieces(K);
  K /= cv::sum(K)[0];
  result.kernel = K;
  result.border_mass = detail::borderMass(K);
  result.hit_size_limit = result.border_mass > options.border_limit;
  result.support = cv::countNonZero(K);
  result.centroid = kernelCentroid(K);
  if (options.progress) options.progress(1.0, "kernel");
  if (result.hit_size_limit && options.throw_on_size_limit)
    throw InvalidInput(detail::kernelSizeLimitMessage(K, pieces));
  return result;
}

KernelEstimate estimateKernel(const cv::Mat& sharp, const cv::Mat& blurred, const KernelEstimationOptions& options) {
  return estimateKernel(sharp, blurred, {}, {}, options, {});
}

double kernelRelativeError(const cv::Mat& estimate, const cv::Mat& truth) {
  const int n = std::max({estimate.rows, estimate.cols, truth.rows, truth.cols}) | 1;
  cv::Mat a = padTo(estimate, n), b = padTo(truth, n);
  return cv::norm(a - b) / std::max(cv::norm(b), 1e-300);
}

double kernelShapeError(const cv::Mat& estimate, const cv::Mat& truth, int max_shift) {
  const int n = (std::max({estimate.rows, estimate.cols, truth.rows, truth.cols}) + 2 * max_shift + 2) | 1;
  const cv::Mat a = padTo(estimate, n), b = padTo(truth, n);
  const double norm_b = std::max(cv::norm(b), 1e-300);
  auto error = [&](double dx, double dy) {
    cv::Mat shifted;
    const cv::Mat A = (cv::Mat_<double>(2, 3) << 1, 0, dx, 0, 1, dy);
    cv::warpAffine(a, shifted, A, a.size(), cv::INTER_CUBIC, cv::BORDER_CONSTANT, cv::Scalar(0));
    return cv::norm(shifted - b) / norm_b;
  };
  // Integer search, then a 1/8-pixel refinement around the best integer shift (a registration residual is
  // rarely a whole pixel; bicubic resampling of the estimate is the price).
  double best = 1e300;
  cv::Point2d at;
  for (int dy = -max_shift; dy <= max_shift; ++dy)
    for (int dx = -max_shift; dx <= max_shift; ++dx) {
      const double e = error(dx, dy);
      if (e < best) {
        best = e;
        at = cv::Point2d(dx, dy);
      }
    }
  const cv::Point2d centre = at;
  for (int iy = -8; iy <= 8; ++iy)
    for (int ix = -8; ix <= 8; ++ix) best = std::min(best, error(centre.x + ix / 8.0, centre.y + iy / 8.0));
  return best;
}

}  // namespace crfcal
