#include "crfcal/ggcm.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>
#include <nlopt.hpp>

#include "crfcal/error.hpp"

namespace crfcal::ggcm {
namespace {

constexpr double kMinimumP = 1e-3;  // P is kept above this during fitting (φ = x^(1/P) needs P > 0)

struct FitProblem {
  std::span<const double> x;
  std::span<const double> target;
  double penalty_weight;
};

// Least-squares cost Σ (φ(x_j) − target_j)² plus penalties for P ≤ kMinimumP and for decreasing φ.
double fitCost(const std::vector<double>& alpha, std::vector<double>& grad, void* data) {
  const auto& problem = *static_cast<const FitProblem*>(data);
  const size_t m = alpha.size();
  const size_t n = problem.x.size();
  if (!grad.empty()) std::fill(grad.begin(), grad.end(), 0.0);
  std::vector<double> phi(n), dphi(n * m);
  double cost = 0;
  for (size_t j = 0; j < n; ++j) {
    const double x = problem.x[j];
    double p = 0, power = 1;
    for (size_t i = 0; i < m; ++i, power *= x) p += alpha[i] * power;
    if (p < kMinimumP) {  // keep P positive; the clamped P makes φ continuous in α
      const double d = kMinimumP - p;
      cost += problem.penalty_weight * d * d;
      power = 1;
      for (size_t i = 0; i < m && !grad.empty(); ++i, power *= x) grad[i] -= 2 * problem.penalty_weight * d * power;
      p = kMinimumP;
    }
    if (x <= 0 || x >= 1) {
      phi[j] = x <= 0 ? 0.0 : 1.0;
      continue;
    }
    const double lx = std::log(x);
    phi[j] = std::exp(lx / p);
    power = 1;
    const bool clamped = p == kMinimumP;
    for (size_t i = 0; i < m; ++i, power *= x) dphi[j * m + i] = clamped ? 0.0 : -phi[j] * lx / (p * p) * power;
    const double r = phi[j] - problem.target[j];
    cost += r * r;
    for (size_t i = 0; i < m && !grad.empty(); ++i) grad[i] += 2 * r * dphi[j * m + i];
  }
  for (size_t j = 0; j + 1 < n; ++j) {  // monotonicity
    const double step = phi[j + 1] - phi[j];
    if (step >= 0) continue;
    cost += problem.penalty_weight * step * step;
    for (size_t i = 0; i < m && !grad.empty(); ++i)
      grad[i] += 2 * problem.penalty_weight * step * (dphi[(j + 1) * m + i] - dphi[j * m + i]);
  }
  return cost;
}

}  // namespace

double polynomial(std::span<const double> alpha, double x) {
  double p = 0;
  for (size_t i = alpha.size(); i-- > 0;) p = p * x + alpha[i];
  return p;
}

double evaluate(std::span<const double> alpha, double x) {
  if (x <= 0) return 0.0;
  if (x >= 1) return 1.0;
  const double p = polynomial(alpha, x);
  if (!(p > 0)) return std::numeric_limits<double>::quiet_NaN();
  return std::exp(std::log(x) / p);
}

void gradient(std::span<const double> alpha, double x, std::span<double> out) {
  std::fill(out.begin(), out.end(), 0.0);
  if (x <= 0 || x >= 1) return;
  const double p = polynomial(alpha, x);
  const double lx = std::log(x);
  const double phi = std::exp(lx / p);
  double power = 1;
  for (size_t i = 0; i < alpha.size(); ++i, power *= x) out[i] = -phi * lx / (p * p) * power;
}

GgcmModel identity(int degree) { return fromGamma(1.0, degree); }

GgcmModel fromGamma(double gamma, int degree) {
  if (!(gamma > 0)) throw InvalidInput("gamma must be positive");
  GgcmModel model;
  model.alpha.assign(static_cast<size_t>(degree) + 1, 0.0);
  model.alpha[0] = 1.0 / gamma;
  return model;
}

FitResult fitInverse(std::span<const double> phi_samples, const FitOptions& options) {
  if (phi_samples.size() < 8) throw InvalidInput("GGCM fit needs at least 8 curve samples");
  if (options.degree < 0 || options.degree > 12) throw InvalidInput("GGCM degree must be in 0..12");
  const size_t n = phi_samples.size();
  const size_t m = static_cast<size_t>(options.degree) + 1;
  std::vector<double> x(n);
  for (size_t j = 0; j < n; ++j) x[j] = double(j) / double(n - 1);

  // Linearised start: ln φ = ln x / P(x)  ⇒  P(x_j) = ln x_j / ln φ_j, a linear least-squares problem in α.
  std::vector<Eigen::RowVectorXd> rows;
  std::vector<double> rhs;
  for (size_t j = 0; j < n; ++j) {
    const double phi = phi_samples[j];
    if (x[j] < 0.01 || x[j] > 0.99 || phi <= 1e-6 || phi >= 1 - 1e-6) continue;
    const double p = std::log(x[j]) / std::log(phi);
    if (!std::isfinite(p) || p <= 0 || p > 100) continue;
    Eigen::RowVectorXd row(static_cast<Eigen::Index>(m));
    double power = 1;
    for (size_t i = 0; i < m; ++i, power *= x[j]) row[static_cast<Eigen::Index>(i)] = power;
    rows.push_back(row);
    rhs.push_back(p);
  }
  std::vector<double> alpha(m, 0.0);
  alpha[0] = 1.0;
  if (rows.size() >= m) {
    Eigen::MatrixXd a(static_cast<Eigen::Index>(rows.size()), static_cast<Eigen::Index>(m));
    Eigen::VectorXd b(static_cast<Eigen::Index>(rows.size()));
    for (size_t r = 0; r < rows.size(); ++r) {
      a.row(static_cast<Eigen::Index>(r)) = rows[r];
      b[static_cast<Eigen::Index>(r)] = rhs[r];
    }
    const Eigen::VectorXd solution = a.colPivHouseholderQr().solve(b);
    std::vector<double> start(solution.data(), solution.data() + m);
    if (checkValidity(GgcmModel{start}, 1024, 1e-9)) alpha = start;
  }

  FitProblem problem{x, phi_samples, 1e4};
  nlopt::opt optimizer(nlopt::LD_LBFGS, static_cast<unsigned>(m));
  optimizer.set_min_objective(fitCost, &problem);
  optimizer.set_ftol_rel(options.tolerance);
  optimizer.set_maxeval(options.max_evaluations);
  double cost = 0;
  std::vector<double> refined = alpha;
  try {
    optimizer.optimize(refined, cost);
  } catch (const nlopt::roundoff_limited&) {
    // the best point so far is in `refined`
  } catch (const std::runtime_error&) {
    refined = alpha;
  }
  FitResult result;
  auto score = [&](const std::vector<double>& candidate, double& rmse, double& max_error) {
    double sum = 0;
    max_error = 0;
    for (size_t j = 0; j < n; ++j) {
      const double e = std::abs(evaluate(candidate, x[j]) - phi_samples[j]);
      sum += e * e;
      max_error = std::max(max_error, std::isfinite(e) ? e : 1e9);
    }
    rmse = std::sqrt(sum / double(n));
    if (!std::isfinite(rmse)) rmse = 1e9;
  };
  double rmse_start = 0, max_start = 0;
  score(alpha, rmse_start, max_start);
  score(refined, result.rmse, result.max_error);
  const bool refined_valid = static_cast<bool>(checkValidity(GgcmModel{refined}, 4096, 1e-9));
  if (!refined_valid || result.rmse > rmse_start) {
    refined = alpha;
    result.rmse = rmse_start;
    result.max_error = max_start;
  }
  result.model = GgcmModel{refined};
  result.valid = static_cast<bool>(checkValidity(result.model, 4096, 1e-9));
  return result;
}

}  // namespace crfcal::ggcm
