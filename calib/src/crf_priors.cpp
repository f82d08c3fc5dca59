#include "crf_priors.hpp"

#include <cmath>

#include <Eigen/Cholesky>

#include "crfcal/emor.hpp"

namespace crfcal::crf_fit {
namespace {

// Nodes of the local-exponent terms: levels j·(L−1)/64, j = 1..64 (x = 0 has no logarithm).
std::vector<int> exponentNodes(int L) {
  std::vector<int> nodes;
  for (int j = 1; j <= 64; ++j) nodes.push_back(static_cast<int>(std::lround(j * (L - 1) / 64.0)));
  return nodes;
}

// The learned prior's rows (CrfFitOptions::learned_prior): g = E · log φ(nodes) on the fit's own node levels; the
// conditional N(offset + gain · g_O, C) of the unobserved exponents; rows √λ · C^{-1/2} (E_U − gain · E_O) log φ − d.
void setLearnedPrior(MomentSystem& sys, const CrfFitOptions& options, std::pair<int, int> covered_levels) {
  const int L = sys.levels();
  const std::vector<int> nodes = exponentNodes(L);
  const int n = static_cast<int>(nodes.size()), m = n - 1;
  const ConditionalExponents c = conditionOnCovered(
      *options.learned_prior, {double(covered_levels.first) / (L - 1), double(covered_levels.second) / (L - 1)});
  if (c.unobserved.empty()) return;
  Eigen::MatrixXd e = Eigen::MatrixXd::Zero(m, n);
  for (int j = 0; j < m; ++j) {
    const double dl = std::log(double(nodes[j + 1]) / nodes[j]);
    e(j, j) = -1 / dl;
    e(j, j + 1) = 1 / dl;
  }
  const int nu = static_cast<int>(c.unobserved.size());
  const Eigen::MatrixXd rows = e(c.unobserved, Eigen::all) - c.gain * e(c.observed, Eigen::all);
  const Eigen::LLT<Eigen::MatrixXd> chol(c.covariance);
  if (chol.info() != Eigen::Success) return;
  // The marginal of the exponents inside (with the observation noise): together with the conditional rows the
  // joint Gaussian p(g_O) p(g_U | g_O). It holds the shapes inside that the data leave free — the affine
  // a + bφ at r = 1 — to those of measured curves.
  const int no = static_cast<int>(c.observed.size());
  const Eigen::MatrixXd inside = e(c.observed, Eigen::all);
  const Eigen::VectorXd mean_o = options.learned_prior->mean(c.observed);
  Eigen::MatrixXd cov_o = options.learned_prior->covariance(c.observed, c.observed);
  cov_o.diagonal().array() += std::pow(options.learned_prior->observed_exponent_sigma, 2);
  const Eigen::LLT<Eigen::MatrixXd> chol_o(cov_o);
  if (no > 0 && chol_o.info() != Eigen::Success) return;
  const double w = std::sqrt(options.learned_prior_weight);
  sys.learned_nodes = nodes;
  sys.learned_matrix.resize(nu + no, n);
  sys.learned_offset.resize(nu + no);
  sys.learned_matrix.topRows(nu) = w * chol.matrixL().solve(rows);
  sys.learned_offset.head(nu) = w * chol.matrixL().solve(c.offset);
  if (no > 0) {
    sys.learned_matrix.bottomRows(no) = w * chol_o.matrixL().solve(inside);
    sys.learned_offset.tail(no) = w * chol_o.matrixL().solve(mean_o);
  }
}

}  // namespace

// The chains from the first node up to the lowest covered level and from the highest covered level up to 1 (one
// node inside the data links each chain to the exponent the data show). A triple belongs to a chain when an outer
// node lies outside the covered range — unless its middle node is inside and that outer node less than one node
// step outside (such a triple is data, not extrapolation).
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

std::vector<std::array<int, 2>> exponentPairs(int L) {
  const std::vector<int> nodes = exponentNodes(L);
  std::vector<std::array<int, 2>> pairs;
  for (std::size_t j = 0; j + 1 < nodes.size(); ++j) pairs.push_back({nodes[j], nodes[j + 1]});
  return pairs;
}

void setExtrapolationPrior(MomentSystem& sys, const CrfFitOptions& options, std::pair<int, int> covered_levels) {
  const int L = sys.levels();
  if (options.min_local_exponent > 0) {
    sys.exponent_pairs = exponentPairs(L);
    sys.min_exponent = options.min_local_exponent;
  }
  if (options.learned_prior && options.learned_prior_weight > 0) setLearnedPrior(sys, options, covered_levels);
  if (!(options.exponent_smoothness > 0)) return;
  sys.exponent_triples = exponentTriples(L, covered_levels.first, covered_levels.second);
  sys.exponent_weight = options.exponent_smoothness;
  sys.shoulder_weight = options.shoulder_prior;
  for (const auto& t : sys.exponent_triples) sys.exponent_upper.push_back(t[0] >= covered_levels.first);
  if (options.experimental.shoulder_follows_emor_mean) {
    const std::vector<double> g0 = onLevelGrid(emor::inverseMean(), L);
    auto logx = [L](int v) { return std::log(double(v) / (L - 1)); };
    auto ell = [&](int a, int b) { return (std::log(g0[b]) - std::log(g0[a])) / (logx(b) - logx(a)); };
    for (std::size_t i = 0; i < sys.exponent_triples.size(); ++i) {
      const auto& t = sys.exponent_triples[i];
      sys.shoulder_reference.push_back(sys.exponent_upper[i] ? ell(t[1], t[2]) - ell(t[0], t[1]) : 0.0);
    }
  }
}

void setRatioPrior(MomentSystem& sys, double residual_variance, const CrfFitOptions& options) {
  if (!(residual_variance > 0) || !(sys.weight > 0)) return;
  sys.ratio_prior_scale = std::sqrt(residual_variance / sys.weight) / options.ratio_prior_sigma;
  sys.ratio_prior_log_centre = std::log(options.nominal_ratio);
}

PriorRows::PriorRows(const MomentSystem& sys, bool fit_ratio, bool with_prior)
    : sys_(sys),
      prior_rows_(with_prior && sys.exponent_weight > 0 ? static_cast<int>(sys.exponent_triples.size()) : 0),
      learned_rows_(with_prior ? static_cast<int>(sys.learned_matrix.rows()) : 0),
      bound_rows_(sys.min_exponent > 0 ? static_cast<int>(sys.exponent_pairs.size()) : 0),
      ratio_rows_(fit_ratio && sys.ratio_prior_scale > 0 ? 1 : 0) {}

double PriorRows::logx(int v) const { return std::log(double(v) / (sys_.levels() - 1)); }

double PriorRows::localExponent(const std::vector<double>& f, int a, int b) const {
  return (std::log(f[b]) - std::log(f[a])) / (logx(b) - logx(a));
}

bool PriorRows::defined(const std::vector<double>& f) const {
  if (prior_rows_)
    for (const auto& t : sys_.exponent_triples)
      if (!(f[t[0]] > 0)) return false;
  if (learned_rows_)
    for (const int v : sys_.learned_nodes)
      if (!(f[v] > 0)) return false;
  if (bound_rows_)
    for (const auto& t : sys_.exponent_pairs)
      if (!(f[t[0]] > 0)) return false;
  return true;
}

void PriorRows::residuals(const std::vector<double>& f, double log_r, Eigen::VectorXd& res, int offset,
                          std::vector<double>& scale) const {
  scale.assign(prior_rows_, 0.0);
  const double prior_scale = std::sqrt(sys_.exponent_weight);
  for (int i = 0; i < prior_rows_; ++i) {
    const auto& t = sys_.exponent_triples[i];
    const double g1 = localExponent(f, t[0], t[1]), g2 = localExponent(f, t[1], t[2]);
    double target = 0;
    if (!sys_.exponent_upper[i]) scale[i] = prior_scale;  // below the data: smoothness
    else if (!sys_.shoulder_reference.empty()) {
      // above the data φ's local exponent changes as the measured mean camera's does (its shoulder)
      scale[i] = std::sqrt(sys_.shoulder_weight);
      target = sys_.shoulder_reference[i];
    } else {
      // the one-sided prior: a rising exponent (a shoulder) is free, a falling one costs the shoulder weight
      scale[i] = g2 < g1 ? std::sqrt(sys_.shoulder_weight) : 0.0;
    }
    res[offset + i] = scale[i] * (g2 - g1 - target);
  }
  if (learned_rows_) {
    Eigen::VectorXd log_f(sys_.learned_nodes.size());
    for (std::size_t k = 0; k < sys_.learned_nodes.size(); ++k) log_f[k] = std::log(f[sys_.learned_nodes[k]]);
    res.segment(offset + prior_rows_, learned_rows_) = sys_.learned_matrix * log_f - sys_.learned_offset;
  }
  const int bound_offset = offset + prior_rows_ + learned_rows_;
  for (int i = 0; i < bound_rows_; ++i) {
    const auto& t = sys_.exponent_pairs[i];
    const double g = localExponent(f, t[0], t[1]);
    res[bound_offset + i] = kPenaltyScale * std::max(0.0, sys_.min_exponent - g);
  }
  if (ratio_rows_) res[bound_offset + bound_rows_] = sys_.ratio_prior_scale * (log_r - sys_.ratio_prior_log_centre);
}

void PriorRows::jacobian(const std::vector<double>& f,
                         const Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>& jm,
                         const Eigen::VectorXd& res, int offset, const std::vector<double>& scale, int d,
                         Eigen::MatrixXd& jac) const {
  for (int i = 0; i < prior_rows_; ++i) {
    const auto& t = sys_.exponent_triples[i];
    const double d1 = logx(t[1]) - logx(t[0]), d2 = logx(t[2]) - logx(t[1]);
    for (int j = 0; j < d; ++j) {
      const double l0 = jm(j, t[0]) / f[t[0]], l1 = jm(j, t[1]) / f[t[1]], l2 = jm(j, t[2]) / f[t[2]];
      jac(offset + i, j) = scale[i] * ((l2 - l1) / d2 - (l1 - l0) / d1);
    }
  }
  if (learned_rows_) {
    const int nodes = static_cast<int>(sys_.learned_nodes.size());
    Eigen::MatrixXd dlog(nodes, d);  // d log φ(node) / d parameter
    for (int k = 0; k < nodes; ++k)
      for (int j = 0; j < d; ++j) dlog(k, j) = jm(j, sys_.learned_nodes[k]) / f[sys_.learned_nodes[k]];
    jac.block(offset + prior_rows_, 0, learned_rows_, d) = sys_.learned_matrix * dlog;
  }
  const int bound_offset = offset + prior_rows_ + learned_rows_;
  for (int i = 0; i < bound_rows_; ++i) {
    if (!(res[bound_offset + i] > 0)) continue;
    const auto& t = sys_.exponent_pairs[i];
    const double d1 = logx(t[1]) - logx(t[0]);
    for (int j = 0; j < d; ++j)
      jac(bound_offset + i, j) = -kPenaltyScale * (jm(j, t[1]) / f[t[1]] - jm(j, t[0]) / f[t[0]]) / d1;
  }
  if (ratio_rows_) jac(bound_offset + bound_rows_, d) = sys_.ratio_prior_scale;
}

ModelFit fitModelMomentsWithPrior(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                                  double r0, bool fit_ratio, int max_iterations, double energy_factor) {
  ModelFit plain = fitModelMoments(curve, sys, starts, r0, fit_ratio, max_iterations, false);
  const bool hand_set = !sys.exponent_triples.empty() && sys.exponent_weight > 0;
  if (!hand_set && sys.learned_matrix.rows() == 0) return plain;
  if (!plain.x.empty()) starts.push_back(plain.x);
  auto dataEnergy = [&](const ModelFit& m) {
    std::vector<double> f;
    if (m.x.empty() || !curve.values(m.x.data(), f, nullptr)) return kInf;
    const double e = momentEnergy(sys, f, m.ratio);  // the data rows only
    return std::isfinite(e) ? e : kInf;
  };
  const double e0 = dataEnergy(plain);
  ModelFit prior;
  if (sys.learned_matrix.rows() > 0) {
    // The learned prior is a Gaussian: its whitened rows go in the units of the data rows, each scaled by the
    // residual's standard deviation per data row of the prior-free fit, so that the sum is −2 log posterior · s².
    if (!std::isfinite(e0)) return plain;
    const double rows = static_cast<double>(sys.h.rows());
    const double s = std::sqrt(e0 / std::max(1.0, rows - curve.dims() - (fit_ratio ? 1 : 0)));
    MomentSystem scaled = sys;
    scaled.learned_matrix *= s;
    scaled.learned_offset *= s;
    prior = fitModelMoments(curve, scaled, starts, r0, fit_ratio, max_iterations, true);
  } else {
    prior = fitModelMoments(curve, sys, starts, r0, fit_ratio, max_iterations, true);
  }
  prior.evaluations += plain.evaluations;
  prior.iterations += plain.iterations;
  plain.evaluations = prior.evaluations;
  plain.iterations = prior.iterations;
  const double e1 = dataEnergy(prior);

  if (prior.valid && (!plain.valid || e1 <= energy_factor * e0)) {
    prior.energy = e1;
    return prior;
  }
  plain.energy = e0;
  return plain;
}

}  // namespace crfcal::crf_fit
