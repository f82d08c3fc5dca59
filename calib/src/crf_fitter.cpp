#include "crfcal/crf_fitter.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <numeric>
#include <span>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/QR>
#include <nlopt.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_debias.hpp"
#include "crfcal/noise_estimation.hpp"

namespace crfcal {

const char* toString(CrfModelChoice value) {
  switch (value) {
    case CrfModelChoice::ggcm: return "ggcm";
    case CrfModelChoice::emor: return "emor";
    case CrfModelChoice::automatic: return "auto";
  }
  return "?";
}
const char* toString(CrfObjective value) {
  switch (value) {
    case CrfObjective::seed_intensity: return "seed_intensity";
    case CrfObjective::moments: return "moments";
  }
  return "?";
}
const char* toString(CrfOptimizer value) {
  switch (value) {
    case CrfOptimizer::nelder_mead: return "nelder_mead";
    case CrfOptimizer::levenberg_marquardt: return "levenberg_marquardt";
  }
  return "?";
}
const char* toString(NoiseHandling value) {
  switch (value) {
    case NoiseHandling::none: return "none";
    case NoiseHandling::debias: return "debias";
    case NoiseHandling::denoise: return "denoise";
    case NoiseHandling::jensen: return "jensen";
  }
  return "?";
}

NoiseHandling noiseHandlingFromString(const std::string& name) {
  for (NoiseHandling value : {NoiseHandling::none, NoiseHandling::debias, NoiseHandling::denoise, NoiseHandling::jensen})
    if (name == toString(value)) return value;
  throw InvalidInput("unknown noise handling '" + name + "' (none, jensen, debias, denoise)");
}

CrfFitOptions CrfFitOptions::seed() {
  CrfFitOptions o;
  o.model = CrfModelChoice::ggcm;
  o.objective = CrfObjective::seed_intensity;
  o.optimizer = CrfOptimizer::nelder_mead;
  o.noise = NoiseHandling::none;
  o.multi_starts = 1;
  o.max_pixels = 6000;  // deterministic subsample keeps one fit near a second (Nelder–Mead needs ~10³ evaluations)
  o.max_evaluations = 600;
  o.ratio_rounds = 3;
  return o;
}

void CrfFitOptions::check() const {
  if (ggcm_degree < 0 || ggcm_degree > 10) throw InvalidInput("fit options: ggcm_degree must be in [0, 10]");
  if (emor_terms < 1 || emor_terms > emor::kMaxTerms) throw InvalidInput("fit options: emor_terms must be in [1, 25]");
  if (!(tau1 >= 0) || !(tau2 >= 0)) throw InvalidInput("fit options: tau1 and tau2 must be non-negative");
  if (!(initial_ratio > 0) || !std::isfinite(initial_ratio)) throw InvalidInput("fit options: initial_ratio must be positive");
  if (multi_starts < 1) throw InvalidInput("fit options: multi_starts must be at least 1");
  if (!(noise_sigma < 1)) throw InvalidInput("fit options: noise_sigma must be < 1");
  for (double s : noise_sigma_per_level)
    if (!(s >= 0 && s < 1)) throw InvalidInput("fit options: noise_sigma_per_level entries must be in [0, 1)");
  if (!(debias_regularization > 0)) throw InvalidInput("fit options: debias_regularization must be positive");
  if (!(edge_threshold >= 0)) throw InvalidInput("fit options: edge_threshold must be non-negative");
  if (level_bins < 4 || level_bins > 1024) throw InvalidInput("fit options: level_bins must be in [4, 1024]");
  if (position_bins < 1 || position_bins > 16) throw InvalidInput("fit options: position_bins must be in [1, 16]");
  if (!(exponent_smoothness >= 0)) throw InvalidInput("fit options: exponent_smoothness must be >= 0");
  if (!(shoulder_prior >= 0)) throw InvalidInput("fit options: shoulder_prior must be >= 0");
  if (!(prior_energy_factor >= 1)) throw InvalidInput("fit options: prior_energy_factor must be >= 1");
  if (!(ratio_prior_sigma >= 0) || !std::isfinite(ratio_prior_sigma))
    throw InvalidInput("fit options: ratio_prior_sigma must be >= 0");
  if (!(min_local_exponent >= 0 && min_local_exponent < 1))
    throw InvalidInput("fit options: min_local_exponent must be in [0, 1)");
  if (!(saturation_high > saturation_low)) throw InvalidInput("fit options: saturation_high must exceed saturation_low");
  if (ratio_rounds < 1) throw InvalidInput("fit options: ratio_rounds must be >= 1");
  if (max_evaluations < 10) throw InvalidInput("fit options: max_evaluations must be at least 10");
  if (min_pixels < 1) throw InvalidInput("fit options: min_pixels must be positive");
  if (max_pixels < 0) throw InvalidInput("fit options: max_pixels must be >= 0");
  if (threads < 0) throw InvalidInput("fit options: threads must be >= 0");
}

std::string CrfFitResult::summary() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(6);
  s << "phi: " << describe(model) << " (" << chosen << ", " << choice_reason << ")\n";
  s << "ratio r = " << ratio << " (initial " << initial_ratio << "), energy " << energy << ", iterations "
    << iterations << ", evaluations " << evaluations << ", ambiguity rise " << ambiguity_rise << "\n";
  for (const auto& c : candidates)
    s << "  candidate " << c.kind << ": energy " << c.energy << ", criterion " << c.criterion
      << (c.valid ? "" : " (invalid)") << ", r " << c.ratio << "\n";
  s << "pixels: " << pixels.used << " used of " << pixels.total << " (border " << pixels.border << ", saturated "
    << pixels.saturated << ", low weight " << pixels.low_weight << ", subsampled " << pixels.subsampled << ")\n";
  s.precision(4);
  s << "noise sigma of I: " << noise_sigma << (noise_sigma_estimated ? " (estimated)" : " (given)") << "; "
    << toString(objective) << ", " << toString(optimizer) << ", " << levels << " levels, " << moment_bins
    << " moment bins, " << mixture_nonzeros << " mixture non-zeros\n";
  s << "time: prepare " << timings.prepare_s << " s, mixtures " << timings.mixture_s << " s, optimise "
    << timings.optimise_s << " s, total " << timings.total_s << " s";
  return s.str();
}

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

constexpr int kGrid = 1024;  // validity grid (the EMoR nodes)
constexpr double kInf = std::numeric_limits<double>::infinity();

bool isValid(const ResponseModel& model) { return static_cast<bool>(checkValidity(model, 4096, 1e-6)); }

bool monotone(const std::vector<double>& f) {
  for (std::size_t i = 1; i < f.size(); ++i)
    if (f[i] < f[i - 1]) return false;
  return true;
}

// ---------------------------------------------------------------------------------------------------------
// Curve parameterisations: values on a grid (+ Jacobian).
class Curve {
 public:
  enum Kind { kGgcm, kEmor };
  Curve(Kind kind, int levels, int size) : kind_(kind), levels_(levels), dims_(kind == kGgcm ? size + 1 : size) {
    if (kind_ == kEmor) {
      basis_levels_.assign(static_cast<std::size_t>(dims_ + 1) * levels_, 0.0);
      basis_grid_.assign(static_cast<std::size_t>(dims_ + 1) * kGrid, 0.0);
      for (int k = 0; k <= dims_; ++k) {
        auto table = k == 0 ? emor::inverseMean() : emor::inverseBasis(k);
        for (int i = 0; i < kGrid; ++i) basis_grid_[k * kGrid + i] = table[i];
        for (int v = 0; v < levels_; ++v) {
          const double s = double(v) / (levels_ - 1) * (kGrid - 1);
          const int i = std::min(kGrid - 2, static_cast<int>(s));
          const double t = s - i;
          basis_levels_[k * levels_ + v] = (1 - t) * table[i] + t * table[i + 1];
        }
      }
    }
  }
  Kind kind() const { return kind_; }
  int dims() const { return dims_; }
  int levels() const { return levels_; }
  const char* name() const { return kind_ == kGgcm ? "ggcm" : "emor"; }

  // f on the levels (jac: dims × levels, row-major). False when the parameters are outside the model's domain.
  bool values(const double* x, std::vector<double>& f, std::vector<double>* jac) const {
    return sample(x, levels_, kind_ == kEmor ? &basis_levels_ : nullptr, f, jac);
  }
  bool gridValues(const double* x, std::vector<double>& f, std::vector<double>* jac) const {
    return sample(x, kGrid, kind_ == kEmor ? &basis_grid_ : nullptr, f, jac);
  }
  ResponseModel model(const std::vector<double>& x) const {
    if (kind_ == kGgcm) return GgcmModel{x};
    return EmorModel{x};
  }

 private:
  bool sample(const double* x, int n, const std::vector<double>* basis, std::vector<double>& f,
              std::vector<double>* jac) const {
    f.assign(n, 0.0);
    if (jac) jac->assign(static_cast<std::size_t>(dims_) * n, 0.0);
    if (kind_ == kGgcm) {
      std::span<const double> alpha(x, dims_);
      std::vector<double> g(dims_);
      for (int v = 0; v < n; ++v) {
        const double xv = double(v) / (n - 1);
        if (!(ggcm::polynomial(alpha, xv) > 1e-3)) return false;
        f[v] = ggcm::evaluate(alpha, xv);
        if (!std::isfinite(f[v])) return false;
        if (jac) {
          ggcm::gradient(alpha, xv, g);
          for (int j = 0; j < dims_; ++j) (*jac)[j * n + v] = g[j];
        }
      }
      return true;
    }
    const std::vector<double>& b = *basis;
    for (int v = 0; v < n; ++v) f[v] = b[v];
    for (int k = 1; k <= dims_; ++k) {
      const double c = x[k - 1];
      for (int v = 0; v < n; ++v) f[v] += c * b[k * n + v];
      if (jac)
        for (int v = 0; v < n; ++v) (*jac)[(k - 1) * n + v] = b[k * n + v];
    }
    return true;
  }

  Kind kind_;
  int levels_;
  int dims_;
  std::vector<double> basis_levels_, basis_grid_;
};

// ---------------------------------------------------------------------------------------------------------
// Nelder–Mead through NLopt, keeping the best point seen.
struct Minimum {
  std::vector<double> x;
  double value = kInf;
  int evaluations = 0;
};

Minimum nelderMead(const std::vector<double>& x0, const std::function<double(const std::vector<double>&)>& objective,
                   int max_evaluations, double step, double ftol = 1e-10) {
  const unsigned n = static_cast<unsigned>(x0.size());
  nlopt::opt opt(nlopt::LN_NELDERMEAD, n);
  struct State {
    const std::function<double(const std::vector<double>&)>* f;
    Minimum best;
  } state{&objective, {}};
  opt.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>&, void* data) -> double {
        auto* s = static_cast<State*>(data);
        ++s->best.evaluations;
        const double value = (*s->f)(x);
        if (value < s->best.value) {
          s->best.value = value;
          s->best.x = x;
        }
        return value;
      },
      &state);
  opt.set_maxeval(max_evaluations);
  opt.set_ftol_rel(ftol);
  opt.set_xtol_rel(1e-9);
  opt.set_initial_step(std::vector<double>(n, step));
  std::vector<double> x = x0;
  double value = 0;
  try {
    opt.optimize(x, value);
  } catch (const std::exception&) {
    // roundoff_limited / forced stop: keep the best point seen
  }
  if (state.best.x.empty()) {
    state.best.x = x0;
    state.best.value = objective(x0);
  }
  return state.best;
}

// Levenberg–Marquardt on a residual vector. `residuals(x, r, jac)` returns false outside the domain.
using ResidualFn = std::function<bool(const Eigen::VectorXd& x, Eigen::VectorXd& r, Eigen::MatrixXd* jac)>;
struct LmResult {
  Eigen::VectorXd x;
  double cost = kInf;
  int iterations = 0;
  int evaluations = 0;
};
LmResult levenbergMarquardt(const Eigen::VectorXd& x0, const ResidualFn& residuals, int max_iterations) {
  LmResult out;
  out.x = x0;
  Eigen::VectorXd r;
  Eigen::MatrixXd jac;
  ++out.evaluations;
  if (!residuals(out.x, r, &jac)) return out;
  out.cost = r.squaredNorm();
  double lambda = 1e-3;
  const int n = static_cast<int>(x0.size());
  for (int it = 0; it < max_iterations; ++it) {
    ++out.iterations;
    const Eigen::MatrixXd jtj = jac.transpose() * jac;
    const Eigen::VectorXd g = jac.transpose() * r;
    bool improved = false;
    for (int tries = 0; tries < 12; ++tries) {
      Eigen::MatrixXd a = jtj;
      for (int i = 0; i < n; ++i) a(i, i) += lambda * std::max(jtj(i, i), 1e-12);
      const Eigen::VectorXd step = a.ldlt().solve(-g);
      if (!step.allFinite()) {
        lambda *= 10;
        continue;
      }
      const Eigen::VectorXd xn = out.x + step;
      Eigen::VectorXd rn;
      ++out.evaluations;
      if (residuals(xn, rn, nullptr)) {
        const double cn = rn.squaredNorm();
        if (cn < out.cost) {
          const double gain = (out.cost - cn) / std::max(out.cost, 1e-300);
          out.x = xn;
          out.cost = cn;
          lambda = std::max(lambda / 5, 1e-9);
          improved = true;
          ++out.evaluations;
          residuals(out.x, r, &jac);
          if (gain < 1e-12 || step.norm() < 1e-12 * (1 + out.x.norm())) return out;
          break;
        }
      }
      lambda *= 8;
    }
    if (!improved) break;
  }
  return out;
}

// ---------------------------------------------------------------------------------------------------------
struct Prepared {
  int levels = 256;
  cv::Mat kernel;                  // normalised CV_64F
  cv::Mat sharp_unit, blurred_unit;
  LevelImage sharp, blurred;
  std::vector<cv::Point> pixels;
  std::vector<double> seed_weight;  // W_p (seed objective)
};

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


// ---------------------------------------------------------------------------------------------------------
// Moment sums: per fold (16×16 checkerboard tiles) and instrument bin, the kernel-mass histogram of I's levels
// (H), the level histogram of B (N) and the pixel count.
struct Moments {
  int levels = 256;
  int bins = 0;
  Eigen::MatrixXd h[2], n[2];  // bins × levels
  Eigen::MatrixXd q[2];        // squared aggregated masses: Σ_q [I_q = v] c_k(q)², c_k(q) = Σ_{p∈k} K(p − q)
  Eigen::VectorXd count[2];
  std::vector<double> bin_level;  // B level (in [0,1]) at the centre of each bin
};

Moments buildMoments(const Prepared& prep, const std::vector<int>& bin_of, int bins, int threads,
                     std::size_t* nonzeros) {
  const int L = prep.levels;
  struct Tap { int dy, dx; double k; };
  std::vector<Tap> taps;
  const cv::Mat& kernel = prep.kernel;
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  for (int y = 0; y < kernel.rows; ++y)
    for (int x = 0; x < kernel.cols; ++x)
      if (const double k = kernel.at<double>(y, x); k > 0) taps.push_back({cy - y, cx - x, k});
  const int npix = static_cast<int>(prep.pixels.size());
  const int stripes = std::max(1, std::min(threads, npix / 2000 + 1));
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
        const int fold = ((p.x / 16) + (p.y / 16)) & 1;
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
  Moments m;
  m.levels = L;
  m.bins = bins;
  for (int f = 0; f < 2; ++f) {
    m.h[f] = Eigen::MatrixXd::Zero(bins, L);
    m.n[f] = Eigen::MatrixXd::Zero(bins, L);
    m.count[f] = Eigen::VectorXd::Zero(bins);
    for (const Acc& a : acc) {
      m.h[f] += Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(a.h[f].data(), bins, L);
      m.n[f] += Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(a.n[f].data(), bins, L);
      m.count[f] += Eigen::Map<const Eigen::VectorXd>(a.c[f].data(), bins);
    }
  }
  if (nonzeros) *nonzeros = static_cast<std::size_t>(((m.h[0] + m.h[1]).array() != 0).count());
  // Squared aggregated masses per (fold, bin): the variance of the bin sum Σ_q c_k(q) g(I_q) under independent
  // per-pixel noise of I is Σ_q c_k(q)² Var g(I_q). Pixels grouped by (fold, bin), masses scattered into a
  // per-stripe image buffer.
  std::vector<int> order(npix);
  std::iota(order.begin(), order.end(), 0);
  auto foldOf = [&](int i) { return ((prep.pixels[i].x / 16) + (prep.pixels[i].y / 16)) & 1; };
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    const int ka = bin_of[a] * 2 + foldOf(a), kb = bin_of[b] * 2 + foldOf(b);
    return ka != kb ? ka < kb : a < b;
  });
  std::vector<int> group_start{0};
  for (int j = 1; j < npix; ++j)
    if (bin_of[order[j]] * 2 + foldOf(order[j]) != bin_of[order[j - 1]] * 2 + foldOf(order[j - 1])) group_start.push_back(j);
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
        const int first = order[group_start[g]];
        const int row = bin_of[first] * 2 + foldOf(first);
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
  return m;
}

// The weighted rows of one data selection: residual_k = √ω_k (r Ĥ_k − N_k) · φ.
// The residual is divided by the secant slope of the current φ over the bin's B levels [v0, v1] (first-order
// intensity-domain residual, Eq. 21), which also removes the φ → 0 / r → 0 degeneracy of irradiance residuals.
struct MomentSystem {
  Eigen::MatrixXd h, n;  // rows already scaled by √ω
  Eigen::MatrixXd q;     // squared masses, scaled by ω (variance of the row's noise: r² q · Var g)
  std::vector<double> row_scale;  // √(ω/n) of each row
  std::vector<int> v0, v1;
  double weight = 0;     // Σ ω (normalisation of the energy)
  // Extrapolation prior (CrfFitOptions::exponent_smoothness): rows √λ (g_{bc} − g_{ab}) for node triples (a, b, c)
  // outside the covered levels, g_{ab} = (log φ_b − log φ_a) / (log x_b − log x_a) the local exponent.
  std::vector<std::array<int, 3>> exponent_triples;
  double exponent_weight = 0;
  std::vector<char> exponent_upper;  // triple of the chain above the covered levels
  double shoulder_weight = 0;        // upper triples: weight of the shoulder prior
  // upper triples: the reference's change of local exponent (g_{bc} − g_{ab} of the EMoR mean g0) that φ's change
  // is held to; empty: the one-sided prior (a rise is free, a fall costs shoulder_weight)
  std::vector<double> shoulder_reference;
  // Lower bound (CrfFitOptions::min_local_exponent): rows kPenaltyScale · max(0, ε − g_ab) for consecutive nodes.
  std::vector<std::array<int, 2>> exponent_pairs;
  double min_exponent = 0;
  // Exposure-ratio prior (CrfFitOptions::ratio_prior_sigma): one row scale · (log r − log r_EXIF) when r is fitted.
  double ratio_prior_scale = 0;
  double ratio_prior_log_centre = 0;
  int levels() const { return static_cast<int>(h.cols()); }
};

// A curve sampled at x = i/(n−1) (n ≥ 2), linearly interpolated onto the L-level grid x = v/(L−1).
std::vector<double> onLevelGrid(std::span<const double> table, int L) {
  std::vector<double> f(L);
  const int n = static_cast<int>(table.size());
  for (int v = 0; v < L; ++v) {
    const double x = double(v) / (L - 1) * (n - 1);
    const int i = std::min(static_cast<int>(x), n - 2);
    f[v] = table[i] + (x - i) * (table[i + 1] - table[i]);
  }
  return f;
}

// Nodes of the local-exponent terms: levels j·(L−1)/64, j = 1..64 (x = 0 has no logarithm).
std::vector<int> exponentNodes(int L) {
  std::vector<int> nodes;
  for (int j = 1; j <= 64; ++j) nodes.push_back(static_cast<int>(std::lround(j * (L - 1) / 64.0)));
  return nodes;
}

// Node triples of the extrapolation prior: the chains from the first node up to the lowest covered level and from
// the highest covered level up to 1 (one node inside the data links each chain to the exponent the data show).
// A triple belongs to a chain when an outer node lies outside the covered range — unless its middle node is inside
// and that outer node less than one node step outside (such a triple is data, not extrapolation).
std::vector<std::array<int, 3>> exponentTriples(int L, int covered_lo, int covered_hi) {
  const double step = (L - 1) / 64.0;
  const std::vector<int> nodes = exponentNodes(L);
  std::vector<std::array<int, 3>> triples;
  for (std::size_t j = 0; j + 2 < nodes.size(); ++j) {
    const int a = nodes[j], b = nodes[j + 1], c = nodes[j + 2];
    const bool outside = a < covered_lo || c > covered_hi;
    const bool barely = b > covered_lo && b < covered_hi && a >= covered_lo - step && c <= covered_hi + step;
    if (outside && !barely) triples.push_back({a, b, c});
  }
  return triples;
}

// Consecutive node pairs for the local-exponent lower bound.
std::vector<std::array<int, 2>> exponentPairs(int L) {
  const std::vector<int> nodes = exponentNodes(L);
  std::vector<std::array<int, 2>> pairs;
  for (std::size_t j = 0; j + 1 < nodes.size(); ++j) pairs.push_back({nodes[j], nodes[j + 1]});
  return pairs;
}

// fold: 0 or 1 for one half, -1 for both. omega: per-bin weight (applied to sums).
MomentSystem makeSystem(const Moments& m, const Eigen::MatrixXd* debias_t, int fold, const Eigen::VectorXd& omega,
                        int level_bins, const std::vector<int>& level_bin_of) {
  Eigen::MatrixXd h, n, q;
  Eigen::VectorXd c;
  if (fold < 0) {
    h = m.h[0] + m.h[1];
    n = m.n[0] + m.n[1];
    q = m.q[0] + m.q[1];  // folds are 16×16 tiles: the cross-fold covariance at tile borders is neglected
    c = m.count[0] + m.count[1];
  } else {
    h = m.h[fold];
    n = m.n[fold];
    q = m.q[fold];
    c = m.count[fold];
  }
  // keep non-empty bins only
  std::vector<int> rows;
  for (int k = 0; k < m.bins; ++k)
    if (c[k] > 0) rows.push_back(k);
  MomentSystem s;
  s.h.resize(static_cast<int>(rows.size()), m.levels);
  s.n.resize(static_cast<int>(rows.size()), m.levels);
  s.q.resize(static_cast<int>(rows.size()), m.levels);
  for (int i = 0; i < static_cast<int>(rows.size()); ++i) {
    const int k = rows[i];
    const double w = omega[k] / c[k];  // ω_k / n_k on sums
    const double sw = std::sqrt(w);
    s.h.row(i) = sw * h.row(k);
    s.n.row(i) = sw * n.row(k);
    s.q.row(i) = w * q.row(k);
    s.row_scale.push_back(sw);
    s.weight += omega[k];
    const int kb = level_bin_of[k], L = m.levels;
    const int margin = std::max(1, (L - 1) / (2 * level_bins));
    s.v0.push_back(std::max(0, static_cast<int>(std::floor(double(kb) / level_bins * (L - 1))) - margin));
    s.v1.push_back(std::min(L - 1, static_cast<int>(std::ceil(double(kb + 1) / level_bins * (L - 1))) + margin));
  }
  if (debias_t) s.h = s.h * (*debias_t);  // (Rᵀ H_k)ᵀ = H_kᵀ R
  return s;
}

struct ModelFit {
  std::vector<double> x;
  double ratio = 1;
  double energy = kInf;  // per unit weight
  bool valid = false;
  int evaluations = 0;
  int iterations = 0;
};

// Monotonicity penalty residuals on the 1024 grid: √P · max(0, f_i − f_{i+1} + ε).
constexpr double kPenaltyScale = 1e3;

// with_prior: include the extrapolation prior rows (the lower bound on the local exponent is always included).
ModelFit fitModelMoments(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                         double r0, bool fit_ratio, int max_iterations, bool with_prior) {
  const int L = sys.levels();
  const int d = curve.dims();
  const int rows = static_cast<int>(sys.h.rows());
  const bool emor = curve.kind() == Curve::kEmor;
  const double norm = 1.0 / std::sqrt(std::max(sys.weight, 1e-300));
  const int monotone_rows = emor ? kGrid - 1 : 0;
  const int prior_rows = with_prior && sys.exponent_weight > 0 ? static_cast<int>(sys.exponent_triples.size()) : 0;
  const int bound_rows = sys.min_exponent > 0 ? static_cast<int>(sys.exponent_pairs.size()) : 0;
  const int ratio_rows = fit_ratio && sys.ratio_prior_scale > 0 ? 1 : 0;
  const int extra = monotone_rows + prior_rows + bound_rows + ratio_rows;
  const double prior_scale = std::sqrt(sys.exponent_weight);
  auto logx = [L](int v) { return std::log(double(v) / (L - 1)); };
  // d log φ / d log x between levels a < b
  auto localExponent = [&](const std::vector<double>& f, int a, int b) {
    return (std::log(f[b]) - std::log(f[a])) / (logx(b) - logx(a));
  };
  ResidualFn fn = [&](const Eigen::VectorXd& p, Eigen::VectorXd& res, Eigen::MatrixXd* jac) {
    std::vector<double> f, jf;
    std::vector<double> psc(prior_rows);
    if (!curve.values(p.data(), f, jac ? &jf : nullptr)) return false;
    // the local exponents need log φ at every node they use (the first node of a chain is its smallest)
    if (prior_rows)
      for (const auto& t : sys.exponent_triples)
        if (!(f[t[0]] > 0)) return false;
    if (bound_rows)
      for (const auto& t : sys.exponent_pairs)
        if (!(f[t[0]] > 0)) return false;
    const double r = fit_ratio ? std::exp(p[d]) : r0;
    Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
    const Eigen::VectorXd hf = sys.h * fv, nf = sys.n * fv;
    Eigen::VectorXd slope(rows), raw = r * hf - nf;
    for (int i = 0; i < rows; ++i) {
      slope[i] = (f[sys.v1[i]] - f[sys.v0[i]]) * (L - 1) / double(sys.v1[i] - sys.v0[i]);
      if (!(slope[i] > 1e-9)) return false;
    }
    res.resize(rows + extra);
    res.head(rows) = norm * raw.cwiseQuotient(slope);
    std::vector<double> g, jg;
    if (emor) {
      curve.gridValues(p.data(), g, jac ? &jg : nullptr);
      for (int i = 0; i + 1 < kGrid; ++i) res[rows + i] = kPenaltyScale * std::max(0.0, g[i] - g[i + 1] + 1e-7);
    } else if (!monotone(f)) {
      return false;
    }
    for (int i = 0; i < prior_rows; ++i) {
      const auto& t = sys.exponent_triples[i];
      const double g1 = localExponent(f, t[0], t[1]), g2 = localExponent(f, t[1], t[2]);
      double target = 0;
      if (!sys.exponent_upper[i]) psc[i] = prior_scale;  // below the data: smoothness
      else if (!sys.shoulder_reference.empty()) {
        // above the data φ's local exponent changes as the measured mean camera's does (its shoulder)
        psc[i] = std::sqrt(sys.shoulder_weight);
        target = sys.shoulder_reference[i];
      } else {
        // the one-sided prior: a rising exponent (a shoulder) is free, a falling one costs the shoulder weight
        psc[i] = g2 < g1 ? std::sqrt(sys.shoulder_weight) : 0.0;
      }
      res[rows + monotone_rows + i] = psc[i] * (g2 - g1 - target);
    }
    const int bound_offset = rows + monotone_rows + prior_rows;
    for (int i = 0; i < bound_rows; ++i) {
      const auto& t = sys.exponent_pairs[i];
      const double g = localExponent(f, t[0], t[1]);
      res[bound_offset + i] = kPenaltyScale * std::max(0.0, sys.min_exponent - g);
    }
    if (ratio_rows) res[rows + extra - 1] = sys.ratio_prior_scale * (p[d] - sys.ratio_prior_log_centre);
    if (jac) {
      const int np = static_cast<int>(p.size());
      jac->setZero(rows + extra, np);
      Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> jm(jf.data(), d, L);
      const Eigen::MatrixXd draw = (r * sys.h - sys.n) * jm.transpose();  // rows × d
      for (int i = 0; i < rows; ++i) {
        const double scale = (L - 1) / double(sys.v1[i] - sys.v0[i]);
        for (int j = 0; j < d; ++j) {
          const double dslope = (jm(j, sys.v1[i]) - jm(j, sys.v0[i])) * scale;
          (*jac)(i, j) = norm * (draw(i, j) / slope[i] - raw[i] * dslope / (slope[i] * slope[i]));
        }
      }
      if (fit_ratio) jac->col(d).head(rows) = norm * r * hf.cwiseQuotient(slope);
      if (emor)
        for (int i = 0; i + 1 < kGrid; ++i)
          if (g[i] - g[i + 1] + 1e-7 > 0)
            for (int j = 0; j < d; ++j) (*jac)(rows + i, j) = kPenaltyScale * (jg[j * kGrid + i] - jg[j * kGrid + i + 1]);
      for (int i = 0; i < prior_rows; ++i) {
        const auto& t = sys.exponent_triples[i];
        const double d1 = logx(t[1]) - logx(t[0]), d2 = logx(t[2]) - logx(t[1]);
        for (int j = 0; j < d; ++j) {
          const double l0 = jm(j, t[0]) / f[t[0]], l1 = jm(j, t[1]) / f[t[1]], l2 = jm(j, t[2]) / f[t[2]];
          (*jac)(rows + monotone_rows + i, j) = psc[i] * ((l2 - l1) / d2 - (l1 - l0) / d1);
        }
      }
      for (int i = 0; i < bound_rows; ++i) {
        if (!(res[bound_offset + i] > 0)) continue;
        const auto& t = sys.exponent_pairs[i];
        const double d1 = logx(t[1]) - logx(t[0]);
        for (int j = 0; j < d; ++j)
          (*jac)(bound_offset + i, j) = -kPenaltyScale * (jm(j, t[1]) / f[t[1]] - jm(j, t[0]) / f[t[0]]) / d1;
      }
      if (ratio_rows) (*jac)(rows + extra - 1, d) = sys.ratio_prior_scale;
    }
    return true;
  };
  ModelFit best;
  if (emor && starts.empty()) {
    // linear least squares in c at r0 (the residual is linear in c for fixed r)
    std::vector<double> f0, jf;
    const std::vector<double> zero(d, 0.0);
    curve.values(zero.data(), f0, &jf);
    Eigen::Map<const Eigen::VectorXd> b0(f0.data(), L);
    Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> e(jf.data(), d, L);
    const Eigen::MatrixXd a = r0 * sys.h - sys.n;
    const Eigen::MatrixXd m = a * e.transpose();
    const Eigen::VectorXd y = -(a * b0);
    const Eigen::VectorXd c = m.colPivHouseholderQr().solve(y);
    starts.push_back(std::vector<double>(c.data(), c.data() + d));
    starts.push_back(zero);
  }
  for (const auto& s : starts) {
    Eigen::VectorXd p(d + (fit_ratio ? 1 : 0));
    for (int j = 0; j < d; ++j) p[j] = s[j];
    if (fit_ratio) p[d] = std::log(r0);
    const LmResult lm = levenbergMarquardt(p, fn, max_iterations);
    best.evaluations += lm.evaluations;
    best.iterations += lm.iterations;
    if (lm.cost < best.energy) {
      best.energy = lm.cost;
      best.x.assign(lm.x.data(), lm.x.data() + d);
      best.ratio = fit_ratio ? std::exp(lm.x[d]) : r0;
    }
  }
  if (!best.x.empty()) best.valid = isValid(curve.model(best.x));
  return best;
}

// Continuously-updated GMM (CUE): residual_k = S_k / √V_k(φ, r), S_k = (r Ĥ_k − N_k)·φ the bin sum and
// V_k = r² Σ_v q_k(v) Var[g(I) | v] + Σ_v N_k(v) φ'(x_v)² Δ²/12 its model variance (I's noise through the
// transition matrix T, plus the quantisation of B and I). The noise part of E[S_k²/V_k] is 1 whatever φ is, so the
// squared noise no longer pulls φ (the errors-in-variables bias of squared sums), and the ratio is invariant to
// the scale of φ (no φ → 0 degeneracy).
struct CueModel {
  const Eigen::MatrixXd* t = nullptr;  // transition matrix (null: no noise of I)
  const Eigen::MatrixXd* r = nullptr;  // debias operator (null: g = φ)
};

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

ModelFit fitModelCue(const Curve& curve, const MomentSystem& sys, const CueModel& cue,
                     std::vector<std::vector<double>> starts, double r0, bool fit_ratio, int max_iterations) {
  const int d = curve.dims();
  const bool emor = curve.kind() == Curve::kEmor;
  const int rows = static_cast<int>(sys.h.rows());
  const double norm = 1.0 / std::sqrt(std::max(1, rows));
  auto eval = [&](const Eigen::VectorXd& p, Eigen::VectorXd& res) {
    std::vector<double> f;
    if (!curve.values(p.data(), f, nullptr) || !monotone(f)) return false;
    if (emor) {
      std::vector<double> g;
      curve.gridValues(p.data(), g, nullptr);
      if (!monotone(g)) return false;
    }
    const double r = fit_ratio ? std::exp(p[d]) : r0;
    if (!cueResiduals(sys, cue, f, r, res)) return false;
    res *= norm;
    return true;
  };
  ResidualFn fn = [&](const Eigen::VectorXd& p, Eigen::VectorXd& res, Eigen::MatrixXd* jac) {
    if (!eval(p, res)) return false;
    if (jac) {
      jac->resize(res.size(), p.size());
      Eigen::VectorXd pp = p, rp;
      for (int j = 0; j < p.size(); ++j) {
        const double h = 1e-6 * std::max(1.0, std::abs(p[j]));
        pp[j] = p[j] + h;
        if (eval(pp, rp)) jac->col(j) = (rp - res) / h;
        else {
          pp[j] = p[j] - h;
          if (!eval(pp, rp)) return false;
          jac->col(j) = (res - rp) / h;
        }
        pp[j] = p[j];
      }
    }
    return true;
  };
  ModelFit best;
  for (const auto& s : starts) {
    if (s.empty()) continue;
    Eigen::VectorXd p(d + (fit_ratio ? 1 : 0));
    for (int j = 0; j < d; ++j) p[j] = s[j];
    if (fit_ratio) p[d] = std::log(r0);
    const LmResult lm = levenbergMarquardt(p, fn, max_iterations);
    best.evaluations += lm.evaluations * (d + 2);
    best.iterations += lm.iterations;
    if (lm.cost < best.energy) {
      best.energy = lm.cost;
      best.x.assign(lm.x.data(), lm.x.data() + d);
      best.ratio = fit_ratio ? std::exp(lm.x[d]) : r0;
    }
  }
  if (!best.x.empty()) best.valid = isValid(curve.model(best.x));
  return best;
}

// Energy (per unit weight) of a fixed φ on a system, r given.
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

// The extrapolation priors (local-exponent smoothness, shoulder) only break ties the data leave open (the affine
// freedom at r = 1): fit without them, then with them from the same starts, and keep the regularised fit while its
// data energy stays within `energy_factor` of the unregularised one (CrfFitOptions::prior_energy_factor).
ModelFit fitModelMomentsWithPrior(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                                  double r0, bool fit_ratio, int max_iterations, double energy_factor) {
  ModelFit plain = fitModelMoments(curve, sys, starts, r0, fit_ratio, max_iterations, false);
  if (sys.exponent_triples.empty() || sys.exponent_weight <= 0) return plain;
  if (!plain.x.empty()) starts.push_back(plain.x);
  ModelFit prior = fitModelMoments(curve, sys, starts, r0, fit_ratio, max_iterations, true);
  prior.evaluations += plain.evaluations;
  prior.iterations += plain.iterations;
  plain.evaluations = prior.evaluations;
  plain.iterations = prior.iterations;
  auto dataEnergy = [&](const ModelFit& m) {
    std::vector<double> f;
    if (m.x.empty() || !curve.values(m.x.data(), f, nullptr)) return kInf;
    const double e = momentEnergy(sys, f, m.ratio);  // the data rows only
    return std::isfinite(e) ? e : kInf;
  };
  const double e0 = dataEnergy(plain), e1 = dataEnergy(prior);
  if (prior.valid && (!plain.valid || e1 <= energy_factor * e0)) {
    prior.energy = e1;
    return prior;
  }
  plain.energy = e0;
  return plain;
}

// ---------------------------------------------------------------------------------------------------------
// Seed objective (Eq. 22): Σ W² (ψ(r · m_p) − B_p)² / Σ W², m_p = Σ w_p(v) g(x_v), g = f or R f.
struct SeedObjective {
  const Prepared* prep;
  const LevelMixture* mixture;
  const Curve* curve;
  const NoiseDebias* debias;  // null: none
  std::vector<double> b_value;
  double ratio = 1;
  double weight_sum = 1;

  double energy(const std::vector<double>& x) const {
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
  // Eq. 25.
  double ratioStep(const std::vector<double>& x) const {
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
};

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

}  // namespace

CrfFitResult fitInverseCrf(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel_in,
                           const CrfFitOptions& options) {
  options.check();
  const auto t_start = Clock::now();
  auto report = [&](double fraction, const std::string& stage) {
    if (options.progress) options.progress(fraction, stage);
  };
  if (sharp.empty() || blurred.empty()) throw InvalidInput("fit: empty image");
  if (sharp.size() != blurred.size()) throw InvalidInput("fit: sharp and blurred images differ in size");
  if (sharp.channels() != 1 || blurred.channels() != 1) throw InvalidInput("fit: images must be single-channel");
  const int threads = options.threads > 0 ? options.threads : std::max(1, cv::getNumThreads());
  const bool seed_objective = options.objective == CrfObjective::seed_intensity;

  CrfFitResult result;
  result.initial_ratio = options.initial_ratio;
  result.objective = options.objective;
  result.optimizer = options.optimizer;

  Prepared prep;
  prep.kernel = normalizeKernel(kernel_in);
  const cv::Mat& kernel = prep.kernel;
  prep.sharp_unit = toUnitGray(sharp);
  prep.blurred_unit = toUnitGray(blurred);
  const int L = std::max(naturalLevels(sharp), naturalLevels(blurred));
  prep.levels = L;
  result.levels = L;

  // σ of I.
  const bool need_sigma = options.noise != NoiseHandling::none || !seed_objective;
  double sigma = 0;
  if (!options.noise_sigma_per_level.empty()) {
    if (static_cast<int>(options.noise_sigma_per_level.size()) != L)
      throw InvalidInput("fit options: noise_sigma_per_level has " + std::to_string(options.noise_sigma_per_level.size()) +
                         " entries, the level grid has " + std::to_string(L));
    sigma = std::accumulate(options.noise_sigma_per_level.begin(), options.noise_sigma_per_level.end(), 0.0) / L;
  } else if (options.noise_sigma >= 0) {
    sigma = options.noise_sigma;
  } else if (need_sigma && sharp.rows >= 9 && sharp.cols >= 9) {
    sigma = estimateNoiseSigma(prep.sharp_unit).sigma;
    result.noise_sigma_estimated = true;
  }
  result.noise_sigma = sigma;
  const bool noisy = sigma * 255.0 > 1.0;  // more than one 8-bit level

  cv::Mat sharp_used = prep.sharp_unit;
  if (options.noise == NoiseHandling::denoise) sharp_used = denoiseSharp(prep.sharp_unit, sigma);
  prep.sharp = toLevels(sharp_used, L);
  prep.blurred = toLevels(prep.blurred_unit, L);

  // Pixel accounting: border, saturation (dilated by the support), edges.
  CrfPixelAccounting& acc = result.pixels;
  acc.total = static_cast<int>(sharp.total());
  const cv::Rect inside = interiorRect(sharp.size(), kernel);
  cv::Mat interior = cv::Mat::zeros(sharp.size(), CV_8U);
  if (inside.area() > 0) interior(inside).setTo(255);
  acc.border = acc.total - cv::countNonZero(interior);
  cv::Mat bad = (prep.blurred_unit >= options.saturation_high) | (prep.blurred_unit <= options.saturation_low);
  if (noisy) {
    // A noisy I clips at 0 and 1 by noise alone (modelled by the censored transition matrix); only regions whose
    // local median is saturated are saturated (a per-pixel test would select pixels by their noise).
    cv::Mat s32, med;
    prep.sharp_unit.convertTo(s32, CV_32F);
    cv::medianBlur(s32, med, 5);
    bad |= (med >= options.saturation_high) | (med <= options.saturation_low);
  } else {
    bad |= (prep.sharp_unit >= options.saturation_high) | (prep.sharp_unit <= options.saturation_low);
  }
  {
    const cv::Size ks((kernel.cols | 1) + (kernel.cols % 2 == 0 ? 1 : 0), (kernel.rows | 1) + (kernel.rows % 2 == 0 ? 1 : 0));
    cv::dilate(bad, bad, cv::getStructuringElement(cv::MORPH_RECT, ks));
  }
  bad &= interior;
  acc.saturated = cv::countNonZero(bad);
  if (acc.saturated > 0 && acc.saturated == cv::countNonZero(interior))
    throw InvalidInput("fit: every pixel is saturated or censored (in B or I, dilated by the kernel support)");

  // Weights / selection.
  cv::Mat weight(sharp.size(), CV_64F, cv::Scalar(0));
  if (seed_objective) {
    const bool unit_ratio = std::abs(options.initial_ratio - 1.0) < 1e-9;
    if (unit_ratio) {
      const cv::Mat gamma = prep.blurred_unit - convolve(sharp_used, kernel);  // Γ = B − I ⊗ K
      weight.setTo(0);
      gamma.copyTo(weight, gamma > options.tau1);  // Eq. 23
    } else {
      const LocalRange range = localRange(sharp_used, kernel);
      const cv::Mat spread = range.max - range.min;
      spread.copyTo(weight, spread > options.tau2);  // Eq. 24
    }
  } else {
    const LocalRange range = localRange(prep.blurred_unit, kernel);
    const cv::Mat spread = range.max - range.min;
    spread.copyTo(weight, spread > options.edge_threshold);
  }
  std::vector<cv::Point> candidates_px;
  for (int y = inside.y; y < inside.y + inside.height; ++y)
    for (int x = inside.x; x < inside.x + inside.width; ++x) {
      if (bad.at<std::uint8_t>(y, x)) continue;
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
  acc.used_mask = cv::Mat::zeros(sharp.size(), CV_8U);
  for (const auto& p : prep.pixels) acc.used_mask.at<std::uint8_t>(p) = 255;
  if (acc.used < options.min_pixels)
    throw InvalidInput("fit: no usable edges: only " + std::to_string(acc.used) + " usable edge pixels (need " +
                       std::to_string(options.min_pixels) + "); the pair needs blurred edges away from saturation");
  for (const auto& p : prep.pixels) prep.seed_weight.push_back(weight.at<double>(p));

  // Noise debias operator.
  NoiseDebias debias;
  const bool use_debias = options.noise == NoiseHandling::debias && (sigma > 0 || !options.noise_sigma_per_level.empty());
  if (use_debias) {
    NoiseDebiasOptions dopt;
    dopt.levels = L;
    dopt.sigma = std::min(sigma, 0.5);
    dopt.sigma_per_level = options.noise_sigma_per_level;
    dopt.regularization = options.debias_regularization;
    debias = NoiseDebias(dopt);
  }
  const bool debias_active = use_debias && !debias.identity();
  // Second-order Jensen correction (NoiseHandling::jensen): g = φ − ½ σ²(v) φ''(v), so that E[g(I) | c] = φ(c) up
  // to O(σ⁴). A tridiagonal operator on the level grid (g = J f, applied to the moment rows as H J like R above):
  // local, so it does not amplify the noise the way the deconvolution R does.
  // σ(v): given, else estimated per level from I (the sharp shot's noise grows with the signal: one σ for all levels
  // over-corrects the shadows and under-corrects the highlights), else the single given σ.
  Eigen::MatrixXd jensen;
  if (options.noise == NoiseHandling::jensen && !seed_objective && (sigma > 0 || !options.noise_sigma_per_level.empty())) {
    std::vector<double> sigma_v = options.noise_sigma_per_level;
    if (sigma_v.empty() && options.noise_sigma < 0 && sharp.rows >= 9 && sharp.cols >= 9) {
      const NoiseProfile profile = estimateNoiseProfile(prep.sharp_unit);
      sigma_v = noiseSigmaPerLevel(profile.level, profile.sigma, L);
    }
    if (sigma_v.empty()) sigma_v.assign(L, sigma);
    jensen = Eigen::MatrixXd::Identity(L, L);
    for (int v = 0; v < L; ++v) {
      const double sv = sigma_v[v];
      const double s = 0.5 * sv * sv * double(L - 1) * double(L - 1);  // ½σ²/h², h = 1/(L−1)
      const int c = std::clamp(v, 1, L - 2);  // the ends use the nearest interior second difference
      jensen(v, c - 1) -= s;  // row v: g_v = f_v − s (f_{c+1} − 2 f_c + f_{c−1})
      jensen(v, c) += 2 * s;
      jensen(v, c + 1) -= s;
    }
  }
  // the noise transition matrix (for the CUE variances) also without debiasing
  NoiseDebias noise_only;
  const NoiseDebias* noise_t = nullptr;
  if (debias_active) noise_t = &debias;
  else if (!seed_objective && options.noise == NoiseHandling::none && sigma * (L - 1) >= 0.05) {
    NoiseDebiasOptions dopt;
    dopt.levels = L;
    dopt.sigma = std::min(sigma, 0.5);
    dopt.sigma_per_level = options.noise_sigma_per_level;
    noise_only = NoiseDebias(dopt);
    noise_t = &noise_only;
  }
  result.timings.prepare_s = secondsSince(t_start);
  report(0.1, "prepare");

  const Curve ggcm_curve(Curve::kGgcm, L, options.ggcm_degree);
  const Curve emor_curve(Curve::kEmor, L, options.emor_terms);
  const bool want_ggcm = options.model != CrfModelChoice::emor;
  const bool want_emor = options.model != CrfModelChoice::ggcm;
  std::vector<CrfCandidate> candidates;
  const auto t_opt = Clock::now();

  MomentSystem full;  // moments: all the data (the ambiguity check below evaluates on it)
  if (seed_objective) {
    const auto t_mix = Clock::now();
    const LevelMixture mixture = LevelMixture::build(prep.sharp, kernel, prep.pixels);
    result.mixture_nonzeros = mixture.nonZeros();
    result.timings.mixture_s = secondsSince(t_mix);
    SeedObjective objective{&prep, &mixture, nullptr, debias_active ? &debias : nullptr, {}, options.initial_ratio, 1};
    for (const auto& p : prep.pixels) objective.b_value.push_back(pixelValue(prep.blurred, p));
    double wsum = 0;
    for (double w : prep.seed_weight) wsum += w * w;
    objective.weight_sum = wsum;
    for (const Curve* curve : {&ggcm_curve, &emor_curve}) {
      if ((curve == &ggcm_curve && !want_ggcm) || (curve == &emor_curve && !want_emor)) continue;
      objective.curve = curve;
      objective.ratio = options.initial_ratio;
      std::vector<double> x = curve == &ggcm_curve ? ggcm::fromGamma(2.2, options.ggcm_degree).alpha
                                                   : std::vector<double>(curve->dims(), 0.0);
      int evaluations = 0;
      const int rounds = options.fit_ratio ? options.ratio_rounds : 1;
      for (int round = 0; round < rounds; ++round) {
        const Minimum m = nelderMead(x, [&](const std::vector<double>& v) { return objective.energy(v); },
                                     options.max_evaluations, 0.05);
        x = m.x;
        evaluations += m.evaluations;
        ++result.iterations;
        report(0.1 + 0.8 * (round + 1) / rounds, "optimise");
        if (!options.fit_ratio) break;
        const double next = std::clamp(objective.ratioStep(x), 0.05, 20.0);
        const bool converged = std::abs(next - objective.ratio) < 1e-4 * objective.ratio;
        objective.ratio = next;
        if (converged) break;
      }
      CrfCandidate c;
      c.kind = curve->name();
      c.model = curve->model(x);
      c.valid = isValid(c.model);
      c.ratio = objective.ratio;
      c.energy = objective.energy(x);
      c.criterion = c.energy;
      c.evaluations = evaluations;
      result.evaluations += evaluations;
      candidates.push_back(c);
    }
  } else {
    // Instruments from B alone: B level bin × bins of B's local min and max over the support (position_bins
    // each). Only non-empty bins are kept (compact ids).
    const int P = options.position_bins, K = options.level_bins;
    const LocalRange brange = localRange(prep.blurred_unit, kernel);
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
    std::vector<int> bin_level_bin;
    for (std::size_t i = 0; i < raw_id.size(); ++i) {
      int& c = compact[raw_id[i]];
      if (c < 0) {
        c = static_cast<int>(bin_level_bin.size());
        bin_level_bin.push_back(raw_id[i] / (P * P));
      }
      bin_of[i] = c;
    }
    const int bins = static_cast<int>(bin_level_bin.size());
    const auto t_mix = Clock::now();
    const Moments moments = buildMoments(prep, bin_of, bins, threads, &result.mixture_nonzeros);
    result.timings.mixture_s = secondsSince(t_mix);
    std::vector<double> centre(bins);
    for (int k = 0; k < bins; ++k) centre[k] = (bin_level_bin[k] + 0.5) / K;
    const Eigen::MatrixXd* rt = debias_active ? &debias.matrix() : jensen.size() ? &jensen : nullptr;
    {
      int nonempty = 0;
      for (int k = 0; k < bins; ++k) nonempty += (moments.count[0][k] + moments.count[1][k]) > 0;
      result.moment_bins = nonempty;
    }
    // Bin weights ω_k = 1: each residual is already divided by the secant slope of φ over the bin (the
    // intensity-domain residual of Eq. 21 to first order, MomentSystem), which makes the bins comparable.
    const Eigen::VectorXd omega = Eigen::VectorXd::Ones(bins);
    // Levels covered by data (I's kernel masses and B's levels, 0.1 % tails dropped): outside them φ is the
    // model's extrapolation, kept smooth by the local-exponent prior.
    {
      const Eigen::VectorXd mass = (moments.h[0] + moments.h[1] + moments.n[0] + moments.n[1]).colwise().sum().transpose();
      const double total = mass.sum(), tail = 1e-3 * total;
      double acc_lo = 0, acc_hi = 0;
      int lo = 0, hi = L - 1;
      while (lo < L - 1 && acc_lo + mass[lo] <= tail) acc_lo += mass[lo++];
      while (hi > 0 && acc_hi + mass[hi] <= tail) acc_hi += mass[hi--];
      result.covered_levels = {lo, hi};
    }
    auto setExtrapolationPrior = [&](MomentSystem& sys) {
      if (options.min_local_exponent > 0) {
        sys.exponent_pairs = exponentPairs(L);
        sys.min_exponent = options.min_local_exponent;
      }
      if (!(options.exponent_smoothness > 0)) return;
      sys.exponent_triples = exponentTriples(L, result.covered_levels.first, result.covered_levels.second);
      sys.exponent_weight = options.exponent_smoothness;
      sys.shoulder_weight = options.shoulder_prior;
      for (const auto& t : sys.exponent_triples) sys.exponent_upper.push_back(t[0] >= result.covered_levels.first);
      if (options.shoulder_follows_emor_mean) {
        const std::vector<double> g0 = onLevelGrid(emor::inverseMean(), L);
        auto logx = [L](int v) { return std::log(double(v) / (L - 1)); };
        auto ell = [&](int a, int b) { return (std::log(g0[b]) - std::log(g0[a])) / (logx(b) - logx(a)); };
        for (std::size_t i = 0; i < sys.exponent_triples.size(); ++i) {
          const auto& t = sys.exponent_triples[i];
          sys.shoulder_reference.push_back(sys.exponent_upper[i] ? ell(t[1], t[2]) - ell(t[0], t[1]) : 0.0);
        }
      }
    };
    // Exposure-ratio prior (CrfFitOptions::ratio_prior_sigma), in the units of the data rows: each bin's residual
    // has the variance s² estimated from the fit without the prior, so the data rows and the prior row add up to
    // −2 log posterior · s² / weight.
    const bool ratio_prior = options.fit_ratio && options.ratio_prior_sigma > 0;
    double residual_variance = 0;
    auto setRatioPrior = [&](MomentSystem& sys) {
      if (!(residual_variance > 0) || !(sys.weight > 0)) return;
      sys.ratio_prior_scale = std::sqrt(residual_variance / sys.weight) / options.ratio_prior_sigma;
      sys.ratio_prior_log_centre = std::log(options.initial_ratio);
    };
    ModelFit fit_g, fit_e;
    double ratio = options.initial_ratio;
    const int lm_iterations = std::max(20, options.max_evaluations / 10);
    {
      full = makeSystem(moments, rt, -1, omega, K, bin_level_bin);
      setExtrapolationPrior(full);
      if (want_emor || want_ggcm) {
        fit_e = fitModelMomentsWithPrior(emor_curve, full, {}, ratio, options.fit_ratio, lm_iterations,
                                         options.prior_energy_factor);
        result.evaluations += fit_e.evaluations;
        result.iterations += fit_e.iterations;
        if (ratio_prior && fit_e.valid && std::isfinite(fit_e.energy)) {
          // what the images alone say, then the same fit with the prior: every later fit carries it
          result.ratio_images_only = fit_e.ratio;
          const double bins = static_cast<double>(full.h.rows());
          residual_variance = fit_e.energy * bins / std::max(1.0, bins - emor_curve.dims() - 1);
          setRatioPrior(full);
          result.ratio_prior_scale = full.ratio_prior_scale;
          const ModelFit with_prior = fitModelMomentsWithPrior(emor_curve, full, {}, ratio, options.fit_ratio,
                                                               lm_iterations, options.prior_energy_factor);
          result.evaluations += with_prior.evaluations;
          result.iterations += with_prior.iterations;
          if (with_prior.valid) fit_e = with_prior;
        }
      }
      if (want_ggcm) {
        std::vector<std::vector<double>> starts;
        if (!fit_g.x.empty()) starts.push_back(fit_g.x);
        if (fit_e.valid) {
          ggcm::FitOptions go;
          go.degree = options.ggcm_degree;
          const auto projected = ggcm::fitInverse(sampleInverse(EmorModel{fit_e.x}, kGrid), go);
          if (projected.valid) starts.push_back(projected.model.alpha);
        }
        for (double gamma : {2.2, 1.6, 3.0, 1.0}) starts.push_back(ggcm::fromGamma(gamma, options.ggcm_degree).alpha);
        if (static_cast<int>(starts.size()) > options.multi_starts + (fit_g.x.empty() ? 0 : 1))
          starts.resize(options.multi_starts + (fit_g.x.empty() ? 0 : 1));
        const double r_start = fit_e.valid ? fit_e.ratio : ratio;
        if (options.optimizer == CrfOptimizer::nelder_mead) {
          // ablation: Nelder–Mead on the moment energy with r profiled out (closed form)
          ModelFit nm;
          for (const auto& s : starts) {
            auto energy = [&](const std::vector<double>& x) {
              std::vector<double> f;
              if (!ggcm_curve.values(x.data(), f, nullptr) || !monotone(f)) return 1e6;
              Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
              const Eigen::VectorXd hf = full.h * fv, nf = full.n * fv;
              const double r = options.fit_ratio ? std::clamp(hf.dot(nf) / std::max(hf.squaredNorm(), 1e-300), 0.05, 20.0) : ratio;
              const double e = momentEnergy(full, f, r);
              return std::isfinite(e) ? e : 1e6;
            };
            const Minimum m = nelderMead(s, energy, options.max_evaluations, 0.05, 1e-12);
            nm.evaluations += m.evaluations;
            if (m.value < nm.energy) {
              nm.energy = m.value;
              nm.x = m.x;
            }
          }
          std::vector<double> f;
          ggcm_curve.values(nm.x.data(), f, nullptr);
          Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
          const Eigen::VectorXd hf = full.h * fv, nf = full.n * fv;
          nm.ratio = options.fit_ratio ? std::clamp(hf.dot(nf) / std::max(hf.squaredNorm(), 1e-300), 0.05, 20.0) : ratio;
          nm.valid = isValid(ggcm_curve.model(nm.x));
          fit_g = nm;
        } else {
          fit_g = fitModelMomentsWithPrior(ggcm_curve, full, starts, r_start, options.fit_ratio, lm_iterations,
                                           options.prior_energy_factor);
        }
        result.evaluations += fit_g.evaluations;
        result.iterations += fit_g.iterations;
      }
      // r of the better valid fit: the start of the CUE refinement
      const bool use_g = want_ggcm && fit_g.valid && (!fit_e.valid || fit_g.energy <= fit_e.energy || !want_emor);
      if (use_g) ratio = fit_g.ratio;
      else if (fit_e.valid) ratio = fit_e.ratio;
      report(0.5, "optimise");
    }
    const bool corrected = options.variance_correction;
    if (corrected) {
      CueModel cue;
      if (noise_t) cue.t = &noise_t->transition();
      if (debias_active) cue.r = &debias.matrix();
      if (want_emor) {
        const ModelFit e = fitModelCue(emor_curve, full, cue, {fit_e.x, std::vector<double>(emor_curve.dims(), 0.0)},
                                       fit_e.x.empty() ? ratio : fit_e.ratio, options.fit_ratio, lm_iterations);
        if (e.valid) fit_e = e;
        result.evaluations += e.evaluations;
      }
      if (want_ggcm) {
        std::vector<std::vector<double>> starts{fit_g.x};
        if (fit_e.valid) {
          ggcm::FitOptions go;
          go.degree = options.ggcm_degree;
          const auto projected = ggcm::fitInverse(sampleInverse(EmorModel{fit_e.x}, kGrid), go);
          if (projected.valid) starts.push_back(projected.model.alpha);
        }
        const ModelFit g = fitModelCue(ggcm_curve, full, cue, starts, fit_g.x.empty() ? ratio : fit_g.ratio,
                                       options.fit_ratio, lm_iterations);
        if (g.valid) fit_g = g;
        result.evaluations += g.evaluations;
      }
    }
    // energies are per unit weight: (cost · weight) / weight — LM cost is already normalised
    const bool cross_validate = options.model == CrfModelChoice::automatic && !corrected;
    auto crossValidate = [&](const Curve& curve, const ModelFit& whole) {
      double total = 0;
      for (int fold = 0; fold < 2; ++fold) {
        MomentSystem train = makeSystem(moments, rt, fold, omega, K, bin_level_bin);
        setExtrapolationPrior(train);
        setRatioPrior(train);
        const MomentSystem test = makeSystem(moments, rt, 1 - fold, omega, K, bin_level_bin);
        if (train.h.rows() == 0 || test.h.rows() == 0) return std::numeric_limits<double>::quiet_NaN();
        const ModelFit f = fitModelMomentsWithPrior(curve, train, {whole.x}, whole.ratio, options.fit_ratio,
                                                   lm_iterations, options.prior_energy_factor);
        if (f.x.empty()) return kInf;
        std::vector<double> fv;
        if (!curve.values(f.x.data(), fv, nullptr)) return kInf;
        total += momentEnergy(test, fv, f.ratio) * test.weight;
      }
      return total;
    };
    if (want_emor && !fit_e.x.empty()) {
      CrfCandidate c;
      c.kind = "emor";
      c.model = emor_curve.model(fit_e.x);
      c.valid = fit_e.valid;
      c.ratio = fit_e.ratio;
      c.energy = fit_e.energy;
      c.criterion = cross_validate && c.valid ? crossValidate(emor_curve, fit_e) : c.energy;
      c.evaluations = fit_e.evaluations;
      candidates.push_back(c);
    }
    if (want_ggcm && !fit_g.x.empty()) {
      CrfCandidate c;
      c.kind = "ggcm";
      c.model = ggcm_curve.model(fit_g.x);
      c.valid = fit_g.valid;
      c.ratio = fit_g.ratio;
      c.energy = fit_g.energy;
      c.criterion = cross_validate && c.valid ? crossValidate(ggcm_curve, fit_g) : c.energy;
      c.evaluations = fit_g.evaluations;
      candidates.push_back(c);
    }
  }
  result.timings.optimise_s = secondsSince(t_opt);

  // Choose: valid first, then the lower criterion.
  const CrfCandidate* best = nullptr;
  for (const auto& c : candidates) {
    if (!c.valid) continue;
    if (!best || (std::isfinite(c.criterion) && !(c.criterion >= best->criterion))) best = &c;
  }
  for (auto& c : candidates) c.inverse_crf = sampleValidTable(c.model);
  if (best) {
    result.model = best->model;
    result.ratio = best->ratio;
    result.energy = best->energy;
    result.chosen = best->kind;
    if (candidates.size() == 1) result.choice_reason = std::string("only ") + best->kind + " was fitted";
    else if (options.model == CrfModelChoice::automatic && !seed_objective)
      result.choice_reason = options.variance_correction
                                 ? "lower CUE moment energy (chi-square per bin; equal parameter counts)"
                                 : "lower 2-fold cross-validated moment energy";
    else result.choice_reason = "lower energy";
  } else {
    // never return an invalid curve: fall back to the γ = 2.2 start
    result.model = ggcm::fromGamma(2.2, options.ggcm_degree);
    result.ratio = options.initial_ratio;
    result.energy = std::numeric_limits<double>::quiet_NaN();
    result.chosen = "fallback";
    result.choice_reason = "no candidate was a valid (monotone) curve; returned the gamma 2.2 start";
  }
  result.candidates = std::move(candidates);
  result.inverse_crf = sampleValidTable(result.model);
  // Along the exponential ambiguity (φ^γ, r^γ) the energy is flat to first order for a plain two-exposure pair;
  // only the blur inconsistency raises it. Relative rise at γ = 1 ± 0.1 (CrfFitResult::ambiguity_rise).
  if (!seed_objective && best && full.h.rows() > 0 && result.energy > 0) {
    const std::vector<double> f = onLevelGrid(result.inverse_crf, L);
    const double e0 = momentEnergy(full, f, result.ratio);
    double rise = kInf;
    for (double gamma : {0.9, 1.1}) {
      std::vector<double> fg(L);
      for (int v = 0; v < L; ++v) fg[v] = std::pow(std::max(f[v], 0.0), gamma);
      rise = std::min(rise, momentEnergy(full, fg, std::pow(result.ratio, gamma)) / e0 - 1);
    }
    result.ambiguity_rise = rise;
  }
  if (!checkValidity(TableModel{result.inverse_crf}, kCurveSamples, 1e-6)) {  // belt and braces (e.g. NaN)
    result.model = ggcm::fromGamma(2.2, options.ggcm_degree);
    result.inverse_crf = sampleValidTable(result.model);
    result.chosen = "fallback";
    result.choice_reason = "the chosen curve failed validation; returned the gamma 2.2 start";
  }
  result.timings.total_s = secondsSince(t_start);
  report(1.0, "done");
  return result;
}

}  // namespace crfcal
