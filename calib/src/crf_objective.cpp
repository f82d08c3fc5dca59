#include "crf_objective.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <numeric>

#include <opencv2/core.hpp>

#include "crf_priors.hpp"
#include "crfcal/blur_model.hpp"

namespace crfcal::crf_fit {
namespace {

double pixelValue(const LevelImage& image, cv::Point p) {
  const double lo = image.lo.at<std::uint16_t>(p);
  const double t = image.frac.empty() ? 0.0 : image.frac.at<float>(p);
  return (lo + t) / (image.levels - 1);
}

// ψ of the piecewise-linear φ given by f on the level grid.
double inverseOf(const std::vector<double>& f, double y) {
  const int n = static_cast<int>(f.size());
  if (y <= f.front()) return 0.0;
  if (y >= f.back()) return 1.0;
  const auto it = std::upper_bound(f.begin(), f.end(), y);
  const int v = static_cast<int>(it - f.begin()) - 1;
  const double d = f[v + 1] - f[v];
  const double t = d > 0 ? (y - f[v]) / d : 0.0;
  return (v + t) / (n - 1);
}

using RowMajor = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct Tap {
  int dy, dx;
  double k;
};

std::vector<Tap> kernelTaps(const cv::Mat& kernel) {
  std::vector<Tap> taps;
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  for (int y = 0; y < kernel.rows; ++y)
    for (int x = 0; x < kernel.cols; ++x)
      if (const double k = kernel.at<double>(y, x); k > 0) taps.push_back({cy - y, cx - x, k});
  return taps;
}

int foldOf(cv::Point p) { return ((p.x / 16) + (p.y / 16)) & 1; }

// H, N and the pixel counts per (fold, bin), accumulated over `stripes` pixel ranges in parallel.
void accumulateSums(const Prepared& prep, const std::vector<Tap>& taps, const std::vector<int>& bin_of, int bins,
                    int stripes, Moments& m) {
  const int L = prep.levels;
  const int npix = static_cast<int>(prep.pixels.size());
  struct Acc {
    std::vector<double> h[2], n[2], c[2];
  };
  std::vector<Acc> acc(stripes);
  const bool sharp_frac = !prep.sharp.frac.empty(), blurred_frac = !prep.blurred.frac.empty();
  auto work = [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s) {
      Acc& a = acc[s];
      for (int f = 0; f < 2; ++f) {
        a.h[f].assign(static_cast<std::size_t>(bins) * L, 0.0);
        a.n[f].assign(static_cast<std::size_t>(bins) * L, 0.0);
        a.c[f].assign(bins, 0.0);
      }
      const int i0 = static_cast<int>(static_cast<long long>(npix) * s / stripes);
      const int i1 = static_cast<int>(static_cast<long long>(npix) * (s + 1) / stripes);
      for (int i = i0; i < i1; ++i) {
        const cv::Point p = prep.pixels[i];
        const int fold = foldOf(p);
        const int b = bin_of[i];
        double* h = a.h[fold].data() + static_cast<std::size_t>(b) * L;
        double* nn = a.n[fold].data() + static_cast<std::size_t>(b) * L;
        a.c[fold][b] += 1;
        for (const Tap& t : taps) {
          const int y = p.y + t.dy, x = p.x + t.dx;
          const int lo = prep.sharp.lo.at<std::uint16_t>(y, x);
          if (sharp_frac) {
            const double fr = prep.sharp.frac.at<float>(y, x);
            if (fr > 0) {
              h[lo] += t.k * (1 - fr);
              h[lo + 1] += t.k * fr;
              continue;
            }
          }
          h[lo] += t.k;
        }
        const int blo = prep.blurred.lo.at<std::uint16_t>(p);
        const double bfr = blurred_frac ? prep.blurred.frac.at<float>(p) : 0.0;
        nn[blo] += 1 - bfr;
        if (bfr > 0) nn[blo + 1] += bfr;
      }
    }
  };
  if (stripes == 1) work(cv::Range(0, 1));
  else cv::parallel_for_(cv::Range(0, stripes), work, stripes);
  m.levels = L;
  m.bins = bins;
  for (int f = 0; f < 2; ++f) {
    m.h[f] = Eigen::MatrixXd::Zero(bins, L);
    m.n[f] = Eigen::MatrixXd::Zero(bins, L);
    m.count[f] = Eigen::VectorXd::Zero(bins);
    for (const Acc& a : acc) {
      m.h[f] += Eigen::Map<const RowMajor>(a.h[f].data(), bins, L);
      m.n[f] += Eigen::Map<const RowMajor>(a.n[f].data(), bins, L);
      m.count[f] += Eigen::Map<const Eigen::VectorXd>(a.c[f].data(), bins);
    }
  }
}

// Squared aggregated masses per (fold, bin): the variance of the bin sum Σ_q c_k(q) g(I_q) under independent
// per-pixel noise of I is Σ_q c_k(q)² Var g(I_q). Pixels grouped by (fold, bin), masses scattered into a
// per-stripe image buffer.
void accumulateSquaredMasses(const Prepared& prep, const std::vector<Tap>& taps, const std::vector<int>& bin_of,
                             int bins, int stripes, Moments& m) {
  const int L = prep.levels;
  const int npix = static_cast<int>(prep.pixels.size());
  const bool sharp_frac = !prep.sharp.frac.empty();
  // Pixels ordered by (key, index), key = (bin, fold): a counting sort (stable, so each group keeps the pixels'
  // order, and every sum below adds in the same order as a comparison sort by (key, index) would).
  std::vector<int> key(npix), first_of_key(2 * bins + 1, 0);
  for (int i = 0; i < npix; ++i) {
    key[i] = bin_of[i] * 2 + foldOf(prep.pixels[i]);
    ++first_of_key[key[i] + 1];
  }
  std::partial_sum(first_of_key.begin(), first_of_key.end(), first_of_key.begin());
  std::vector<int> order(npix), next = first_of_key;
  for (int i = 0; i < npix; ++i) order[next[key[i]]++] = i;
  auto keyOf = [&](int i) { return key[i]; };
  std::vector<int> group_start;
  for (int k = 0; k < 2 * bins; ++k)
    if (first_of_key[k + 1] > first_of_key[k]) group_start.push_back(first_of_key[k]);
  group_start.push_back(npix);
  const int groups = static_cast<int>(group_start.size()) - 1;
  std::vector<Eigen::MatrixXd> qacc(stripes);
  auto qwork = [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s) {
      Eigen::MatrixXd& q = qacc[s];
      q = Eigen::MatrixXd::Zero(2 * bins, L);
      cv::Mat buffer = cv::Mat::zeros(prep.sharp.lo.size(), CV_64F);
      std::vector<cv::Point> touched;
      const int g0 = static_cast<int>(static_cast<long long>(groups) * s / stripes);
      const int g1 = static_cast<int>(static_cast<long long>(groups) * (s + 1) / stripes);
      for (int g = g0; g < g1; ++g) {
        touched.clear();
        const int row = keyOf(order[group_start[g]]);
        for (int j = group_start[g]; j < group_start[g + 1]; ++j) {
          const cv::Point p = prep.pixels[order[j]];
          for (const Tap& t : taps) {
            double& c = buffer.at<double>(p.y + t.dy, p.x + t.dx);
            if (c == 0.0) touched.emplace_back(p.x + t.dx, p.y + t.dy);
            c += t.k;
          }
        }
        for (const cv::Point& qp : touched) {
          double& c = buffer.at<double>(qp);
          const double c2 = c * c;
          c = 0.0;
          const int lo = prep.sharp.lo.at<std::uint16_t>(qp);
          const double fr = sharp_frac ? prep.sharp.frac.at<float>(qp) : 0.0;
          q(row, lo) += c2 * (1 - fr);
          if (fr > 0) q(row, lo + 1) += c2 * fr;
        }
      }
    }
  };
  if (stripes == 1) qwork(cv::Range(0, 1));
  else cv::parallel_for_(cv::Range(0, stripes), qwork, stripes);
  for (int f = 0; f < 2; ++f) m.q[f] = Eigen::MatrixXd::Zero(bins, L);
  for (const auto& q : qacc)
    for (int k = 0; k < bins; ++k)
      for (int f = 0; f < 2; ++f) m.q[f].row(k) += q.row(k * 2 + f);
}

// squared_masses: also the squared aggregated masses (Moments::q), which only the CUE residuals read.
Moments buildMoments(const Prepared& prep, const std::vector<int>& bin_of, int bins, int threads,
                     bool squared_masses, std::size_t* nonzeros) {
  const std::vector<Tap> taps = kernelTaps(prep.kernel);
  const int npix = static_cast<int>(prep.pixels.size());
  const int stripes = std::max(1, std::min(threads, npix / 2000 + 1));
  Moments m;
  accumulateSums(prep, taps, bin_of, bins, stripes, m);
  if (nonzeros) *nonzeros = static_cast<std::size_t>(((m.h[0] + m.h[1]).array() != 0).count());
  if (squared_masses) accumulateSquaredMasses(prep, taps, bin_of, bins, stripes, m);
  return m;
}

// Instruments from B alone: B level bin × bins of B's local min and max over the support (position_bins each).
// Only non-empty bins are kept (compact ids). Returns the bin of every pixel; bin_level_bin: B-level bin per bin.
std::vector<int> instrumentBins(const Prepared& prep, int K, int P, std::vector<int>& bin_level_bin) {
  const LocalRange& brange = prep.blurred_range;
  std::vector<int> bin_of(prep.pixels.size());
  std::vector<int> raw_id(prep.pixels.size());
  for (std::size_t i = 0; i < prep.pixels.size(); ++i) {
    const cv::Point p = prep.pixels[i];
    const double b = prep.blurred_unit.at<double>(p);
    const int kb = std::clamp(static_cast<int>(b * K), 0, K - 1);
    const double lo = brange.min.at<double>(p), hi = brange.max.at<double>(p);
    const int pl = std::clamp(static_cast<int>(lo * P), 0, P - 1);
    const int ph = std::clamp(static_cast<int>(hi * P), 0, P - 1);
    raw_id[i] = (kb * P + pl) * P + ph;
  }
  std::vector<int> compact(static_cast<std::size_t>(K) * P * P, -1);
  bin_level_bin.clear();
  for (std::size_t i = 0; i < raw_id.size(); ++i) {
    int& c = compact[raw_id[i]];
    if (c < 0) {
      c = static_cast<int>(bin_level_bin.size());
      bin_level_bin.push_back(raw_id[i] / (P * P));
    }
    bin_of[i] = c;
  }
  return bin_of;
}

// Levels covered by data (I's kernel masses and B's levels, 0.1 % tails dropped): outside them φ is the model's
// extrapolation, kept smooth by the local-exponent prior (crf_priors.hpp).
std::pair<int, int> coveredLevels(const Moments& moments) {
  const int L = moments.levels;
  const Eigen::VectorXd mass = (moments.h[0] + moments.h[1] + moments.n[0] + moments.n[1]).colwise().sum().transpose();
  const double total = mass.sum(), tail = 1e-3 * total;
  double acc_lo = 0, acc_hi = 0;
  int lo = 0, hi = L - 1;
  while (lo < L - 1 && acc_lo + mass[lo] <= tail) acc_lo += mass[lo++];
  while (hi > 0 && acc_hi + mass[hi] <= tail) acc_hi += mass[hi--];
  return {lo, hi};
}

}  // namespace

SeedObjective::SeedObjective(const Prepared& prepared, const LevelMixture& mix, const NoiseDebias* debias_or_null,
                             double r)
    : prep(&prepared), mixture(&mix), curve(nullptr), debias(debias_or_null), ratio(r) {
  for (const auto& p : prep->pixels) b_value.push_back(pixelValue(prep->blurred, p));
  double wsum = 0;
  for (double w : prep->seed_weight) wsum += w * w;
  weight_sum = wsum;
}

double SeedObjective::energy(const std::vector<double>& x) const {
  std::vector<double> f;
  if (!curve->values(x.data(), f, nullptr)) return 1e6;
  if (!monotone(f)) return 1e5;
  const std::vector<double> g = debias ? debias->apply(f) : f;
  std::vector<double> m(prep->pixels.size());
  mixture->mix(g, m);
  double sum = 0;
  for (std::size_t i = 0; i < m.size(); ++i) {
    const double w = prep->seed_weight[i];
    const double e = inverseOf(f, std::min(1.0, ratio * m[i])) - b_value[i];
    sum += w * w * e * e;
  }
  return sum / weight_sum;
}

double SeedObjective::ratioStep(const std::vector<double>& x) const {
  std::vector<double> f;
  if (!curve->values(x.data(), f, nullptr)) return ratio;
  const std::vector<double> g = debias ? debias->apply(f) : f;
  std::vector<double> m(prep->pixels.size());
  mixture->mix(g, m);
  double num = 0, den = 0;
  const int L = static_cast<int>(f.size());
  for (std::size_t i = 0; i < m.size(); ++i) {
    const double s = std::clamp(b_value[i], 0.0, 1.0) * (L - 1);
    const int lo = std::min(L - 2, static_cast<int>(s));
    const double t = s - lo;
    const double pb = (1 - t) * f[lo] + t * f[lo + 1];
    num += m[i] * pb;
    den += m[i] * m[i];
  }
  return den > 0 ? num / den : ratio;
}

MomentProblem buildMomentProblem(const Prepared& prep, const NoiseOperators& noise, const CrfFitOptions& options,
                                 int threads, CrfFitResult& result) {
  MomentProblem problem;
  problem.level_bins = options.level_bins;
  const std::vector<int> bin_of = instrumentBins(prep, options.level_bins, options.position_bins, problem.bin_level_bin);
  const int bins = static_cast<int>(problem.bin_level_bin.size());
  const auto t_mix = std::chrono::steady_clock::now();
  // The squared masses cost half the sums' time (a scatter per instrument bin) and feed only the CUE ablation.
  const bool cue = options.experimental.variance_correction;
  problem.moments = buildMoments(prep, bin_of, bins, threads, cue, &result.mixture_nonzeros);
  result.timings.mixture_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_mix).count();
  problem.level_operator = noise.levelOperator();
  int nonempty = 0;
  for (int k = 0; k < bins; ++k) nonempty += (problem.moments.count[0][k] + problem.moments.count[1][k]) > 0;
  result.moment_bins = nonempty;
  // Bin weights ω_k = 1: each residual is already divided by the secant slope of φ over the bin (the
  // intensity-domain residual of Eq. 21 to first order, MomentSystem), which makes the bins comparable.
  problem.omega = Eigen::VectorXd::Ones(bins);
  problem.covered_levels = coveredLevels(problem.moments);
  result.covered_levels = problem.covered_levels;
  problem.censored = buildCensoredRows(prep, options);
  return problem;
}

MomentSystem MomentProblem::system(int fold) const {
  const Moments& m = moments;
  Eigen::MatrixXd h, n, q;
  Eigen::VectorXd c;
  if (fold < 0) {
    h = m.h[0] + m.h[1];
    n = m.n[0] + m.n[1];
    // folds are 16×16 tiles: the cross-fold covariance at tile borders is neglected
    if (m.hasSquaredMasses()) q = m.q[0] + m.q[1];
    c = m.count[0] + m.count[1];
  } else {
    h = m.h[fold];
    n = m.n[fold];
    if (m.hasSquaredMasses()) q = m.q[fold];
    c = m.count[fold];
  }
  // keep non-empty bins only
  std::vector<int> rows;
  for (int k = 0; k < m.bins; ++k)
    if (c[k] > 0) rows.push_back(k);
  MomentSystem s;
  s.h.resize(static_cast<int>(rows.size()), m.levels);
  s.n.resize(static_cast<int>(rows.size()), m.levels);
  if (m.hasSquaredMasses()) s.q.resize(static_cast<int>(rows.size()), m.levels);
  for (int i = 0; i < static_cast<int>(rows.size()); ++i) {
    const int k = rows[i];
    const double w = omega[k] / c[k];  // ω_k / n_k on sums
    const double sw = std::sqrt(w);
    s.h.row(i) = sw * h.row(k);
    s.n.row(i) = sw * n.row(k);
    if (m.hasSquaredMasses()) s.q.row(i) = w * q.row(k);
    s.row_scale.push_back(sw);
    s.weight += omega[k];
    const int kb = bin_level_bin[k], L = m.levels;
    const int margin = std::max(1, (L - 1) / (2 * level_bins));
    s.v0.push_back(std::max(0, static_cast<int>(std::floor(double(kb) / level_bins * (L - 1))) - margin));
    s.v1.push_back(std::min(L - 1, static_cast<int>(std::ceil(double(kb + 1) / level_bins * (L - 1))) + margin));
  }
  if (level_operator) s.h = s.h * (*level_operator);  // (Rᵀ H_k)ᵀ = H_kᵀ R
  if (censored.rows() > 0) s.censored = censored.select(fold);
  return s;
}

double momentEnergy(const MomentSystem& sys, const std::vector<double>& f, double r) {
  const int L = sys.levels();
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
  const Eigen::VectorXd raw = r * (sys.h * fv) - sys.n * fv;
  double e = 0;
  for (int i = 0; i < static_cast<int>(raw.size()); ++i) {
    const double slope = (f[sys.v1[i]] - f[sys.v0[i]]) * (L - 1) / double(sys.v1[i] - sys.v0[i]);
    if (!(slope > 1e-9)) return kInf;
    e += raw[i] * raw[i] / (slope * slope);
  }
  return e / std::max(sys.weight, 1e-300);
}

namespace {
std::atomic<std::uint64_t> next_residuals_id{1};

// acc (rows × d, row-major) = r H Jᵀ − N Jᵀ from H and N's non-zeros, jt = Jᵀ (levels × d, row-major). D: d fixed at
// compile time (0: the run-time d).
template <int D>
void sparseRowsTimesJacobian(const Eigen::SparseMatrix<double, Eigen::RowMajor>& h,
                             const Eigen::SparseMatrix<double, Eigen::RowMajor>& n, double r, const double* jt,
                             double* acc, int d_runtime) {
  const int d = D > 0 ? D : d_runtime;
  using Rows = Eigen::SparseMatrix<double, Eigen::RowMajor>;
  for (int i = 0; i < static_cast<int>(h.rows()); ++i) {
    double* out = acc + static_cast<std::ptrdiff_t>(i) * d;
    for (Rows::InnerIterator it(h, i); it; ++it) {
      const double v = r * it.value();
      const double* in = jt + static_cast<std::ptrdiff_t>(it.col()) * d;
      for (int j = 0; j < d; ++j) out[j] += v * in[j];
    }
    for (Rows::InnerIterator it(n, i); it; ++it) {
      const double v = it.value();
      const double* in = jt + static_cast<std::ptrdiff_t>(it.col()) * d;
      for (int j = 0; j < d; ++j) out[j] -= v * in[j];
    }
  }
}

}  // namespace

MomentResiduals::MomentResiduals(const Curve& curve, const MomentSystem& sys, double r0, bool fit_ratio,
                                 bool with_prior)
    : curve_(curve), sys_(sys), r0_(r0), fit_ratio_(fit_ratio), with_prior_(with_prior), id_(next_residuals_id++) {
  if (curve.kind() != Curve::kEmor) {
    // Stored sparse when that saves at least half of the products' multiplications (a sparse product costs about
    // twice a dense one per stored entry).
    const Eigen::Index entries = sys.h.size() + sys.n.size();
    const Eigen::Index nonzeros = (sys.h.array() != 0).count() + (sys.n.array() != 0).count();
    sparse_ = entries > 0 && 4 * nonzeros <= entries;
    if (sparse_) {
      h_sparse_ = sys.h.sparseView(0.0, 0.0);
      n_sparse_ = sys.n.sparseView(0.0, 0.0);
    }
    return;
  }
  const int L = sys.levels(), d = curve.dims();
  const std::vector<double>& basis = curve.emorBasisOnLevels();
  Eigen::Map<const Eigen::VectorXd> mean(basis.data(), L);
  Eigen::Map<const RowMajor> functions(basis.data() + L, d, L);
  h_mean_ = sys.h * mean;
  n_mean_ = sys.n * mean;
  h_basis_ = sys.h * functions.transpose();
  n_basis_ = sys.n * functions.transpose();
}

// Levenberg–Marquardt asks for the Jacobian at the trial point it has just accepted, whose residuals it evaluated
// a moment before: that evaluation's values (φ, H φ, N φ, the slopes, the prior rows) are kept per thread and
// reused when the point is the same to the bit, so the Jacobian call adds only the Jacobian. Same function, same
// arithmetic: the same bits as evaluating again (the products H φ and N φ are most of an evaluation's cost).
bool MomentResiduals::operator()(const Eigen::VectorXd& p, Eigen::VectorXd& res, Eigen::MatrixXd* jac) const {
  thread_local Evaluation last;
  const bool reuse = jac && last.owner == id_ && last.p.size() == p.size() && last.p == p;
  if (!reuse && !evaluate(p, last)) {
    last.owner = 0;
    return false;
  }
  res = last.res;
  if (jac) jacobian(p, last, *jac);
  return true;
}

MomentResiduals::Layout MomentResiduals::layout() const {
  const bool emor = curve_.kind() == Curve::kEmor;
  return {sys_.levels(), curve_.dims(), static_cast<int>(sys_.h.rows()), emor,
          1.0 / std::sqrt(std::max(sys_.weight, 1e-300)), emor ? kGrid - 1 : 0};
}

bool MomentResiduals::evaluate(const Eigen::VectorXd& p, Evaluation& e) const {
  const MomentSystem& sys = sys_;
  const auto [L, d, rows, emor, norm, monotone_rows] = layout();
  const PriorRows priors(sys, fit_ratio_, with_prior_);
  const CensoredResiduals censored(sys.censored, norm);
  const int extra = monotone_rows + priors.count() + censored.count();
  e.owner = 0;
  std::vector<double>& f = e.f;
  if (!curve_.values(p.data(), f, nullptr)) return false;
  if (!priors.defined(f)) return false;
  const double r = fit_ratio_ ? std::exp(p[d]) : r0_;
  e.r = r;
  Eigen::VectorXd nf;
  if (emor) {
    Eigen::Map<const Eigen::VectorXd> c(p.data(), d);
    e.hf = h_mean_ + h_basis_ * c;
    nf = n_mean_ + n_basis_ * c;
  } else if (sparse_) {
    Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
    e.hf = h_sparse_ * fv;
    nf = n_sparse_ * fv;
  } else {
    Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
    e.hf = sys.h * fv;
    nf = sys.n * fv;
  }
  e.slope.resize(rows);
  e.raw = r * e.hf - nf;
  for (int i = 0; i < rows; ++i) {
    e.slope[i] = (f[sys.v1[i]] - f[sys.v0[i]]) * (L - 1) / double(sys.v1[i] - sys.v0[i]);
    if (!(e.slope[i] > 1e-9)) return false;
  }
  Eigen::VectorXd& res = e.res;
  res.resize(rows + extra);
  res.head(rows) = norm * e.raw.cwiseQuotient(e.slope);
  if (emor) {
    curve_.gridValues(p.data(), e.g, nullptr);
    for (int i = 0; i + 1 < kGrid; ++i) res[rows + i] = kPenaltyScale * std::max(0.0, e.g[i] - e.g[i + 1] + 1e-7);
  } else if (!monotone(f)) {
    return false;
  }
  const double log_r = fit_ratio_ ? p[d] : 0.0;
  priors.residuals(f, log_r, res, rows + monotone_rows, e.prior_scale);
  const int censored_offset = rows + monotone_rows + priors.count();
  if (!censored.residuals(f, r, res, censored_offset)) return false;
  e.p = p;
  e.owner = id_;
  return true;
}

void MomentResiduals::jacobian(const Eigen::VectorXd& p, const Evaluation& e, Eigen::MatrixXd& jac) const {
  const MomentSystem& sys = sys_;
  const auto [L, d, rows, emor, norm, monotone_rows] = layout();
  const PriorRows priors(sys, fit_ratio_, with_prior_);
  const CensoredResiduals censored(sys.censored, norm);
  const int extra = monotone_rows + priors.count() + censored.count();
  const std::vector<double>& f = e.f;
  const Eigen::VectorXd &slope = e.slope, &raw = e.raw, &res = e.res;
  const double r = e.r;
  // φ's Jacobian on the levels: EMoR's is its basis (φ is linear in the coefficients), read in place; GGCM's is
  // sampled at p (valid: evaluate() succeeded there).
  std::vector<double> scratch, jf;
  if (!emor) curve_.values(p.data(), scratch, &jf);
  const double* jf_data = emor ? curve_.emorBasisOnLevels().data() + L : jf.data();
  const int np = static_cast<int>(p.size());
  jac.setZero(rows + extra, np);
  Eigen::Map<const RowMajor> jm(jf_data, d, L);
  Eigen::MatrixXd draw;  // ∂(r H φ − N φ)/∂p, rows × d
  if (emor) {
    draw = r * h_basis_ - n_basis_;
  } else if (sparse_) {
    // Row by row over the non-zeros, the Jacobian of φ transposed so that each level's d derivatives are adjacent.
    const RowMajor jt = jm.transpose();  // levels × d
    RowMajor acc = RowMajor::Zero(rows, d);
    // GGCM of the default degree 4 has 5 parameters: with d known to the compiler the row update is unrolled and
    // vectorised (this loop was ~12 % of a phone pair's CPU with a run-time d).
    if (d == 5) sparseRowsTimesJacobian<5>(h_sparse_, n_sparse_, r, jt.data(), acc.data(), 5);
    else sparseRowsTimesJacobian<0>(h_sparse_, n_sparse_, r, jt.data(), acc.data(), d);
    draw = acc;
  } else {
    draw = (r * sys.h - sys.n) * jm.transpose();
  }
  for (int i = 0; i < rows; ++i) {
    const double scale = (L - 1) / double(sys.v1[i] - sys.v0[i]);
    for (int j = 0; j < d; ++j) {
      const double dslope = (jm(j, sys.v1[i]) - jm(j, sys.v0[i])) * scale;
      jac(i, j) = norm * (draw(i, j) / slope[i] - raw[i] * dslope / (slope[i] * slope[i]));
    }
  }
  if (fit_ratio_) jac.col(d).head(rows) = norm * r * e.hf.cwiseQuotient(slope);
  if (emor) {
    const double* jg = curve_.emorBasisOnGrid().data() + kGrid;  // the basis functions on the grid, d × kGrid
    const std::vector<double>& g = e.g;
    for (int i = 0; i + 1 < kGrid; ++i)
      if (g[i] - g[i + 1] + 1e-7 > 0)
        for (int j = 0; j < d; ++j) jac(rows + i, j) = kPenaltyScale * (jg[j * kGrid + i] - jg[j * kGrid + i + 1]);
  }
  priors.jacobian(f, jm, res, rows + monotone_rows, e.prior_scale, d, jac);
  if (censored.count() > 0) censored.jacobian(f, jm, r, fit_ratio_, res, rows + monotone_rows + priors.count(), jac);
}

bool cueResiduals(const MomentSystem& sys, const CueModel& cue, const std::vector<double>& f, double r,
                  Eigen::VectorXd& res) {
  const int L = sys.levels();
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
  const Eigen::VectorXd raw = r * (sys.h * fv) - sys.n * fv;
  const Eigen::VectorXd g = cue.r ? Eigen::VectorXd(*cue.r * fv) : Eigen::VectorXd(fv);
  Eigen::VectorXd var(L), slope2(L);
  const double delta2 = 1.0 / (12.0 * (L - 1) * (L - 1));
  for (int v = 0; v < L; ++v) {
    const int a = std::max(0, v - 1), b = std::min(L - 1, v + 1);
    const double gs = (g[b] - g[a]) * (L - 1) / double(b - a);
    const double fs = (f[b] - f[a]) * (L - 1) / double(b - a);
    var[v] = gs * gs * delta2;
    slope2[v] = fs * fs * delta2;
  }
  if (cue.t) {
    const Eigen::VectorXd m1 = *cue.t * g, m2 = *cue.t * g.cwiseProduct(g);
    var += (m2 - m1.cwiseProduct(m1)).cwiseMax(0.0);
  }
  const Eigen::VectorXd vq = sys.q * var, vb = sys.n * slope2;
  res.resize(raw.size());
  for (int i = 0; i < static_cast<int>(raw.size()); ++i) {
    const double v = r * r * vq[i] + sys.row_scale[i] * vb[i] + 1e-18;
    if (!(v > 0)) return false;
    res[i] = raw[i] / std::sqrt(v);
  }
  return true;
}

}  // namespace crfcal::crf_fit
