#include "crf_optimisation.hpp"

#include <algorithm>
#include <cmath>
#include <exception>

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <nlopt.hpp>

#include "parallel_jobs.hpp"

namespace crfcal::crf_fit {

Minimum nelderMead(const std::vector<double>& x0, const std::function<double(const std::vector<double>&)>& objective,
                   int max_evaluations, double step, double ftol) {
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

// Kept hand-written, measured against Eigen's unsupported LevenbergMarquardt (MINPACK lmder; adapter: a step outside
// the model's domain returned as a residual of 10¹⁰⁰ so the trust region rejects it, maxfev 10 × max_iterations,
// ftol = xtol = 1e-12): `bench synthetic --method both -q` default mean RMSE 0.0272/0.0305/0.0291 → 0.0270/0.0302/
// 0.0291, shape 0.0052 → 0.0053 at σ² = 0.005, 353 → 360 evaluations for the speed line's fit (fit times were not
// comparable: both runs shared 2 cores at load ~20); `bench pairs --ratio 2` identical on the 6 cases measured.
// The tables must stay identical (issue 16), so this one stays: Marquardt's diagonal damping λ·diag(JᵀJ) with
// LDLᵀ steps, and a step outside the domain (false from `residuals`) rejected like a rise in cost.
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

namespace {

// EMoR's starts: the residual is linear in the coefficients c for fixed r, so the least-squares c at r0; and the
// mean curve (c = 0).
std::vector<std::vector<double>> emorLinearStarts(const Curve& curve, const MomentSystem& sys, double r0) {
  const int L = sys.levels();
  const int d = curve.dims();
  std::vector<double> f0, jf;
  const std::vector<double> zero(d, 0.0);
  curve.values(zero.data(), f0, &jf);
  Eigen::Map<const Eigen::VectorXd> b0(f0.data(), L);
  Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> e(jf.data(), d, L);
  const Eigen::MatrixXd a = r0 * sys.h - sys.n;
  const Eigen::MatrixXd m = a * e.transpose();
  const Eigen::VectorXd y = -(a * b0);
  const Eigen::VectorXd c = m.colPivHouseholderQr().solve(y);
  return {std::vector<double>(c.data(), c.data() + d), zero};
}

// The closed-form r of the moments at φ: argmin_r ‖r H φ − N φ‖ (clamped to the fitter's range, crf_fitter.hpp).
double profiledRatio(const MomentSystem& sys, const std::vector<double>& f) {
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), sys.levels());
  const Eigen::VectorXd hf = sys.h * fv, nf = sys.n * fv;
  return std::clamp(hf.dot(nf) / std::max(hf.squaredNorm(), 1e-300), kMinExposureRatio, kMaxExposureRatio);
}

// Levenberg–Marquardt from each non-empty start (the model's parameters, then log r when it is fitted); the lowest
// cost wins, the earlier start on a tie. `evaluations_per_call`: energy evaluations one residual call costs (for the
// fit's counters). The starts are independent runs of a pure residual function: one per core (inside a job that
// already runs in parallel, e.g. a band refit, they run serially), with the result of a serial loop.
ModelFit bestOfStarts(const Curve& curve, const std::vector<std::vector<double>>& starts, double r0, bool fit_ratio,
                      const ResidualFn& fn, int max_iterations, int evaluations_per_call) {
  const int d = curve.dims();
  std::vector<LmResult> runs(starts.size());
  const std::vector<std::exception_ptr> errors =
      detail::runInParallel(static_cast<int>(starts.size()), [&](int i) {
        const std::vector<double>& s = starts[static_cast<std::size_t>(i)];
        if (s.empty()) return;
        Eigen::VectorXd p(d + (fit_ratio ? 1 : 0));
        for (int j = 0; j < d; ++j) p[j] = s[j];
        if (fit_ratio) p[d] = std::log(r0);
        runs[static_cast<std::size_t>(i)] = levenbergMarquardt(p, fn, max_iterations);
      });
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
  ModelFit best;
  for (std::size_t i = 0; i < starts.size(); ++i) {
    if (starts[i].empty()) continue;
    const LmResult& lm = runs[i];
    best.evaluations += lm.evaluations * evaluations_per_call;
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

}  // namespace

ModelFit fitModelMoments(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                         double r0, bool fit_ratio, int max_iterations, bool with_prior) {
  const MomentResiduals residuals(curve, sys, r0, fit_ratio, with_prior);
  const ResidualFn fn = std::cref(residuals);
  if (curve.kind() == Curve::kEmor && starts.empty()) starts = emorLinearStarts(curve, sys, r0);
  return bestOfStarts(curve, starts, r0, fit_ratio, fn, max_iterations, 1);
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
  // Each residual call also evaluates d + 1 finite-difference columns: counted as energy evaluations.
  return bestOfStarts(curve, starts, r0, fit_ratio, fn, max_iterations, d + 2);
}

ModelFit fitGgcmNelderMead(const Curve& ggcm_curve, const MomentSystem& full,
                           const std::vector<std::vector<double>>& starts, double ratio, bool fit_ratio,
                           int max_evaluations) {
  ModelFit nm;
  for (const auto& s : starts) {
    auto energy = [&](const std::vector<double>& x) {
      std::vector<double> f;
      if (!ggcm_curve.values(x.data(), f, nullptr) || !monotone(f)) return 1e6;
      const double r = fit_ratio ? profiledRatio(full, f) : ratio;
      const double e = momentEnergy(full, f, r);
      return std::isfinite(e) ? e : 1e6;
    };
    const Minimum m = nelderMead(s, energy, max_evaluations, 0.05, 1e-12);
    nm.evaluations += m.evaluations;
    if (m.value < nm.energy) {
      nm.energy = m.value;
      nm.x = m.x;
    }
  }
  std::vector<double> f;
  ggcm_curve.values(nm.x.data(), f, nullptr);
  nm.ratio = fit_ratio ? profiledRatio(full, f) : ratio;
  nm.valid = isValid(ggcm_curve.model(nm.x));
  return nm;
}

SeedFit alternateRatio(SeedObjective& objective, std::vector<double> x, const CrfFitOptions& options,
                       const std::function<void(double fraction)>& progress) {
  SeedFit fit;
  const int rounds = options.fit_ratio ? options.experimental.ratio_rounds : 1;
  for (int round = 0; round < rounds; ++round) {
    const Minimum m = nelderMead(x, [&](const std::vector<double>& v) { return objective.energy(v); },
                                 options.max_evaluations, 0.05);
    x = m.x;
    fit.evaluations += m.evaluations;
    ++fit.rounds;
    progress(double(round + 1) / rounds);
    if (!options.fit_ratio) break;
    const double next = std::clamp(objective.ratioStep(x), kMinExposureRatio, kMaxExposureRatio);
    const bool converged = std::abs(next - objective.ratio) < 1e-4 * objective.ratio;
    objective.ratio = next;
    if (converged) break;
  }
  fit.x = std::move(x);
  return fit;
}

}  // namespace crfcal::crf_fit
