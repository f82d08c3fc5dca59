#include "crfcal/crf_fitter.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <sstream>

#include <Eigen/Cholesky>
#include <Eigen/Core>
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
    case CrfObjective::noise_aware_intensity: return "noise_aware_intensity";
    case CrfObjective::instrumental: return "instrumental";
    case CrfObjective::corrected_irradiance: return "corrected_irradiance";
  }
  return "?";
}
const char* toString(CrfOptimizer value) {
  switch (value) {
    case CrfOptimizer::nelder_mead: return "nelder_mead";
    case CrfOptimizer::lbfgs: return "lbfgs";
    case CrfOptimizer::bobyqa: return "bobyqa";
  }
  return "?";
}
const char* toString(NoiseHandling value) {
  switch (value) {
    case NoiseHandling::none: return "none";
    case NoiseHandling::debias: return "debias";
    case NoiseHandling::denoise: return "denoise";
  }
  return "?";
}

CrfFitOptions CrfFitOptions::seed() {
  CrfFitOptions o;
  o.model = CrfModelChoice::ggcm;
  o.objective = CrfObjective::seed_intensity;
  o.optimizer = CrfOptimizer::nelder_mead;
  o.noise = NoiseHandling::none;
  o.multi_starts = 1;
  o.max_pixels = 0;
  o.max_evaluations = 1000;
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
  if (!(debias_regularization > 0)) throw InvalidInput("fit options: debias_regularization must be positive");
  if (!(edge_threshold >= 0)) throw InvalidInput("fit options: edge_threshold must be non-negative");
  if (!(saturation_high > saturation_low)) throw InvalidInput("fit options: saturation_high must exceed saturation_low");
  if (irls_rounds < 1 || ratio_rounds < 1) throw InvalidInput("fit options: irls_rounds and ratio_rounds must be >= 1");
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
    << iterations << ", evaluations " << evaluations << "\n";
  for (const auto& c : candidates)
    s << "  candidate " << c.kind << ": energy " << c.energy << ", criterion " << c.criterion
      << (c.valid ? "" : " (invalid)") << ", r " << c.ratio << "\n";
  s << "pixels: " << pixels.used << " used of " << pixels.total << " (border " << pixels.border << ", saturated "
    << pixels.saturated << ", low weight " << pixels.low_weight << ", subsampled " << pixels.subsampled << ")\n";
  s.precision(4);
  s << "noise sigma of I: " << noise_sigma << (noise_sigma_estimated ? " (estimated)" : " (given)") << "; "
    << toString(objective) << ", " << toString(optimizer) << ", " << levels << " levels, " << mixture_nonzeros
    << " mixture non-zeros\n";
  s << "time: prepare " << timings.prepare_s << " s, mixtures " << timings.mixture_s << " s, optimise "
    << timings.optimise_s << " s, total " << timings.total_s << " s";
  return s.str();
}

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

constexpr int kGrid = 1024;  // validity grid (the EMoR nodes)

// ---------------------------------------------------------------------------------------------------------
// Curve parameterisations: values on the level grid (+ Jacobian) and a smooth monotonicity penalty.
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
  // Quadratic penalty on decreasing steps over the 1024-node grid, with its gradient (added to `grad`).
  double penalty(const double* x, double* grad) const {
    std::vector<double> f, jac;
    if (!sample(x, kGrid, kind_ == kEmor ? &basis_grid_ : nullptr, f, grad ? &jac : nullptr)) return kInfeasible;
    double pen = 0;
    for (int i = 0; i + 1 < kGrid; ++i) {
      const double d = f[i] - f[i + 1] + 1e-7;  // want f[i+1] ≥ f[i] + 1e-7
      if (d <= 0) continue;
      pen += d * d;
      if (grad)
        for (int j = 0; j < dims_; ++j) grad[j] += kPenalty * 2 * d * (jac[j * kGrid + i] - jac[j * kGrid + i + 1]);
    }
    return kPenalty * pen;
  }
  ResponseModel model(const std::vector<double>& x) const {
    if (kind_ == kGgcm) return GgcmModel{x};
    return EmorModel{x};
  }
  std::vector<double> start(const ResponseModel& model) const {
    if (const auto* g = std::get_if<GgcmModel>(&model)) return g->alpha;
    if (const auto* e = std::get_if<EmorModel>(&model)) return e->coefficients;
    return std::vector<double>(dims_, 0.0);
  }
  // EMoR: f = b0 + B c on the levels.
  const double* emorLevels(int k) const { return basis_levels_.data() + static_cast<std::size_t>(k) * levels_; }

  static constexpr double kInfeasible = 1e6;
  static constexpr double kPenalty = 1e6;

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
// NLopt wrapper: keeps the best point seen (NLopt may stop with roundoff errors after progress).
struct Minimum {
  std::vector<double> x;
  double value = std::numeric_limits<double>::infinity();
  int evaluations = 0;
};

using Objective = std::function<double(const std::vector<double>& x, std::vector<double>* grad)>;

Minimum minimise(CrfOptimizer optimizer, const std::vector<double>& x0, const Objective& objective, int max_evaluations,
                 double step) {
  nlopt::algorithm algorithm = nlopt::LN_NELDERMEAD;
  if (optimizer == CrfOptimizer::lbfgs) algorithm = nlopt::LD_LBFGS;
  if (optimizer == CrfOptimizer::bobyqa) algorithm = nlopt::LN_BOBYQA;
  const unsigned n = static_cast<unsigned>(x0.size());
  nlopt::opt opt(algorithm, n);
  struct State {
    const Objective* f;
    Minimum best;
  } state{&objective, {}};
  opt.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>& grad, void* data) -> double {
        auto* s = static_cast<State*>(data);
        ++s->best.evaluations;
        const double value = (*s->f)(x, grad.empty() ? nullptr : &grad);
        if (value < s->best.value) {
          s->best.value = value;
          s->best.x = x;
        }
        return value;
      },
      &state);
  opt.set_maxeval(max_evaluations);
  opt.set_ftol_rel(1e-12);
  opt.set_xtol_rel(1e-10);
  if (algorithm != nlopt::LD_LBFGS) opt.set_initial_step(std::vector<double>(n, step));
  if (algorithm == nlopt::LD_LBFGS) opt.set_vector_storage(10);
  std::vector<double> x = x0;
  double value = 0;
  try {
    opt.optimize(x, value);
  } catch (const std::exception&) {
    // roundoff_limited / forced stop: keep the best point seen
  }
  if (state.best.x.empty()) {
    state.best.x = x0;
    state.best.value = objective(x0, nullptr);
  }
  return state.best;
}

// ---------------------------------------------------------------------------------------------------------
struct Prepared {
  int levels = 256;
  LevelImage sharp, blurred;
  cv::Mat blurred_unit;
  std::vector<cv::Point> pixels;
  std::vector<double> seed_weight;  // W_p (seed objective)
  std::vector<int> fold;            // 0/1, 16×16 checkerboard tiles
  LevelMixture mixture;
  NoiseDebias debias;
  std::vector<double> b_value;      // B_p in [0,1]
  std::vector<int> b_lo;            // B level (lo) and frac
  std::vector<double> b_frac;
};

double pixelValue(const LevelImage& image, int y, int x) {
  const double lo = image.lo.at<std::uint16_t>(y, x);
  const double t = image.frac.empty() ? 0.0 : image.frac.at<float>(y, x);
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

bool monotone(const std::vector<double>& f) {
  for (std::size_t i = 1; i < f.size(); ++i)
    if (f[i] < f[i - 1]) return false;
  return true;
}

double phiAtB(const Prepared& p, const std::vector<double>& f, int i) {
  const int lo = p.b_lo[i];
  const double t = p.b_frac[i];
  return t > 0 ? (1 - t) * f[lo] + t * f[lo + 1] : f[lo];
}

// ---------------------------------------------------------------------------------------------------------
// Seed objective (Eq. 22): Σ W² (ψ(r · m_p) − B_p)², m_p = Σ w_p(v) g(x_v), g = f or R f.
struct SeedObjective {
  const Prepared* prep;
  const Curve* curve;
  bool debias = false;
  double ratio = 1;
  double weight_sum = 1;
  mutable std::vector<double> f, g, m;

  bool variance_correction = false;  // second-order E[ψ(m + e)] ≈ ψ(m) + ½ ψ''(m) Var(e)
  mutable std::vector<double> h, v, f2;

  double energy(const std::vector<double>& x) const {
    if (!curve->values(x.data(), f, nullptr)) return Curve::kInfeasible;
    if (!monotone(f)) return Curve::kInfeasible * 0.5 + curve->penalty(x.data(), nullptr);
    g = debias ? prep->debias.apply(f) : f;
    m.resize(prep->pixels.size());
    prep->mixture.mix(g, m);
    const int L = static_cast<int>(f.size());
    if (variance_correction) {
      f2.resize(L);
      for (int i = 0; i < L; ++i) f2[i] = f[i] * f[i];
      h = prep->debias.apply(f2);
      for (int i = 0; i < L; ++i) h[i] = g[i] * g[i] - h[i];
      v.resize(m.size());
      prep->mixture.mixSquared(h, v);
    }
    double sum = 0;
    for (std::size_t i = 0; i < m.size(); ++i) {
      const double w = prep->seed_weight[i];
      const double y = std::min(1.0, ratio * m[i]);
      const double xi = inverseOf(f, y);
      double predicted = xi;
      if (variance_correction && v[i] > 0) {
        // ψ''(y) = −φ''(x)/φ'(x)³ at x = ψ(y), central differences over ±2 levels
        const double s = xi * (L - 1);
        const int c = std::clamp(static_cast<int>(std::lround(s)), 2, L - 3);
        const double hstep = 2.0 / (L - 1);
        const double d1 = (f[c + 2] - f[c - 2]) / (2 * hstep);
        const double d2 = (f[c + 2] - 2 * f[c] + f[c - 2]) / (hstep * hstep);
        if (d1 > 1e-3) predicted += 0.5 * (-d2 / (d1 * d1 * d1)) * ratio * ratio * v[i];
      }
      const double e = predicted - prep->b_value[i];
      sum += w * w * e * e;
    }
    return sum / weight_sum;
  }
  double operator()(const std::vector<double>& x, std::vector<double>* grad) const {
    const double value = energy(x);
    if (grad) {  // central differences (only when a derivative-based optimiser is asked for)
      std::vector<double> xp = x;
      for (std::size_t j = 0; j < x.size(); ++j) {
        const double h = 1e-6 * std::max(1.0, std::abs(x[j]));
        xp[j] = x[j] + h;
        const double a = energy(xp);
        xp[j] = x[j] - h;
        const double b = energy(xp);
        xp[j] = x[j];
        (*grad)[j] = (a - b) / (2 * h);
      }
    }
    return value;
  }
  // Eq. 25 on the used pixels.
  double ratioStep(const std::vector<double>& x) const {
    if (!curve->values(x.data(), f, nullptr)) return ratio;
    g = debias ? prep->debias.apply(f) : f;
    m.resize(prep->pixels.size());
    prep->mixture.mix(g, m);
    if (variance_correction) {
      const int L = static_cast<int>(f.size());
      f2.resize(L);
      for (int i = 0; i < L; ++i) f2[i] = f[i] * f[i];
      h = prep->debias.apply(f2);
      for (int i = 0; i < L; ++i) h[i] = g[i] * g[i] - h[i];
      v.resize(m.size());
      prep->mixture.mixSquared(h, v);
    }
    double num = 0, den = 0;
    for (std::size_t i = 0; i < m.size(); ++i) {
      num += m[i] * phiAtB(*prep, f, static_cast<int>(i));
      den += m[i] * m[i] - (variance_correction ? v[i] : 0.0);
    }
    return den > 0 ? num / den : ratio;
  }
};

// ---------------------------------------------------------------------------------------------------------
// Corrected irradiance objective. The pixels are grouped by the level of B into bins; per bin and fold the
// corrected energy is a quadratic form fᵀ (Q0 + r Q1 + r² Q2) f. The intensity-domain scaling 1/φ'(B)² is
// applied per bin with the secant slope of the *current* f over the bin (so a collapsing φ ≈ 0 gains
// nothing: the energy is invariant to the local scale of φ), and within a bin by ω_p from the previous iterate.
struct QuadraticForms {
  int bins = 1;
  int levels = 256;
  std::vector<int> edge;  // bin b covers levels [edge[b], edge[b+1]]
  std::vector<Eigen::MatrixXd> q0[2], q1[2], q2[2];
  double weight[2] = {0, 0};
  int binOf(int level) const { return std::min(bins - 1, level * bins / levels); }
};

QuadraticForms buildForms(const Prepared& prep, const std::vector<double>& omega, int threads, int bins) {
  const int L = prep.levels;
  const int n = static_cast<int>(prep.pixels.size());
  const int stripes = std::max(1, threads);
  QuadraticForms forms;
  forms.bins = bins;
  forms.levels = L;
  for (int b = 0; b <= bins; ++b) forms.edge.push_back(std::min(L - 1, b * L / bins));
  struct Acc {
    std::vector<Eigen::MatrixXd> bb[2], bw[2], ww[2];
    std::vector<Eigen::VectorXd> u[2];
    double weight[2] = {0, 0};
  };
  std::vector<Acc> acc(stripes);
  for (auto& a : acc)
    for (int f = 0; f < 2; ++f) {
      a.bb[f].assign(bins, Eigen::MatrixXd::Zero(L, L));
      a.bw[f].assign(bins, Eigen::MatrixXd::Zero(L, L));
      a.ww[f].assign(bins, Eigen::MatrixXd::Zero(L, L));
      a.u[f].assign(bins, Eigen::VectorXd::Zero(L));
    }
  auto work = [&](const cv::Range& range) {
    for (int s = range.start; s < range.end; ++s) {
      Acc& a = acc[s];
      const int begin = static_cast<int>(static_cast<long long>(n) * s / stripes);
      const int end = static_cast<int>(static_cast<long long>(n) * (s + 1) / stripes);
      for (int i = begin; i < end; ++i) {
        const double om = omega[i];
        if (om <= 0) continue;
        const int f = prep.fold[i];
        const int bin = forms.binOf(prep.b_lo[i]);
        a.weight[f] += om;
        const auto levels = prep.mixture.rowLevels(i);
        const auto w = prep.mixture.rowWeights(i);
        const auto u = prep.mixture.rowSquared(i);
        int bl[2] = {prep.b_lo[i], prep.b_lo[i] + 1};
        double bv[2] = {1 - prep.b_frac[i], prep.b_frac[i]};
        const int nb = prep.b_frac[i] > 0 ? 2 : 1;
        double* bb = a.bb[f][bin].data();
        double* bw = a.bw[f][bin].data();
        double* ww = a.ww[f][bin].data();
        double* uu = a.u[f][bin].data();
        for (int s1 = 0; s1 < nb; ++s1) {
          for (int s2 = 0; s2 < nb; ++s2) bb[static_cast<std::size_t>(bl[s2]) * L + bl[s1]] += om * bv[s1] * bv[s2];
          for (std::size_t k = 0; k < levels.size(); ++k)
            bw[static_cast<std::size_t>(levels[k]) * L + bl[s1]] += om * bv[s1] * w[k];  // (row b, col level)
        }
        for (std::size_t k = 0; k < levels.size(); ++k) {
          uu[levels[k]] += om * u[k];
          const double wk = om * w[k];
          double* col = ww + static_cast<std::size_t>(levels[k]) * L;  // column levels[k]
          for (std::size_t j = 0; j <= k; ++j) col[levels[j]] += wk * w[j];  // rows levels[j] ≤ levels[k]
        }
      }
    }
  };
  if (stripes == 1) work(cv::Range(0, 1));
  else cv::parallel_for_(cv::Range(0, stripes), work, stripes);

  const Eigen::MatrixXd& r = prep.debias.matrix();
  const bool identity = prep.debias.identity();
  for (int f = 0; f < 2; ++f) {
    for (auto& a : acc) forms.weight[f] += a.weight[f];
    for (int bin = 0; bin < bins; ++bin) {
      Eigen::MatrixXd bb = Eigen::MatrixXd::Zero(L, L), bw = bb, ww = bb;
      Eigen::VectorXd u = Eigen::VectorXd::Zero(L);
      for (auto& a : acc) {
        bb += a.bb[f][bin];
        bw += a.bw[f][bin];
        ww += a.ww[f][bin];
        u += a.u[f][bin];
      }
      Eigen::MatrixXd upper = ww.triangularView<Eigen::StrictlyUpper>();
      ww = ww.triangularView<Eigen::Upper>();
      ww += upper.transpose();
      forms.q0[f].push_back(bb);
      if (identity || bb.isZero(0)) {
        forms.q1[f].push_back(-(bw + bw.transpose()));
        forms.q2[f].push_back(ww);  // the variance correction cancels without debiasing
      } else {
        const Eigen::MatrixXd bwr = bw * r;
        forms.q1[f].push_back(-(bwr + bwr.transpose()));
        Eigen::MatrixXd inner = ww;
        inner.diagonal() -= u;
        Eigen::MatrixXd q2 = r.transpose() * inner * r;
        q2.diagonal() += r.transpose() * u;
        forms.q2[f].push_back(q2);
      }
    }
  }
  return forms;
}

// The bin matrices at ratio r for one fold (or both: fold −1).
struct BinnedForm {
  std::vector<Eigen::MatrixXd> q;
  std::vector<int> edge;
  double weight = 1;
};

BinnedForm formAt(const QuadraticForms& forms, double r, int fold) {
  BinnedForm out;
  out.edge = forms.edge;
  out.weight = 0;
  for (int f = 0; f < 2; ++f)
    if (fold < 0 || fold == f) out.weight += forms.weight[f];
  if (out.weight <= 0) out.weight = 1;
  for (int b = 0; b < forms.bins; ++b) {
    Eigen::MatrixXd q = Eigen::MatrixXd::Zero(forms.levels, forms.levels);
    for (int f = 0; f < 2; ++f)
      if (fold < 0 || fold == f) q += forms.q0[f][b] + r * forms.q1[f][b] + r * r * forms.q2[f][b];
    out.q.push_back(0.5 * (q + q.transpose()));
  }
  return out;
}

// J(f) = Σ_b (h_b / Δf_b)² fᵀ Q_b f / W, h_b the bin width, Δf_b = f(edge_{b+1}) − f(edge_b).
struct QuadraticObjective {
  const Curve* curve;
  const BinnedForm* form;
  mutable std::vector<double> f, jac;

  double binScale(int b, double* d_delta) const {
    const int lo = form->edge[b], hi = form->edge[b + 1];
    const double h = double(hi - lo) / (form->q.size() > 0 ? double(curve->levels() - 1) : 1.0);
    const double delta = std::max(f[hi] - f[lo], 1e-9);
    if (d_delta) *d_delta = -2 * h * h / (delta * delta * delta);
    return h * h / (delta * delta);
  }
  double evaluateF(std::vector<double>* grad_f) const {
    const int L = static_cast<int>(f.size());
    Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
    double value = 0;
    if (grad_f) grad_f->assign(L, 0.0);
    for (std::size_t b = 0; b < form->q.size(); ++b) {
      double ds = 0;
      const double s = binScale(static_cast<int>(b), grad_f ? &ds : nullptr);
      const Eigen::VectorXd qf = form->q[b] * fv;
      const double e = fv.dot(qf);
      value += s * e;
      if (grad_f) {
        Eigen::Map<Eigen::VectorXd> g(grad_f->data(), L);
        g += 2 * s * qf;
        if (f[form->edge[b + 1]] - f[form->edge[b]] > 1e-9) {
          (*grad_f)[form->edge[b + 1]] += ds * e;
          (*grad_f)[form->edge[b]] -= ds * e;
        }
      }
    }
    if (grad_f)
      for (double& g : *grad_f) g /= form->weight;
    return value / form->weight;
  }
  double operator()(const std::vector<double>& x, std::vector<double>* grad) const {
    if (grad) std::fill(grad->begin(), grad->end(), 0.0);
    if (!curve->values(x.data(), f, grad ? &jac : nullptr)) return Curve::kInfeasible;
    std::vector<double> gf;
    double value = evaluateF(grad ? &gf : nullptr);
    if (grad) {
      const int L = static_cast<int>(f.size());
      Eigen::Map<const Eigen::VectorXd> gv(gf.data(), L);
      for (int j = 0; j < curve->dims(); ++j) {
        Eigen::Map<const Eigen::VectorXd> row(jac.data() + static_cast<std::size_t>(j) * L, L);
        (*grad)[j] = row.dot(gv);
      }
    }
    value += curve->penalty(x.data(), grad ? grad->data() : nullptr);
    return value;
  }
  double plain(const std::vector<double>& x) const {
    if (!curve->values(x.data(), f, nullptr)) return std::numeric_limits<double>::infinity();
    return evaluateF(nullptr);
  }
  // r minimising Σ_b s_b fᵀ(Q0 + r Q1 + r² Q2)f for the given per-ratio forms.
};

bool isValid(const ResponseModel& model) { return static_cast<bool>(checkValidity(model, 4096, 1e-6)); }

struct FitOutcome {
  std::vector<double> x;
  double value = std::numeric_limits<double>::infinity();
  bool valid = false;
  int evaluations = 0;
};

// EMoR: closed-form minimiser of the quadratic form with the bin scales frozen at `reference` (irradiance-
// domain least squares, φ(0) = 0 and φ(1) = 1 by construction), then refinement of the full objective.
FitOutcome fitEmor(const Curve& curve, const BinnedForm& form, const std::vector<double>& reference,
                   const CrfFitOptions& options) {
  const int L = curve.levels();
  const int k = curve.dims();
  Eigen::MatrixXd h(L, k);
  for (int j = 0; j < k; ++j) h.col(j) = Eigen::Map<const Eigen::VectorXd>(curve.emorLevels(j + 1), L);
  const Eigen::Map<const Eigen::VectorXd> g0(curve.emorLevels(0), L);
  Eigen::MatrixXd q = Eigen::MatrixXd::Zero(L, L);
  for (std::size_t b = 0; b < form.q.size(); ++b) {
    const int lo = form.edge[b], hi = form.edge[b + 1];
    const double hb = double(hi - lo) / (L - 1);
    const double delta = std::max(reference[hi] - reference[lo], 1e-6);
    q += (hb * hb / (delta * delta)) * form.q[b];
  }
  Eigen::MatrixXd a = h.transpose() * q * h;
  const Eigen::VectorXd rhs = -(h.transpose() * (q * g0));
  a.diagonal().array() += 1e-10 * std::max(1e-300, a.trace() / k);
  const Eigen::VectorXd c = a.ldlt().solve(rhs);
  FitOutcome out;
  out.x = c.allFinite() ? std::vector<double>(c.data(), c.data() + k) : std::vector<double>(k, 0.0);
  QuadraticObjective objective{&curve, &form, {}, {}};
  const Minimum m = minimise(options.optimizer == CrfOptimizer::nelder_mead ? CrfOptimizer::lbfgs : options.optimizer,
                             out.x, objective, options.max_evaluations, 0.05);
  const bool start_valid = isValid(curve.model(out.x));
  const bool refined_valid = isValid(curve.model(m.x));
  out.evaluations = m.evaluations;
  if (refined_valid && (!start_valid || objective.plain(m.x) <= objective.plain(out.x))) out.x = m.x;
  out.valid = isValid(curve.model(out.x));
  out.value = objective.plain(out.x);
  return out;
}

FitOutcome fitGgcm(const Curve& curve, const Objective& objective, const std::vector<std::vector<double>>& starts,
                   CrfOptimizer optimizer, int max_evaluations, const std::function<double(const std::vector<double>&)>& plain) {
  FitOutcome best;
  for (const auto& s : starts) {
    const Minimum m = minimise(optimizer, s, objective, max_evaluations, 0.05);
    best.evaluations += m.evaluations;
    const bool valid = isValid(curve.model(m.x));
    const double value = plain(m.x);
    if ((valid && !best.valid) || (valid == best.valid && value < best.value)) {
      best.x = m.x;
      best.value = value;
      best.valid = valid;
    }
  }
  return best;
}

cv::Mat supportBox(const cv::Mat& kernel) {
  return cv::getStructuringElement(cv::MORPH_RECT, cv::Size(kernel.cols, kernel.rows));
}

}  // namespace

CrfFitResult fitInverseCrf(const cv::Mat& sharp_in, const cv::Mat& blurred_in, const cv::Mat& kernel_in,
                           const CrfFitOptions& options) {
  options.check();
  const auto t_start = Clock::now();
  auto report = [&](double fraction, const char* stage) {
    if (options.progress) options.progress(fraction, stage);
  };
  if (sharp_in.empty() || blurred_in.empty()) throw InvalidInput("fit: sharp and blurred images must not be empty");
  if (sharp_in.size() != blurred_in.size())
    throw InvalidInput("fit: sharp and blurred images differ in size (" + std::to_string(sharp_in.cols) + "x" +
                       std::to_string(sharp_in.rows) + " vs " + std::to_string(blurred_in.cols) + "x" +
                       std::to_string(blurred_in.rows) + ")");
  if (sharp_in.channels() != 1 || blurred_in.channels() != 1)
    throw InvalidInput("fit: sharp and blurred images must be single-channel");
  const cv::Mat kernel = normalizeKernel(kernel_in);
  const cv::Mat sharp = toUnitGray(sharp_in);
  const cv::Mat blurred = toUnitGray(blurred_in);
  const int threads = options.threads > 0 ? options.threads : std::max(1, cv::getNumThreads());

  CrfFitResult result;
  result.initial_ratio = options.initial_ratio;
  result.objective = options.objective;
  result.optimizer = options.optimizer;
  report(0.0, "prepare");

  Prepared prep;
  prep.levels = std::max(naturalLevels(sharp_in), naturalLevels(blurred_in));
  const int L = prep.levels;
  result.levels = L;

  // Noise of I (estimated from I alone unless given).
  double sigma = 0;
  if (options.noise != NoiseHandling::none) {
    if (options.noise_sigma >= 0) sigma = options.noise_sigma;
    else {
      sigma = estimateNoiseSigma(sharp).sigma;
      result.noise_sigma_estimated = true;
    }
  } else if (options.noise_sigma >= 0) {
    sigma = options.noise_sigma;
  } else {
    sigma = estimateNoiseSigma(sharp).sigma;
    result.noise_sigma_estimated = true;
  }
  result.noise_sigma = sigma;
  const bool noisy = sigma > 1.5 / 255.0;

  cv::Mat sharp_used = sharp;
  if (options.noise == NoiseHandling::denoise && noisy) {
    cv::Mat f32, den;
    sharp.convertTo(f32, CV_32F);
    cv::bilateralFilter(f32, den, 7, 2.0 * sigma, 2.0, cv::BORDER_REFLECT);
    den.convertTo(sharp_used, CV_64F);
  }
  prep.sharp = toLevels(sharp_used, L);
  prep.blurred = toLevels(blurred, L);
  const bool debias = options.noise == NoiseHandling::debias;
  prep.debias = NoiseDebias(NoiseDebiasOptions{L, debias ? sigma : 0.0, options.debias_regularization});

  // Pixel accounting: border, saturation (dilated by the support), weights.
  CrfPixelAccounting& acc = result.pixels;
  acc.total = sharp.rows * sharp.cols;
  const cv::Rect inside = interiorRect(sharp.size(), kernel);
  acc.border = acc.total - inside.area();
  if (inside.area() == 0) throw InvalidInput("fit: the kernel is larger than the images");
  cv::Mat sharp_ref = sharp;
  if (noisy) {  // judge saturation of a noisy I on its local median
    cv::Mat s8, med;
    sharp.convertTo(s8, CV_8U, 255.0);
    cv::medianBlur(s8, med, 5);
    med.convertTo(sharp_ref, CV_64F, 1.0 / 255.0);
  }
  cv::Mat saturated = (blurred >= options.saturation_high) | (blurred <= options.saturation_low) |
                      (sharp_ref >= options.saturation_high) | (sharp_ref <= options.saturation_low);
  cv::dilate(saturated, saturated, supportBox(kernel));
  const cv::Mat sat_inside = saturated(inside);
  acc.saturated = cv::countNonZero(sat_inside);
  if (acc.saturated == inside.area())
    throw InvalidInput("fit: all pixels are saturated or black in the sharp or blurred image; nothing to fit");

  cv::Mat weight;  // CV_64F, > 0 where usable
  if (options.objective == CrfObjective::seed_intensity) {
    if (std::abs(options.initial_ratio - 1.0) < 1e-12) {  // Eq. 23: Γ = B − I ⊗ K
      const cv::Mat gamma = blurInconsistency(blurred, intensityBlur(sharp_used, kernel));
      weight = cv::Mat::zeros(sharp.size(), CV_64F);
      gamma.copyTo(weight, gamma > options.tau1);
    } else {  // Eq. 24: Imax − Imin
      const LocalRange range = localRange(sharp_used, kernel);
      const cv::Mat span = range.max - range.min;
      weight = cv::Mat::zeros(sharp.size(), CV_64F);
      span.copyTo(weight, span > options.tau2);
    }
  } else {
    const LocalRange range = localRange(blurred, kernel);
    const cv::Mat span = range.max - range.min;
    weight = cv::Mat::zeros(sharp.size(), CV_64F);
    weight.setTo(1.0, span > options.edge_threshold);
  }
  std::vector<cv::Point> usable;
  for (int y = inside.y; y < inside.y + inside.height; ++y)
    for (int x = inside.x; x < inside.x + inside.width; ++x) {
      if (saturated.at<std::uint8_t>(y, x)) continue;
      if (weight.at<double>(y, x) > 0) usable.emplace_back(x, y);
      else ++acc.low_weight;
    }
  if (static_cast<int>(usable.size()) < options.min_pixels) {
    std::ostringstream why;
    why << "fit: the pair has no usable edges: " << usable.size() << " edge pixels (need at least "
        << options.min_pixels << "; " << acc.low_weight << " low-weight, " << acc.saturated << " saturated, "
        << acc.border << " border of " << acc.total << "). The sharp and blurred images must show edges "
        << "(Claim 1: flat regions carry no information about the CRF)";
    throw InvalidInput(why.str());
  }
  if (options.objective != CrfObjective::seed_intensity && options.max_pixels > 0 &&
      static_cast<int>(usable.size()) > options.max_pixels) {
    std::mt19937 rng(12345);
    std::shuffle(usable.begin(), usable.end(), rng);
    acc.subsampled = static_cast<int>(usable.size()) - options.max_pixels;
    usable.resize(options.max_pixels);
    std::sort(usable.begin(), usable.end(), [](const cv::Point& a, const cv::Point& b) {
      return a.y != b.y ? a.y < b.y : a.x < b.x;
    });
  }
  acc.used = static_cast<int>(usable.size());
  acc.used_mask = cv::Mat::zeros(sharp.size(), CV_8U);
  prep.pixels = usable;
  for (const auto& p : usable) {
    acc.used_mask.at<std::uint8_t>(p) = 255;
    prep.seed_weight.push_back(weight.at<double>(p));
    prep.fold.push_back(((p.x / 16) + (p.y / 16)) % 2);
    prep.b_value.push_back(pixelValue(prep.blurred, p.y, p.x));
    prep.b_lo.push_back(prep.blurred.lo.at<std::uint16_t>(p));
    prep.b_frac.push_back(prep.blurred.frac.empty() ? 0.0 : prep.blurred.frac.at<float>(p));
  }
  result.timings.prepare_s = secondsSince(t_start);
  report(0.1, "mixtures");

  const auto t_mix = Clock::now();
  prep.mixture = LevelMixture::build(prep.sharp, kernel, prep.pixels);
  result.mixture_nonzeros = prep.mixture.nonZeros();
  result.timings.mixture_s = secondsSince(t_mix);

  const Curve ggcm_curve(Curve::kGgcm, L, options.ggcm_degree);
  const Curve emor_curve(Curve::kEmor, L, options.emor_terms);
  const bool want_ggcm = options.model != CrfModelChoice::emor;
  const bool want_emor = options.model != CrfModelChoice::ggcm;
  const int n_eval = options.max_evaluations;
  double ratio = options.initial_ratio;
  std::vector<CrfCandidate> candidates;

  const auto t_opt = Clock::now();
  if (options.objective == CrfObjective::instrumental) {
    // Errors in variables by instrumental variables (GMM). In the irradiance domain the residual
    //   r_p(φ) = φ(B_p) − r Σ_v w_p(v) (Rφ)(x_v)
    // has zero mean at the true φ (the debiased mixture is unbiased, B is noise-free), and is linear in the
    // EMoR coefficients. Instruments built from B alone (independent of I's noise): H_j(B_p) and
    // (H_j(B) ⊗ K)(p) for the EMoR functions H_0..H_K. Two-stage least squares with weights ω_p = 1/φ'(B_p)²
    // (intensity-domain scale, from the previous iterate). No trivial solution: φ(0) = 0, φ(1) = 1 are built in.
    const int K = options.emor_terms;
    const int n = static_cast<int>(prep.pixels.size());
    std::vector<std::vector<double>> hb(K + 1, std::vector<double>(n)), mix(K + 1, std::vector<double>(n));
    std::vector<std::vector<double>> inst;
    for (int j = 0; j <= K; ++j) {
      const std::vector<double> hj(emor_curve.emorLevels(j), emor_curve.emorLevels(j) + L);
      for (int i = 0; i < n; ++i) hb[j][i] = phiAtB(prep, hj, i);
      const std::vector<double> gj = prep.debias.apply(hj);
      prep.mixture.mix(gj, mix[j]);
      // instruments
      cv::Mat hbimg(blurred.size(), CV_64F);
      for (int y = 0; y < blurred.rows; ++y)
        for (int x = 0; x < blurred.cols; ++x) {
          const int lo = prep.blurred.lo.at<std::uint16_t>(y, x);
          const double t = prep.blurred.frac.empty() ? 0.0 : prep.blurred.frac.at<float>(y, x);
          hbimg.at<double>(y, x) = t > 0 ? (1 - t) * hj[lo] + t * hj[lo + 1] : hj[lo];
        }
      const cv::Mat conv = convolve(hbimg, kernel);
      std::vector<double> z1(n), z2(n);
      for (int i = 0; i < n; ++i) {
        z1[i] = hb[j][i];
        z2[i] = conv.at<double>(prep.pixels[i]);
      }
      inst.push_back(std::move(z1));
      inst.push_back(std::move(z2));
    }
    const int J = static_cast<int>(inst.size());
    std::vector<double> phi_levels(L);
    for (int v = 0; v < L; ++v) phi_levels[v] = std::pow(double(v) / (L - 1), 2.2);
    std::vector<double> omega(n, 1.0);
    auto setWeights = [&](const std::vector<double>& f) {
      for (int i = 0; i < n; ++i) {
        const int lo = prep.b_lo[i];
        const int a = std::max(0, lo - 2), b = std::min(L - 1, lo + 2);
        const double slope = (f[b] - f[a]) / (double(b - a) / (L - 1));
        const double s = std::max(slope, 0.05);
        omega[i] = 1.0 / (s * s);
      }
    };
    // 2SLS on the pixels of `fold` (−1: all) at ratio r; returns the EMoR coefficients.
    auto solve = [&](int fold, double r) {
      Eigen::MatrixXd G = Eigen::MatrixXd::Zero(J, K), S = Eigen::MatrixXd::Zero(J, J);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(J);
      Eigen::VectorXd z(J);
      for (int i = 0; i < n; ++i) {
        if (fold >= 0 && prep.fold[i] != fold) continue;
        for (int j = 0; j < J; ++j) z[j] = inst[j][i];
        const double alpha = hb[0][i] - r * mix[0][i];
        for (int k = 1; k <= K; ++k) G.col(k - 1) += omega[i] * z * (hb[k][i] - r * mix[k][i]);
        g += omega[i] * z * alpha;
        S += omega[i] * omega[i] * z * z.transpose();
      }
      S.diagonal().array() += 1e-12 * std::max(1e-300, S.trace() / J);
      const Eigen::MatrixXd W = S.ldlt().solve(Eigen::MatrixXd::Identity(J, J));
      Eigen::MatrixXd A = G.transpose() * W * G;
      A.diagonal().array() += 1e-12 * std::max(1e-300, A.trace() / K);
      const Eigen::VectorXd c = A.ldlt().solve(-(G.transpose() * W * g));
      return std::vector<double>(c.data(), c.data() + K);
    };
    // GMM criterion of any φ (on the level grid) on a fold: mean moment norm ḡᵀ W ḡ.
    auto criterion = [&](const std::vector<double>& f, int fold, double r) {
      std::vector<double> gf = prep.debias.apply(f), m(n);
      prep.mixture.mix(gf, m);
      Eigen::VectorXd g = Eigen::VectorXd::Zero(J), z(J);
      Eigen::MatrixXd S = Eigen::MatrixXd::Zero(J, J);
      double wsum = 0;
      for (int i = 0; i < n; ++i) {
        if (fold >= 0 && prep.fold[i] != fold) continue;
        for (int j = 0; j < J; ++j) z[j] = inst[j][i];
        const double res = phiAtB(prep, f, i) - r * m[i];
        g += omega[i] * z * res;
        S += omega[i] * omega[i] * z * z.transpose();
        wsum += omega[i];
      }
      if (wsum <= 0) return std::numeric_limits<double>::quiet_NaN();
      S.diagonal().array() += 1e-12 * std::max(1e-300, S.trace() / J);
      return g.dot(S.ldlt().solve(g));
    };
    auto monotoneEmor = [&](std::vector<double> c) {
      if (isValid(EmorModel{c})) return c;
      emor::FitOptions eo;
      eo.terms = K;
      eo.enforce_monotone = true;
      const auto fit = emor::fitInverse(sampleInverse(EmorModel{c}, kGrid), eo);
      return fit.model.coefficients;
    };
    auto projectGgcm = [&](const std::vector<double>& c) {
      ggcm::FitOptions go;
      go.degree = options.ggcm_degree;
      return ggcm::fitInverse(sampleInverse(EmorModel{c}, kGrid), go);
    };
    std::vector<double> c(K, 0.0);
    for (int round = 0; round < options.irls_rounds + 1; ++round) {
      setWeights(phi_levels);
      const int rounds = options.fit_ratio ? options.ratio_rounds : 1;
      for (int rr = 0; rr < rounds; ++rr) {
        c = monotoneEmor(solve(-1, ratio));
        ++result.iterations;
        std::vector<double> f;
        emor_curve.values(c.data(), f, nullptr);
        phi_levels = f;
        if (!options.fit_ratio) break;
        // r by IV (Eq. 25 with the noise-free instrument s_p = (φ(B) ⊗ K)(p) in place of the noisy mixture)
        std::vector<double> gf = prep.debias.apply(f), m(n);
        prep.mixture.mix(gf, m);
        cv::Mat fb(blurred.size(), CV_64F);
        for (int y = 0; y < blurred.rows; ++y)
          for (int x = 0; x < blurred.cols; ++x) {
            const int lo = prep.blurred.lo.at<std::uint16_t>(y, x);
            const double t = prep.blurred.frac.empty() ? 0.0 : prep.blurred.frac.at<float>(y, x);
            fb.at<double>(y, x) = t > 0 ? (1 - t) * f[lo] + t * f[lo + 1] : f[lo];
          }
        const cv::Mat sconv = convolve(fb, kernel);
        double num = 0, den = 0;
        for (int i = 0; i < n; ++i) {
          const double s = sconv.at<double>(prep.pixels[i]);
          num += omega[i] * s * phiAtB(prep, f, i);
          den += omega[i] * s * m[i];
        }
        const double next = den > 0 ? std::clamp(num / den, 0.05, 20.0) : ratio;
        const bool converged = std::abs(next - ratio) < 1e-7 * ratio;
        ratio = next;
        if (converged) break;
      }
      report(0.1 + 0.8 * (round + 1) / (options.irls_rounds + 1), "optimise");
    }
    const bool cv_needed = options.model == CrfModelChoice::automatic;
    auto levelsOf = [&](const ResponseModel& model) {
      std::vector<double> f(L);
      for (int v = 0; v < L; ++v) f[v] = evaluateInverse(model, double(v) / (L - 1));
      return f;
    };
    double crit_emor = 0, crit_ggcm = 0;
    if (cv_needed) {
      for (int fold = 0; fold < 2; ++fold) {
        const std::vector<double> cf = monotoneEmor(solve(fold, ratio));
        crit_emor += criterion(levelsOf(EmorModel{cf}), 1 - fold, ratio);
        const auto gp = projectGgcm(cf);
        crit_ggcm += gp.valid ? criterion(levelsOf(gp.model), 1 - fold, ratio) : std::numeric_limits<double>::infinity();
      }
    }
    if (want_emor) {
      CrfCandidate e;
      e.kind = "emor";
      e.model = EmorModel{c};
      e.valid = isValid(e.model);
      e.ratio = ratio;
      e.energy = criterion(levelsOf(e.model), -1, ratio);
      e.criterion = cv_needed ? crit_emor : e.energy;
      candidates.push_back(e);
    }
    if (want_ggcm) {
      const auto gp = projectGgcm(c);
      CrfCandidate g;
      g.kind = "ggcm";
      g.model = gp.model;
      g.valid = gp.valid && isValid(g.model);
      g.ratio = ratio;
      g.energy = criterion(levelsOf(g.model), -1, ratio);
      g.criterion = cv_needed ? crit_ggcm : g.energy;
      candidates.push_back(g);
    }
  } else
  if (options.objective != CrfObjective::corrected_irradiance) {
    const bool aware = options.objective == CrfObjective::noise_aware_intensity;
    double wsum = 0;
    for (double w : prep.seed_weight) wsum += w * w;
    for (const Curve* curve : {&ggcm_curve, &emor_curve}) {
      if ((curve == &ggcm_curve && !want_ggcm) || (curve == &emor_curve && !want_emor)) continue;
      SeedObjective objective{&prep, curve, debias, options.initial_ratio, wsum, {}, {}, {}};
      objective.variance_correction = aware && debias && !prep.debias.identity();
      std::vector<double> x = curve == &ggcm_curve ? ggcm::fromGamma(2.2, options.ggcm_degree).alpha
                                                   : std::vector<double>(curve->dims(), 0.0);
      if (aware && options.multi_starts > 1) {  // best of a few starts by energy
        double best = objective.energy(x);
        const std::vector<double> gammas{1.6, 3.0, 1.0};
        for (int k = 0; k + 1 < options.multi_starts && k < 3; ++k) {
          const std::vector<double> cand = curve == &ggcm_curve ? ggcm::fromGamma(gammas[k], options.ggcm_degree).alpha
                                                                : std::vector<double>(curve->dims(), 0.0);
          if (curve != &ggcm_curve) break;
          const double e = objective.energy(cand);
          if (e < best) { best = e; x = cand; }
        }
      }
      int evaluations = 0;
      if (aware && options.fit_ratio) {
        // crfcal: φ and r jointly (alternating φ-steps and Eq. 25 crawls along the φ/r valley); log r is the
        // extra parameter, started from the noise-corrected Eq. 25 value.
        objective.ratio = std::clamp(objective.ratioStep(x), 0.5 * options.initial_ratio, 2.0 * options.initial_ratio);
        std::vector<double> xr = x;
        xr.push_back(std::log(objective.ratio));
        const std::size_t dims = x.size();
        auto joint = [&](const std::vector<double>& v, std::vector<double>* g) {
          SeedObjective local = objective;
          local.ratio = std::exp(v[dims]);
          const std::vector<double> params(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(dims));
          const double value = local.energy(params);
          if (g) {
            std::vector<double> vp = v;
            for (std::size_t j = 0; j < v.size(); ++j) {
              const double hs = 1e-6 * std::max(1.0, std::abs(v[j]));
              vp[j] = v[j] + hs;
              local.ratio = std::exp(vp[dims]);
              const double a = local.energy(std::vector<double>(vp.begin(), vp.begin() + static_cast<std::ptrdiff_t>(dims)));
              vp[j] = v[j] - hs;
              local.ratio = std::exp(vp[dims]);
              const double b = local.energy(std::vector<double>(vp.begin(), vp.begin() + static_cast<std::ptrdiff_t>(dims)));
              vp[j] = v[j];
              (*g)[j] = (a - b) / (2 * hs);
            }
          }
          return value;
        };
        const Minimum m = minimise(options.optimizer, xr, joint, n_eval, 0.05);
        evaluations += m.evaluations;
        x.assign(m.x.begin(), m.x.begin() + static_cast<std::ptrdiff_t>(dims));
        objective.ratio = std::exp(m.x[dims]);
        ++result.iterations;
      }
      const int rounds = (aware && options.fit_ratio) ? 0 : (options.fit_ratio ? options.ratio_rounds : 1);
      for (int round = 0; round < rounds; ++round) {
        const Minimum m = minimise(options.optimizer, x,
                                   [&](const std::vector<double>& v, std::vector<double>* g) { return objective(v, g); },
                                   n_eval, 0.05);
        x = m.x;
        evaluations += m.evaluations;
        ++result.iterations;
        report(0.1 + 0.8 * (round + 1) / rounds, "optimise");
        if (!options.fit_ratio) break;
        const double next = std::clamp(objective.ratioStep(x), 0.05, 20.0);
        const bool converged = std::abs(next - objective.ratio) < 1e-6 * objective.ratio;
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
    // Iteratively reweighted corrected objective. Round 0: ω = 1 (bins carry the slope); later rounds: ω_p =
    // (bin secant / φ'(B_p))² of the previous iterate.
    const int bins = L > 256 ? 1 : 8;
    std::vector<double> phi_levels;  // previous iterate on the level grid
    std::vector<double> omega(prep.pixels.size(), 1.0);
    QuadraticForms forms;
    std::vector<double> x_ggcm, x_emor;
    double e_ggcm = std::numeric_limits<double>::infinity(), e_emor = e_ggcm;
    bool v_ggcm = false, v_emor = false;
    {
      std::vector<double> g22(L);
      for (int v = 0; v < L; ++v) g22[v] = std::pow(double(v) / (L - 1), 2.2);
      phi_levels = g22;
    }
    auto ggcmStarts = [&](const std::vector<double>* extra) {
      std::vector<std::vector<double>> starts;
      if (!x_ggcm.empty()) starts.push_back(x_ggcm);
      if (extra) starts.push_back(*extra);
      for (double gamma : {2.2, 1.6, 3.0, 1.0}) starts.push_back(ggcm::fromGamma(gamma, options.ggcm_degree).alpha);
      if (static_cast<int>(starts.size()) > options.multi_starts) starts.resize(options.multi_starts);
      return starts;
    };
    auto ratioStep = [&](const std::vector<double>& f, double current) {
      // r minimising Σ_b s_b fᵀ(Q0 + r Q1 + r² Q2) f
      QuadraticObjective probe{nullptr, nullptr, {}, {}};
      (void)probe;
      Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
      double a = 0, b = 0;
      for (int bin = 0; bin < forms.bins; ++bin) {
        const int lo = forms.edge[bin], hi = forms.edge[bin + 1];
        const double hb = double(hi - lo) / (L - 1);
        const double delta = std::max(f[hi] - f[lo], 1e-9);
        const double s = hb * hb / (delta * delta);
        for (int fold = 0; fold < 2; ++fold) {
          a += s * fv.dot(forms.q2[fold][bin] * fv);
          b += s * fv.dot(forms.q1[fold][bin] * fv);
        }
      }
      return a > 0 ? std::clamp(-b / (2 * a), 0.05, 20.0) : current;
    };
    for (int round = 0; round < options.irls_rounds; ++round) {
      if (round > 0) {
        for (std::size_t i = 0; i < omega.size(); ++i) {
          const int lo = prep.b_lo[i];
          const int bin = forms.binOf(lo);
          const int e0 = forms.edge[bin], e1 = forms.edge[bin + 1];
          const double secant = (phi_levels[e1] - phi_levels[e0]) / double(e1 - e0);
          const int j0 = std::max(0, lo - 1), j1 = std::min(L - 1, lo + 1);
          const double local = (phi_levels[j1] - phi_levels[j0]) / double(j1 - j0);
          const double ratio_w = secant / std::max(local, 0.2 * secant);
          omega[i] = std::clamp(ratio_w * ratio_w, 0.04, 25.0);
        }
      }
      const auto t_forms = Clock::now();
      forms = buildForms(prep, omega, threads, bins);
      result.timings.mixture_s += secondsSince(t_forms);
      const int rounds = options.fit_ratio ? options.ratio_rounds : 1;
      for (int rr = 0; rr < rounds; ++rr) {
        const BinnedForm form = formAt(forms, ratio, -1);
        std::vector<double> emor_start_alpha;
        {  // EMoR (also seeds the GGCM search)
          const FitOutcome e = fitEmor(emor_curve, form, phi_levels, options);
          result.evaluations += e.evaluations;
          x_emor = e.x;
          e_emor = e.value;
          v_emor = e.valid;
          if (want_ggcm && e.valid) {
            ggcm::FitOptions go;
            go.degree = options.ggcm_degree;
            const auto projected = ggcm::fitInverse(sampleInverse(EmorModel{e.x}, kGrid), go);
            if (projected.valid) emor_start_alpha = projected.model.alpha;
          }
        }
        if (want_ggcm) {
          QuadraticObjective objective{&ggcm_curve, &form, {}, {}};
          const FitOutcome g = fitGgcm(
              ggcm_curve, [&](const std::vector<double>& v, std::vector<double>* gr) { return objective(v, gr); },
              ggcmStarts(emor_start_alpha.empty() ? nullptr : &emor_start_alpha), options.optimizer, n_eval,
              [&](const std::vector<double>& v) { return objective.plain(v); });
          result.evaluations += g.evaluations;
          x_ggcm = g.x;
          e_ggcm = g.value;
          v_ggcm = g.valid;
        }
        ++result.iterations;
        report(0.1 + 0.8 * (round * rounds + rr + 1) / (options.irls_rounds * rounds), "optimise");
        // the better valid model (of those asked for) drives r and the next weights
        const bool use_ggcm = want_ggcm && v_ggcm && (!want_emor || !v_emor || e_ggcm <= e_emor);
        const Curve& curve = use_ggcm ? ggcm_curve : emor_curve;
        const std::vector<double>& x = use_ggcm ? x_ggcm : x_emor;
        std::vector<double> f;
        if (x.empty() || !curve.values(x.data(), f, nullptr) || !monotone(f)) break;
        phi_levels = f;
        if (!options.fit_ratio) break;
        const double next = ratioStep(f, ratio);
        const bool converged = std::abs(next - ratio) < 1e-7 * ratio;
        ratio = next;
        if (converged) break;
      }
    }
    // Candidates with 2-fold cross-validated energies at the final r and weights.
    auto crossValidate = [&](const Curve& curve, const std::vector<double>& x_full) {
      double total = 0, weight = 0;
      for (int fold = 0; fold < 2; ++fold) {
        const BinnedForm fit_form = formAt(forms, ratio, fold), test_form = formAt(forms, ratio, 1 - fold);
        if (forms.weight[0] <= 0 || forms.weight[1] <= 0) return std::numeric_limits<double>::quiet_NaN();
        std::vector<double> x;
        if (curve.kind() == Curve::kEmor) {
          x = fitEmor(curve, fit_form, phi_levels, options).x;
        } else {
          QuadraticObjective objective{&curve, &fit_form, {}, {}};
          x = fitGgcm(curve, [&](const std::vector<double>& v, std::vector<double>* gr) { return objective(v, gr); },
                      {x_full}, options.optimizer, n_eval, [&](const std::vector<double>& v) { return objective.plain(v); })
                  .x;
        }
        QuadraticObjective test{&curve, &test_form, {}, {}};
        total += test.plain(x) * test_form.weight;
        weight += test_form.weight;
      }
      return total / weight;
    };
    const bool cross_validate = options.model == CrfModelChoice::automatic;
    if (want_emor && !x_emor.empty()) {
      CrfCandidate c;
      c.kind = "emor";
      c.model = emor_curve.model(x_emor);
      c.valid = v_emor && isValid(c.model);
      c.ratio = ratio;
      c.energy = e_emor;
      c.criterion = cross_validate ? crossValidate(emor_curve, x_emor) : e_emor;
      candidates.push_back(c);
    }
    if (want_ggcm && !x_ggcm.empty()) {
      CrfCandidate c;
      c.kind = "ggcm";
      c.model = ggcm_curve.model(x_ggcm);
      c.valid = v_ggcm && isValid(c.model);
      c.ratio = ratio;
      c.energy = e_ggcm;
      c.criterion = cross_validate ? crossValidate(ggcm_curve, x_ggcm) : e_ggcm;
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
  for (auto& c : candidates) c.inverse_crf = sampleInverse(c.model, kCurveSamples);
  if (best) {
    result.model = best->model;
    result.ratio = best->ratio;
    result.energy = best->energy;
    result.chosen = best->kind;
    if (candidates.size() == 1) result.choice_reason = std::string("only ") + best->kind + " was fitted";
    else if (options.objective == CrfObjective::corrected_irradiance)
      result.choice_reason = "lower 2-fold cross-validated corrected energy";
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
  result.inverse_crf = sampleInverse(result.model, kCurveSamples);
  result.timings.total_s = secondsSince(t_start);
  report(1.0, "done");
  return result;
}

}  // namespace crfcal
