#include "crfcal/learned_curve_prior.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "crfcal/error.hpp"

namespace crfcal {
namespace {

constexpr int kN = LearnedCurvePrior::kNodes;
constexpr int kG = LearnedCurvePrior::kExponents;

double nodeX(int j) { return j / double(kN); }  // j = 1..kN

// φ at x by linear interpolation of a uniform table on [0, 1].
double sampleAt(const std::vector<double>& table, double x) {
  const double t = std::clamp(x, 0.0, 1.0) * (table.size() - 1);
  const std::size_t i = std::min(static_cast<std::size_t>(t), table.size() - 2);
  return table[i] + (t - i) * (table[i + 1] - table[i]);
}

void checkCurve(const std::vector<double>& c, std::size_t index) {
  const std::string which = "learned prior: training curve " + std::to_string(index);
  if (c.size() < kN + 1) throw InvalidInput(which + " has fewer than 65 samples", ErrorSubject::curve);
  for (std::size_t i = 0; i < c.size(); ++i)
    if (!std::isfinite(c[i]) || (i > 0 && c[i] < c[i - 1]))
      throw InvalidInput(which + " is not finite and non-decreasing", ErrorSubject::curve);
  if (std::abs(c.front()) > 1e-6 || std::abs(c.back() - 1) > 1e-6)
    throw InvalidInput(which + " does not run from phi(0) = 0 to phi(1) = 1", ErrorSubject::curve);
}

// The index of the highest / lowest node inside [lo, hi] (nodes 1..kN), or 0 when none.
int highestNodeInside(std::pair<double, double> covered) {
  for (int j = kN; j >= 1; --j)
    if (nodeX(j) <= covered.second + 1e-12 && nodeX(j) >= covered.first - 1e-12) return j;
  return 0;
}

// log φ at the nodes 1..kN (index 0 unused): the curve's own at node `top`, the exponents g everywhere else.
std::vector<double> logNodes(const std::vector<double>& inverse_crf, int top, const Eigen::VectorXd& g) {
  std::vector<double> log_node(kN + 1, 0.0);
  log_node[top] = std::log(std::max(sampleAt(inverse_crf, nodeX(top)), 1e-9));
  for (int j = top + 1; j <= kN; ++j) log_node[j] = log_node[j - 1] + g[j - 2] * std::log(nodeX(j) / nodeX(j - 1));
  for (int j = top - 1; j >= 1; --j) log_node[j] = log_node[j + 1] - g[j - 1] * std::log(nodeX(j + 1) / nodeX(j));
  return log_node;
}

// The curve's exponents with the unobserved ones replaced by the conditional mean given the observed ones.
Eigen::VectorXd conditionalMeanExponents(const ConditionalExponents& c, const std::vector<double>& inverse_crf) {
  Eigen::VectorXd g = localExponents(inverse_crf);
  Eigen::VectorXd g_o(c.observed.size());
  for (std::size_t i = 0; i < c.observed.size(); ++i) g_o[i] = g[c.observed[i]];
  const Eigen::VectorXd g_u = c.offset + c.gain * g_o;
  for (std::size_t i = 0; i < c.unobserved.size(); ++i) g[c.unobserved[i]] = g_u[i];
  return g;
}

// A square root of a covariance (eigenvalues clipped at 0: the conditional covariance is semi-definite up to
// rounding).
Eigen::MatrixXd covarianceRoot(const Eigen::MatrixXd& covariance) {
  if (covariance.size() == 0) return covariance;
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(covariance);
  return eigen.eigenvectors() * eigen.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal();
}

// The q-quantile of sorted values v (linear between order statistics).
double sortedQuantile(const std::vector<double>& v, double q) {
  const double t = q * (v.size() - 1);
  const std::size_t i = std::min(static_cast<std::size_t>(t), v.size() - 1), k = std::min(i + 1, v.size() - 1);
  return v[i] + (t - i) * (v[k] - v[i]);
}

}  // namespace

void LearnedCurvePriorOptions::check() const {
  if (!(shrinkage >= 0 && shrinkage <= 1)) throw InvalidInput("learned prior: shrinkage must be in [0, 1]");
  if (!(exponent_sigma_floor >= 0) || !std::isfinite(exponent_sigma_floor))
    throw InvalidInput("learned prior: exponent_sigma_floor must be >= 0");
  if (!(observed_exponent_sigma >= 0) || !std::isfinite(observed_exponent_sigma))
    throw InvalidInput("learned prior: observed_exponent_sigma must be >= 0");
}

Eigen::VectorXd localExponents(const std::vector<double>& inverse_crf) {
  Eigen::VectorXd g(kG);
  for (int j = 1; j < kN; ++j) {
    const double a = std::max(sampleAt(inverse_crf, nodeX(j)), 1e-9);
    const double b = std::max(sampleAt(inverse_crf, nodeX(j + 1)), 1e-9);
    g[j - 1] = (std::log(b) - std::log(a)) / (std::log(nodeX(j + 1)) - std::log(nodeX(j)));
  }
  return g;
}

LearnedCurvePrior learnCurvePrior(const std::vector<std::vector<double>>& inverse_crfs,
                                  const LearnedCurvePriorOptions& options) {
  options.check();
  if (inverse_crfs.size() < 2) throw InvalidInput("learned prior: needs at least 2 training curves", ErrorSubject::curve);
  Eigen::MatrixXd g(kG, static_cast<Eigen::Index>(inverse_crfs.size()));
  for (std::size_t i = 0; i < inverse_crfs.size(); ++i) {
    checkCurve(inverse_crfs[i], i);
    g.col(static_cast<Eigen::Index>(i)) = localExponents(inverse_crfs[i]);
  }
  LearnedCurvePrior prior;
  prior.curves = static_cast<int>(inverse_crfs.size());
  prior.mean = g.rowwise().mean();
  const Eigen::MatrixXd centred = g.colwise() - prior.mean;
  const Eigen::MatrixXd sample = centred * centred.transpose() / double(prior.curves - 1);
  Eigen::MatrixXd cov = (1 - options.shrinkage) * sample;
  const double floor2 = options.exponent_sigma_floor * options.exponent_sigma_floor;
  for (int j = 0; j < kG; ++j) cov(j, j) = std::max(cov(j, j) + options.shrinkage * sample(j, j), floor2);
  prior.covariance = cov;
  prior.observed_exponent_sigma = options.observed_exponent_sigma;
  return prior;
}

ConditionalExponents conditionOnCovered(const LearnedCurvePrior& prior, std::pair<double, double> covered) {
  if (prior.empty()) throw InvalidInput("learned prior: empty");
  ConditionalExponents c;
  for (int j = 1; j < kN; ++j) {
    const bool inside = nodeX(j) >= covered.first - 1e-12 && nodeX(j + 1) <= covered.second + 1e-12;
    (inside ? c.observed : c.unobserved).push_back(j - 1);
  }
  const int nu = static_cast<int>(c.unobserved.size()), no = static_cast<int>(c.observed.size());
  const Eigen::MatrixXd s_uu = prior.covariance(c.unobserved, c.unobserved);
  const Eigen::MatrixXd s_uo = prior.covariance(c.unobserved, c.observed);
  Eigen::MatrixXd s_oo = prior.covariance(c.observed, c.observed);
  s_oo.diagonal().array() += prior.observed_exponent_sigma * prior.observed_exponent_sigma;
  const Eigen::VectorXd m_u = prior.mean(c.unobserved), m_o = prior.mean(c.observed);
  if (nu == 0) {  // nothing to predict; Eigen's solvers bind a reference to the data of an empty right-hand side
    c.gain = Eigen::MatrixXd::Zero(0, no);
    c.offset = Eigen::VectorXd(0);
    c.covariance = Eigen::MatrixXd(0, 0);
    return c;
  }
  if (no == 0) {
    c.gain = Eigen::MatrixXd::Zero(nu, 0);
    c.offset = m_u;
    c.covariance = s_uu;
    return c;
  }
  const Eigen::LDLT<Eigen::MatrixXd> solver(s_oo);
  c.gain = solver.solve(s_uo.transpose()).transpose();
  c.offset = m_u - c.gain * m_o;
  c.covariance = s_uu - c.gain * s_uo.transpose();
  c.covariance = 0.5 * (c.covariance + c.covariance.transpose());
  return c;
}

std::vector<double> extrapolateWithPrior(const LearnedCurvePrior& prior, const std::vector<double>& inverse_crf,
                                         std::pair<double, double> covered) {
  checkCurve(inverse_crf, 0);
  const int top = highestNodeInside(covered);
  if (top == 0) throw InvalidInput("learned prior: the covered range holds no node x = j/64");
  const ConditionalExponents c = conditionOnCovered(prior, covered);
  const Eigen::VectorXd g = conditionalMeanExponents(c, inverse_crf);
  const std::vector<double> log_node = logNodes(inverse_crf, top, g);
  const double log_scale = -log_node[kN];  // φ(1) = 1
  int bottom = top;
  while (bottom > 1 && nodeX(bottom - 1) >= covered.first - 1e-12) --bottom;
  const std::size_t n = inverse_crf.size();
  std::vector<double> out(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double x = double(i) / (n - 1);
    if (x <= 0) { out[i] = 0; continue; }
    if (x >= nodeX(bottom) && x <= nodeX(top)) { out[i] = inverse_crf[i] * std::exp(log_scale); continue; }
    // the power law of the interval holding x (below x_1: the first exponent)
    const int j = std::clamp(static_cast<int>(std::floor(x * kN)), 1, kN - 1);
    const int base = x < nodeX(1) ? 1 : j;
    out[i] = std::exp(log_scale + log_node[base] + g[base - 1] * std::log(x / nodeX(base)));
  }
  out.back() = 1.0;
  return out;
}

bool coversANode(std::pair<double, double> covered) { return highestNodeInside(covered) > 0; }

PriorContinuation continuationQuantiles(const LearnedCurvePrior& prior, const std::vector<double>& inverse_crf,
                                        std::pair<double, double> covered, double level, int draws,
                                        std::uint64_t seed) {
  checkCurve(inverse_crf, 0);
  if (!(level > 0 && level < 1)) throw InvalidInput("learned prior: the band's level must be in (0, 1)");
  if (draws < 2) throw InvalidInput("learned prior: at least 2 draws");
  const int top = highestNodeInside(covered);
  if (top == 0) throw InvalidInput("learned prior: the covered range holds no node x = j/64");
  const ConditionalExponents c = conditionOnCovered(prior, covered);
  const Eigen::VectorXd mean = conditionalMeanExponents(c, inverse_crf);
  const Eigen::MatrixXd root = covarianceRoot(c.covariance);
  const std::size_t n = inverse_crf.size();
  const std::size_t first_above = static_cast<std::size_t>(std::floor(nodeX(top) * (n - 1))) + 1;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  std::vector<double> scales(draws);
  std::vector<std::vector<double>> above(n > first_above ? n - first_above : 0, std::vector<double>(draws));
  for (int d = 0; d < draws; ++d) {
    Eigen::VectorXd z(root.cols());
    for (Eigen::Index k = 0; k < z.size(); ++k) z[k] = normal(rng);
    Eigen::VectorXd g = mean;
    const Eigen::VectorXd g_u = root * z;
    for (std::size_t i = 0; i < c.unobserved.size(); ++i) g[c.unobserved[i]] += g_u[i];
    const std::vector<double> log_node = logNodes(inverse_crf, top, g);
    const double log_scale = -log_node[kN];  // φ(1) = 1
    scales[d] = std::exp(log_scale);
    for (std::size_t i = first_above; i < n; ++i) {
      const double x = double(i) / (n - 1);
      const int j = std::clamp(static_cast<int>(std::floor(x * kN)), top, kN - 1);
      above[i - first_above][d] = std::exp(log_scale + log_node[j] + g[j - 1] * std::log(x / nodeX(j)));
    }
  }
  const double q_lo = 0.5 * (1 - level), q_hi = 0.5 * (1 + level);
  PriorContinuation out;
  out.draws = draws;
  out.top_node_x = nodeX(top);
  std::sort(scales.begin(), scales.end());
  out.scale_range = {sortedQuantile(scales, q_lo), sortedQuantile(scales, q_hi)};
  out.lower.resize(n);
  out.upper.resize(n);
  for (std::size_t i = 0; i < std::min(first_above, n); ++i) {
    out.lower[i] = out.scale_range.first * inverse_crf[i];
    out.upper[i] = out.scale_range.second * inverse_crf[i];
  }
  for (std::size_t i = first_above; i < n; ++i) {
    std::vector<double>& values = above[i - first_above];
    std::sort(values.begin(), values.end());
    out.lower[i] = std::min(sortedQuantile(values, q_lo), 1.0);
    out.upper[i] = std::min(sortedQuantile(values, q_hi), 1.0);
  }
  out.lower.back() = out.upper.back() = 1.0;
  return out;
}

}  // namespace crfcal
