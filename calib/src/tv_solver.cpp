#include "tv_solver.hpp"

#include <algorithm>
#include <cmath>
#include <type_traits>
#include <utility>
#include <vector>

#include <opencv2/core/hal/intrin.hpp>

#include "half_spectrum.hpp"
#include "real_fft.hpp"

namespace crfcal::detail {
namespace {

// Everything between the FFTs is fused into a few passes over buffers kept per thread (as cv::Mat expressions each
// operation allocated and faulted in a full-size temporary: 6–11 % more CPU at 12 MP). The FFTs themselves are most
// of the time (docs/RESULTS.md, "Speed at 12 MP").
// The w-step and the ADMM multiplier update (Goldstein & Osher 2009): g = ∇u + b, w = shrink(g, 1/β) (isotropic),
// b ← g − w; the u-step's field is p = w − b (bregman; b starts at 0) or w. ∇ is forwardDifference:
// (Dx u)(p) = u(p + eₓ) − u(p) with wrap-around. Fused with Dᵀp = Dxᵀ px + Dyᵀ py, (Dxᵀ g)(p) = g(p − eₓ) − g(p),
// the adjoint formed in the image domain (two FFTs fewer per u-step than through spectra): one pass over u, b and
// the output, p kept for two rows only (row 0's adjoint needs the last row's py: it is written last).
template <typename T>
class ShrinkAndAdjoint {
 public:
  explicit ShrinkAndAdjoint(int cols) : rows_(5 * static_cast<size_t>(cols)), cols_(cols) {}

  void operator()(const cv::Mat& u, double beta, bool bregman, cv::Mat& bx, cv::Mat& by, cv::Mat& adjoint) {
    const int rows = u.rows, cols = cols_;
    T *px = row(0), *py = row(1), *py_above = row(2), *px_first = row(3), *py_first = row(4);
    for (int y = 0; y < rows; ++y) {
      shrinkRow(u.ptr<T>(y), u.ptr<T>(y + 1 < rows ? y + 1 : 0), beta, bregman, bx.ptr<T>(y), by.ptr<T>(y), px, py);
      if (y == 0) {
        std::copy(px, px + cols, px_first);
        std::copy(py, py + cols, py_first);
      } else {
        adjointRow(px, py, py_above, adjoint.ptr<T>(y));
      }
      std::swap(py, py_above);
    }
    adjointRow(px_first, py_first, py_above, adjoint.ptr<T>(0));  // py_above: the last row's
  }

 private:
  T* row(int i) { return rows_.data() + static_cast<size_t>(i) * cols_; }

  void shrinkRow(const T* here, const T* below, double beta, bool bregman, T* bxr, T* byr, T* pxr, T* pyr) const {
    if (bregman) shrinkRowAs<true>(here, below, static_cast<T>(1.0 / beta), bxr, byr, pxr, pyr, cols_);
    else shrinkRowAs<false>(here, below, static_cast<T>(1.0 / beta), bxr, byr, pxr, pyr, cols_);
  }

  // One row's shrinkage with the multiplier update chosen at compile time: float rows four at a time
  // (shrinkRowSimd), the rest and the wrap-around one by one (std::sqrt without an errno branch: tv_solver.cpp is
  // built with -fno-math-errno; the arithmetic is the same element by element either way).
  template <bool kBregman>
  static void shrinkRowAs(const T* __restrict here, const T* __restrict below, T threshold, T* __restrict bxr,
                          T* __restrict byr, T* __restrict pxr, T* __restrict pyr, int cols) {
    int x = 0;
    if constexpr (std::is_same_v<T, float>) x = shrinkRowSimd<kBregman>(here, below, threshold, bxr, byr, pxr, pyr, cols);
    for (; x + 1 < cols; ++x) shrinkOne<kBregman>(here[x + 1], here[x], below[x], threshold, bxr[x], byr[x], pxr[x], pyr[x]);
    shrinkOne<kBregman>(here[0], here[cols - 1], below[cols - 1], threshold, bxr[cols - 1], byr[cols - 1],
                        pxr[cols - 1], pyr[cols - 1]);  // wrap-around
  }

  // The float rows four at a time with OpenCV's universal intrinsics (GCC does not vectorise the scalar loop for
  // float at the baseline instruction set): the same operations in the same order as shrinkOne, element by element,
  // so the results are identical. Returns the first x left to the scalar loop.
  template <bool kBregman>
  static int shrinkRowSimd(const float* __restrict here, const float* __restrict below, float threshold,
                           float* __restrict bxr, float* __restrict byr, float* __restrict pxr, float* __restrict pyr,
                           int cols) {
    int x = 0;
#if CV_SIMD128
    const cv::v_float32x4 limit = cv::v_setall_f32(threshold), zero = cv::v_setzero_f32(),
                          tiny = cv::v_setall_f32(static_cast<float>(1e-12));
    for (; x + 4 < cols; x += 4) {  // here[x + 4] is the last right neighbour read: x + 4 ≤ cols − 1
      const cv::v_float32x4 centre = cv::v_load(here + x);
      const cv::v_float32x4 gx = (cv::v_load(here + x + 1) - centre) + cv::v_load(bxr + x);
      const cv::v_float32x4 gy = (cv::v_load(below + x) - centre) + cv::v_load(byr + x);
      const cv::v_float32x4 magnitude = cv::v_sqrt(gx * gx + gy * gy);
      const cv::v_float32x4 scale = cv::v_max(magnitude - limit, zero) / cv::v_max(magnitude, tiny);
      const cv::v_float32x4 wx = gx * scale, wy = gy * scale;
      if constexpr (kBregman) {
        const cv::v_float32x4 bx_next = gx - wx, by_next = gy - wy;
        cv::v_store(bxr + x, bx_next);
        cv::v_store(byr + x, by_next);
        cv::v_store(pxr + x, wx - bx_next);
        cv::v_store(pyr + x, wy - by_next);
      } else {
        cv::v_store(pxr + x, wx);
        cv::v_store(pyr + x, wy);
      }
    }
#endif
    return x;
  }

  template <bool kBregman>
  static inline void shrinkOne(T right, T centre, T below, T threshold, T& bx, T& by, T& px, T& py) {
    const T gx = right - centre + bx;
    const T gy = below - centre + by;
    const T magnitude = std::sqrt(gx * gx + gy * gy);
    const T scale = std::max(magnitude - threshold, T(0)) / std::max(magnitude, static_cast<T>(1e-12));
    const T wx = gx * scale, wy = gy * scale;
    if constexpr (kBregman) {
      const T bx_next = gx - wx, by_next = gy - wy;
      bx = bx_next;
      by = by_next;
      px = wx - bx_next;
      py = wy - by_next;
    } else {
      px = wx;
      py = wy;
    }
  }

  void adjointRow(const T* pxr, const T* pyr, const T* above, T* o) const {
    o[0] = (pxr[cols_ - 1] - pxr[0]) + (above[0] - pyr[0]);
    for (int x = 1; x < cols_; ++x) o[x] = (pxr[x - 1] - pxr[x]) + (above[x] - pyr[x]);
  }

  std::vector<T> rows_;  // px, py, py of the row above, px and py of row 0
  int cols_;
};

// ‖next − u‖ / ‖next‖ in one pass.
template <typename T>
double relativeChange(const cv::Mat& next, const cv::Mat& u) {
  // eight independent partial sums (in double, as before), so that the loop vectorises without reassociating a sum;
  // float rows four at a time with OpenCV's universal intrinsics, widened to double
  constexpr int kLanes = 8;
  double difference[kLanes] = {}, norm[kLanes] = {};
  for (int y = 0; y < u.rows; ++y) {
    const T* __restrict n = next.ptr<T>(y);
    const T* __restrict p = u.ptr<T>(y);
    int x = 0;
#if CV_SIMD128_64F
    if constexpr (std::is_same_v<T, float>) {
      cv::v_float64x2 difference_low = cv::v_setzero_f64(), difference_high = cv::v_setzero_f64();
      cv::v_float64x2 norm_low = cv::v_setzero_f64(), norm_high = cv::v_setzero_f64();
      for (; x + 4 <= u.cols; x += 4) {
        const cv::v_float32x4 a = cv::v_load(n + x), b = cv::v_load(p + x);
        const cv::v_float64x2 a_low = cv::v_cvt_f64(a), a_high = cv::v_cvt_f64_high(a);
        const cv::v_float64x2 d_low = a_low - cv::v_cvt_f64(b), d_high = a_high - cv::v_cvt_f64_high(b);
        difference_low += d_low * d_low;
        difference_high += d_high * d_high;
        norm_low += a_low * a_low;
        norm_high += a_high * a_high;
      }
      difference[1] += cv::v_reduce_sum(difference_low + difference_high);
      norm[1] += cv::v_reduce_sum(norm_low + norm_high);
    }
#endif
    for (; x + kLanes <= u.cols; x += kLanes)
      for (int lane = 0; lane < kLanes; ++lane) {
        const double d = double(n[x + lane]) - double(p[x + lane]);
        difference[lane] += d * d;
        norm[lane] += double(n[x + lane]) * double(n[x + lane]);
      }
    for (; x < u.cols; ++x) {
      const double d = double(n[x]) - double(p[x]);
      difference[0] += d * d;
      norm[0] += double(n[x]) * double(n[x]);
    }
  }
  double total_difference = 0, total_norm = 0;
  for (int lane = 0; lane < kLanes; ++lane) {
    total_difference += difference[lane];
    total_norm += norm[lane];
  }
  return std::sqrt(total_difference) / std::max(std::sqrt(total_norm), 1e-12);
}

// The runs of pixels left out of the data term (mask 0): the MM fill rewrites only these.
struct MaskedOutRun {
  int y, x0, x1;  // [x0, x1) of row y
};

std::vector<MaskedOutRun> maskedOutRuns(const cv::Mat& mask) {
  std::vector<MaskedOutRun> runs;
  for (int y = 0; y < mask.rows; ++y) {
    const uchar* m = mask.ptr<uchar>(y);
    for (int x = 0; x < mask.cols;) {
      if (m[x]) {
        ++x;
        continue;
      }
      const int x0 = x;
      while (x < mask.cols && !m[x]) ++x;
      runs.push_back({y, x0, x});
    }
  }
  return runs;
}

// The TV solver's planes, one set per thread, kept between the (channel, tile) jobs the thread runs: fresh planes per
// job were faulted in every time (page faults and page clearing were ~8 % of a 12 MP run's CPU). cv::Mat::create
// reuses a plane of the same size and type.
struct TvWorkspace {
  cv::Mat u, next, fill, adjoint, bx, by;
  cv::Mat u_spectrum, f_spectrum, fill_spectrum, adjoint_spectrum, prediction, fixed_data;
};

TvWorkspace& tvWorkspace() {
  thread_local TvWorkspace workspace;
  return workspace;
}

}  // namespace

// FTVd (Wang et al. 2008, Alg. 1 with continuation) with the masked data term minimised by MM (see header).
// Spectra in FFTW's half layout (real_fft.hpp), R and G scaled by the inverse DFT's 1 / N.
// Per u-step four real FFTs: K ⊗ u and F(ḟ) for the MM fill ḟ = M f + (1 − M) K ⊗ u, F(Dᵀw) (Dᵀw formed in the
// image domain), and u. (Refreshing ḟ only once per β saves two but measurably slows the fill of the padding and
// of saturated regions: −1 dB on the tests' images.) The u-step
//   (DᵀD + λ/β KᵀK) u = Dᵀw + λ/β Kᵀḟ
// is diagonal in Fourier: Û = F(Dᵀw) · R + F(ḟ) · G with R = 1 / (|D̂x|² + |D̂y|² + λ/β |K̂|²) and
// G = λ/β · conj(K̂) · R, both fixed per β (the first β's shared by every tile of the canvas size). Between the FFTs
// three passes: shrinkage with Dᵀ, the spectral u-step with the next prediction's spectrum Û · K̂, and the change of
// u; ḟ keeps f where M = 1, and only its masked-out runs are rewritten.
template <typename T>
cv::Mat totalVariationSolve(const cv::Mat& f, const cv::Mat& mask, const CanvasOperators& canvas,
                            const DeconvolutionOptions& options, int* iterations) {
  const cv::Size size = f.size();
  const int depth = f.depth();
  const std::vector<MaskedOutRun> runs = maskedOutRuns(mask);
  const bool masked = !runs.empty();

  TvWorkspace& workspace = tvWorkspace();
  cv::Mat &u = workspace.u, &next = workspace.next, &fill = workspace.fill, &adjoint = workspace.adjoint;
  cv::Mat &bx = workspace.bx, &by = workspace.by;  // scaled ADMM multipliers of w = ∇u
  cv::Mat &u_spectrum = workspace.u_spectrum, &f_spectrum = workspace.f_spectrum;
  cv::Mat &fill_spectrum = workspace.fill_spectrum, &adjoint_spectrum = workspace.adjoint_spectrum;
  cv::Mat &prediction = workspace.prediction, &fixed_data = workspace.fixed_data;
  cv::Mat reciprocal, data_gain;  // the canvas's at the first β (shared, read only), fresh at the others
  f.copyTo(u);
  f.copyTo(fill);
  next.create(size, depth);
  adjoint.create(size, depth);
  bx.create(size, depth);
  bx.setTo(0);
  by.create(size, depth);
  by.setTo(0);
  ShrinkAndAdjoint<T> shrink_and_adjoint(size.width);
  fft::forwardHalf(u, u_spectrum);
  if (masked) {  // K ⊗ u's spectrum, with the inverse's 1 / N
    cv::mulSpectrums(u_spectrum, canvas.kernel_half, prediction, 0);
    prediction *= 1.0 / static_cast<double>(size.area());
  } else {
    u_spectrum.copyTo(f_spectrum);
  }
  int steps = 0;
  for (double beta = options.beta_start; beta <= options.beta_max * (1 + 1e-12); beta *= options.beta_factor) {
    if (beta == options.beta_start) {
      reciprocal = canvas.first_reciprocal;
      data_gain = canvas.first_data_gain;
    } else {  // fresh buffers: the first β's are the canvas's, shared with other tiles
      reciprocal.release();
      data_gain.release();
      canvas.stepOperators(beta, options.lambda, reciprocal, data_gain);
    }
    if (!masked) cv::mulSpectrums(f_spectrum, data_gain, fixed_data, 0);  // Kᵀf: the same at every step
    if (beta > options.beta_start) {  // the scaled multiplier b = y / β follows β
      bx /= options.beta_factor;
      by /= options.beta_factor;
    }
    for (int inner = 0; inner < options.inner_iterations; ++inner) {
      if (masked) {  // MM: masked-out data replaced by the current prediction K ⊗ u (the adjoint's buffer, free here)
        fft::inverseHalf(prediction, size.width, adjoint);  // overwrites the prediction: the u-step forms it anew
        for (const MaskedOutRun& run : runs)
          std::copy(adjoint.ptr<T>(run.y) + run.x0, adjoint.ptr<T>(run.y) + run.x1, fill.ptr<T>(run.y) + run.x0);
        fft::forwardHalf(fill, fill_spectrum);
      }
      shrink_and_adjoint(u, beta, options.bregman, bx, by, adjoint);
      fft::forwardHalf(adjoint, adjoint_spectrum);
      if (masked)
        half::uStepSpectrum<T>(adjoint_spectrum, reciprocal, fill_spectrum, data_gain, canvas.kernel_half,
                               u_spectrum, prediction);
      else
        half::uStepSpectrum<T>(adjoint_spectrum, reciprocal, fixed_data, u_spectrum);
      fft::inverseHalf(u_spectrum, size.width, next);  // overwrites Û: not needed after this
      const double change = relativeChange<T>(next, u);
      std::swap(u, next);
      ++steps;
      if (change < options.tolerance) break;
    }
  }
  if (iterations) *iterations = steps;
  return u;
}


template cv::Mat totalVariationSolve<float>(const cv::Mat&, const cv::Mat&, const CanvasOperators&,
                                            const DeconvolutionOptions&, int*);
template cv::Mat totalVariationSolve<double>(const cv::Mat&, const cv::Mat&, const CanvasOperators&,
                                             const DeconvolutionOptions&, int*);

}  // namespace crfcal::detail
