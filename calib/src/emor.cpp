#include "crfcal/emor.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>
#include <nlopt.hpp>

#include "crfcal/error.hpp"

// Generated at build time from samples/emor/{invemor,emor}.txt: rows are B|E, g0|f0, h(1..25).
extern const double crfcal_emor_inverse[27][1024];
extern const double crfcal_emor_forward[27][1024];

namespace crfcal::emor {
namespace {

void checkTerm(int k) {
  if (k < 1 || k > kMaxTerms) throw InvalidInput("EMoR basis index must be in 1..25");
}

// Basis value at x by linear interpolation of a 1024-sample curve.
double at(std::span<const double, kSamples> curve, double x) {
  const double position = std::clamp(x, 0.0, 1.0) * (kSamples - 1);
  const int i = std::min(static_cast<int>(position), kSamples - 2);
  const double t = position - i;
  return curve[static_cast<size_t>(i)] + t * (curve[static_cast<size_t>(i) + 1] - curve[static_cast<size_t>(i)]);
}

struct LinearConstraint {
  Eigen::RowVectorXd a;  // a·c + b ≥ 0
  double b;
};

double quadraticCost(unsigned n, const double* c, double* grad, void* data) {
  const auto& [hessian, linear] = *static_cast<std::pair<Eigen::MatrixXd, Eigen::VectorXd>*>(data);
  const Eigen::Map<const Eigen::VectorXd> coefficients(c, n);
  if (grad) Eigen::Map<Eigen::VectorXd>(grad, n) = 2 * (hessian * coefficients + linear);
  return coefficients.dot(hessian * coefficients) + 2 * linear.dot(coefficients);
}

double linearConstraint(unsigned n, const double* c, double* grad, void* data) {
  const auto& constraint = *static_cast<LinearConstraint*>(data);
  if (grad) Eigen::Map<Eigen::RowVectorXd>(grad, n) = -constraint.a;
  return -(constraint.a.dot(Eigen::Map<const Eigen::VectorXd>(c, n)) + constraint.b);  // ≤ 0 form
}

}  // namespace

std::span<const double, kSamples> inverseMean() { return std::span<const double, kSamples>(crfcal_emor_inverse[1], kSamples); }
std::span<const double, kSamples> inverseBasis(int k) {
  checkTerm(k);
  return std::span<const double, kSamples>(crfcal_emor_inverse[k + 1], kSamples);
}
std::span<const double, kSamples> forwardMean() { return std::span<const double, kSamples>(crfcal_emor_forward[1], kSamples); }
std::span<const double, kSamples> forwardBasis(int k) {
  checkTerm(k);
  return std::span<const double, kSamples>(crfcal_emor_forward[k + 1], kSamples);
}

FitResult fitInverse(std::span<const double> phi_samples, const FitOptions& options, std::span<const double> weights) {
  const auto n = static_cast<Eigen::Index>(phi_samples.size());
  const int terms = options.terms;
  if (n < 2) throw InvalidInput("EMoR fit needs at least 2 curve samples");
  if (terms < 0 || terms > kMaxTerms) throw InvalidInput("EMoR fit: terms must be in 0..25");
  if (!weights.empty() && weights.size() != phi_samples.size()) throw InvalidInput("EMoR fit: weights size mismatch");

  Eigen::MatrixXd basis(n, terms);
  Eigen::VectorXd residual_target(n), w = Eigen::VectorXd::Ones(n);
  for (Eigen::Index j = 0; j < n; ++j) {
    const double x = double(j) / double(n - 1);
    for (int k = 0; k < terms; ++k) basis(j, k) = at(inverseBasis(k + 1), x);
    residual_target[j] = phi_samples[static_cast<size_t>(j)] - at(inverseMean(), x);
    if (!weights.empty()) w[j] = std::max(0.0, weights[static_cast<size_t>(j)]);
  }
  const Eigen::MatrixXd weighted_basis = w.asDiagonal() * basis;
  Eigen::VectorXd coefficients = terms == 0 ? Eigen::VectorXd()
                                            : Eigen::VectorXd(weighted_basis.colPivHouseholderQr().solve(
                                                  Eigen::VectorXd(w.asDiagonal() * residual_target)));
  FitResult result;
  result.model.coefficients.assign(coefficients.data(), coefficients.data() + terms);

  if (options.enforce_monotone && terms > 0 && !checkValidity(result.model, kSamples, 1e-12)) {
    // Constrained least squares: minimise ‖W(Hc − t)‖² subject to φ(x_{i+1}) − φ(x_i) ≥ 0 on a grid.
    std::pair<Eigen::MatrixXd, Eigen::VectorXd> quadratic{
        weighted_basis.transpose() * weighted_basis,
        -(weighted_basis.transpose() * (w.asDiagonal() * residual_target))};
    std::vector<LinearConstraint> constraints;
    const int grid = std::max(8, options.monotone_grid);
    for (int i = 0; i + 1 < grid; ++i) {
      const double x0 = double(i) / (grid - 1), x1 = double(i + 1) / (grid - 1);
      LinearConstraint c{Eigen::RowVectorXd(terms), at(inverseMean(), x1) - at(inverseMean(), x0)};
      for (int k = 0; k < terms; ++k) c.a[k] = at(inverseBasis(k + 1), x1) - at(inverseBasis(k + 1), x0);
      constraints.push_back(std::move(c));
    }
    nlopt::opt optimizer(nlopt::LD_SLSQP, static_cast<unsigned>(terms));
    optimizer.set_min_objective(
        [](const std::vector<double>& c, std::vector<double>& g, void* d) {
          return quadraticCost(static_cast<unsigned>(c.size()), c.data(), g.empty() ? nullptr : g.data(), d);
        },
        &quadratic);
    for (auto& c : constraints)
      optimizer.add_inequality_constraint(
          [](const std::vector<double>& x, std::vector<double>& g, void* d) {
            return linearConstraint(static_cast<unsigned>(x.size()), x.data(), g.empty() ? nullptr : g.data(), d);
          },
          &c, 1e-12);
    optimizer.set_xtol_rel(1e-10);
    optimizer.set_maxeval(2000);
    std::vector<double> c(static_cast<size_t>(terms), 0.0);  // g0 alone is monotone: a feasible start
    double cost = 0;
    try {
      optimizer.optimize(c, cost);
    } catch (const nlopt::roundoff_limited&) {
    } catch (const std::runtime_error&) {
    }
    result.model.coefficients = c;
    result.constrained = true;
  }
  double sum = 0;
  for (Eigen::Index j = 0; j < n; ++j) {
    const double e = evaluateInverse(result.model, double(j) / double(n - 1)) - phi_samples[static_cast<size_t>(j)];
    sum += e * e;
    result.max_error = std::max(result.max_error, std::abs(e));
  }
  result.rmse = std::sqrt(sum / double(n));
  return result;
}

std::vector<double> fitForward(std::span<const double> psi_samples, int terms) {
  if (terms < 1 || terms > kMaxTerms) throw InvalidInput("EMoR fit: terms must be in 1..25");
  const auto n = static_cast<Eigen::Index>(psi_samples.size());
  Eigen::MatrixXd basis(n, terms);
  Eigen::VectorXd target(n);
  for (Eigen::Index j = 0; j < n; ++j) {
    const double x = double(j) / double(n - 1);
    for (int k = 0; k < terms; ++k) basis(j, k) = at(forwardBasis(k + 1), x);
    target[j] = psi_samples[static_cast<size_t>(j)] - at(forwardMean(), x);
  }
  const Eigen::VectorXd c = basis.colPivHouseholderQr().solve(target);
  return {c.data(), c.data() + terms};
}

std::vector<double> evaluateForward(std::span<const double> coefficients) {
  std::vector<double> psi(kSamples);
  for (int j = 0; j < kSamples; ++j) {
    double v = forwardMean()[static_cast<size_t>(j)];
    for (size_t k = 0; k < coefficients.size(); ++k) v += coefficients[k] * forwardBasis(static_cast<int>(k) + 1)[static_cast<size_t>(j)];
    psi[static_cast<size_t>(j)] = v;
  }
  return psi;
}

}  // namespace crfcal::emor
