#include "crfcal/chart_calibration.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numeric>
#include <sstream>

#include <Eigen/Dense>
#include <nlopt.hpp>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "chart_stages.hpp"

namespace crfcal {
namespace {

double lerp(std::span<const double, emor::kSamples> curve, double x) {
  const double position = std::clamp(x, 0.0, 1.0) * (emor::kSamples - 1);
  const int i = std::min(static_cast<int>(position), emor::kSamples - 2);
  const double t = position - i;
  return curve[static_cast<size_t>(i)] + t * (curve[static_cast<size_t>(i) + 1] - curve[static_cast<size_t>(i)]);
}

struct Problem {
  int terms = 0;
  int groups = 0;
  Eigen::MatrixXd basis;    // N × K: h_k(x_i)
  Eigen::VectorXd mean;     // g0(x_i)
  Eigen::VectorXd y, w;
  std::vector<int> group;
  std::vector<ScaledObservation::Kind> kind;
  double normaliser = 1;
  double smoothness = 0;
  Eigen::MatrixXd rough_a;     // second differences of the basis on the roughness grid
  Eigen::VectorXd rough_b;     // … of g0    // Σ w y² (keeps the cost O(1))
  double exponent_smoothness = 0;
  Eigen::MatrixXd exponent_a;     // φ at the exponent grid nodes: φ_j = exponent_a.row(j)·c + exponent_b[j]
  Eigen::VectorXd exponent_b;
  Eigen::VectorXd exponent_dlog;  // log x_{j+1} − log x_j
  Eigen::MatrixXd monotone_a;  // M × K: h_k(x_{j+1}) − h_k(x_j)
  Eigen::VectorXd monotone_b;  // g0(x_{j+1}) − g0(x_j)
  bool profile_scales = false;  // the scales are bestScales(φ), not variables (ScaledFitOptions::profile_scales)
};

std::vector<double> bestScales(const Problem& p, const Eigen::VectorXd& phi);

double cost(const Problem& p, const double* v, double* grad) {
  const Eigen::Map<const Eigen::VectorXd> c(v, p.terms);
  const Eigen::VectorXd phi = p.terms > 0 ? Eigen::VectorXd(p.mean + p.basis * c) : p.mean;
  double sum = 0;
  Eigen::VectorXd grad_c = Eigen::VectorXd::Zero(p.terms);
  std::vector<double> grad_s(static_cast<size_t>(p.groups), 0.0);
  // Profiled scales: at the closed-form optimum ∂J/∂s = 0, so ∂J/∂c is the partial derivative at fixed s.
  const std::vector<double> profiled = p.profile_scales ? bestScales(p, phi) : std::vector<double>();
  for (Eigen::Index i = 0; i < phi.size(); ++i) {
    const int g = p.group[static_cast<size_t>(i)];
    const double s = p.profile_scales ? profiled[static_cast<size_t>(g)] : v[p.terms + g];
    double r = p.y[i] - s * phi[i];
    const auto kind = p.kind[static_cast<size_t>(i)];
    if (kind == ScaledObservation::Kind::AtMost) r = std::min(r, 0.0);       // violated when sφ > y
    else if (kind == ScaledObservation::Kind::AtLeast) r = std::max(r, 0.0); // violated when sφ < y
    sum += p.w[i] * r * r;
    if (grad) {
      const double d = -2 * p.w[i] * r / p.normaliser;
      if (p.terms > 0) grad_c += (d * s) * p.basis.row(i).transpose();
      grad_s[static_cast<size_t>(g)] += d * phi[i];
    }
  }
  double rough = 0;
  if (p.smoothness > 0 && p.terms > 0) {
    const Eigen::VectorXd d = p.rough_a * c + p.rough_b;
    rough = p.smoothness * d.squaredNorm();
    if (grad) grad_c += 2 * p.smoothness * (p.rough_a.transpose() * d);
  }
  double bend = 0;
  if (p.exponent_smoothness > 0 && p.terms > 0) {
    // Local exponent between nodes, g_j = Δ log φ / Δ log x (constant for φ = x^γ); penalty λ Σ (g_{j+1} − g_j)².
    // Invariant to the unknown scale s (log sφ = log s + log φ), so it cannot be lowered by trading s against φ.
    const Eigen::VectorXd node = p.exponent_a * c + p.exponent_b;
    const Eigen::Index m = node.size();
    Eigen::VectorXd phi_n = node.cwiseMax(1e-12);
    Eigen::VectorXd g(m - 1);
    for (Eigen::Index j = 0; j + 1 < m; ++j) g[j] = (std::log(phi_n[j + 1]) - std::log(phi_n[j])) / p.exponent_dlog[j];
    Eigen::VectorXd dg_dlogphi = Eigen::VectorXd::Zero(m);  // ∂penalty/∂ log φ_j
    for (Eigen::Index j = 0; j + 2 < m; ++j) {
      const double d = g[j + 1] - g[j];
      bend += d * d;
      if (grad) {
        // d = (L_{j+2} − L_{j+1})/Δ_{j+1} − (L_{j+1} − L_j)/Δ_j
        dg_dlogphi[j + 2] += 2 * d / p.exponent_dlog[j + 1];
        dg_dlogphi[j + 1] += 2 * d * (-1 / p.exponent_dlog[j + 1] - 1 / p.exponent_dlog[j]);
        dg_dlogphi[j] += 2 * d / p.exponent_dlog[j];
      }
    }
    bend *= p.exponent_smoothness;
    if (grad) {
      for (Eigen::Index j = 0; j < m; ++j)
        if (node[j] > 1e-12) grad_c += (p.exponent_smoothness * dg_dlogphi[j] / node[j]) * p.exponent_a.row(j).transpose();
    }
  }
  if (grad) {
    for (int k = 0; k < p.terms; ++k) grad[k] = grad_c[k];
    if (!p.profile_scales)
      for (int g = 0; g < p.groups; ++g) grad[p.terms + g] = grad_s[static_cast<size_t>(g)];
  }
  return sum / p.normaliser + rough + bend;
}

// Closed-form scales for a fixed φ at the observations.
std::vector<double> bestScales(const Problem& p, const Eigen::VectorXd& phi) {
  std::vector<double> num(static_cast<size_t>(p.groups), 0.0), den(static_cast<size_t>(p.groups), 0.0);
  for (Eigen::Index i = 0; i < phi.size(); ++i) {
    if (p.kind[static_cast<size_t>(i)] != ScaledObservation::Kind::Exact) continue;
    const auto g = static_cast<size_t>(p.group[static_cast<size_t>(i)]);
    num[g] += p.w[i] * p.y[i] * phi[i];
    den[g] += p.w[i] * phi[i] * phi[i];
  }
  std::vector<double> s(static_cast<size_t>(p.groups), 0.0);
  for (size_t g = 0; g < s.size(); ++g) s[g] = den[g] > 0 ? std::max(num[g] / den[g], 1e-12) : 0.0;
  return s;
}

std::vector<double> emorSamples(const std::vector<double>& c) {
  std::vector<double> phi(emor::kSamples);
  for (int j = 0; j < emor::kSamples; ++j) {
    double v = emor::inverseMean()[static_cast<size_t>(j)];
    for (size_t k = 0; k < c.size(); ++k) v += c[k] * emor::inverseBasis(int(k) + 1)[static_cast<size_t>(j)];
    phi[static_cast<size_t>(j)] = v;
  }
  return phi;
}

void validate(std::span<const ScaledObservation> observations) {
  if (observations.size() < 3) throw InvalidInput("response fit needs at least 3 observations");
  for (const auto& o : observations) {
    if (!std::isfinite(o.x) || !std::isfinite(o.y) || !std::isfinite(o.weight))
      throw InvalidInput("response fit: non-finite observation");
    if (!(o.y > 0)) throw InvalidInput("response fit: reference values must be > 0");
    if (o.x < 0 || o.x > 1) throw InvalidInput("response fit: intensities must be in [0,1]");
    if (o.group < 0) throw InvalidInput("response fit: negative group index");
    if (o.weight < 0) throw InvalidInput("response fit: negative weight");
  }
}

}  // namespace

void ScaledFitOptions::check() const {
  if (terms < 0 || terms > emor::kMaxTerms) throw InvalidInput("fit terms must be in 0..25");
  if (min_terms < 0 || max_terms > emor::kMaxTerms || min_terms > max_terms)
    throw InvalidInput("fit term range must satisfy 0 ≤ min_terms ≤ max_terms ≤ 25");
  if (monotone_grid < 8) throw InvalidInput("monotone_grid must be ≥ 8");
  if (max_evaluations < 10) throw InvalidInput("max_evaluations must be ≥ 10");
  if (!(smoothness >= 0)) throw InvalidInput("smoothness must be ≥ 0");
  if (!(exponent_smoothness >= 0)) throw InvalidInput("exponent_smoothness must be ≥ 0");
  if (!(cv_tolerance >= 0)) throw InvalidInput("cv_tolerance must be ≥ 0");
}

std::string ScaledFitResult::summary() const {
  std::ostringstream out;
  out << "EMoR K=" << terms << ", " << observations << " observations, rmse " << rmse << " (max " << max_error
      << "), covered x in [" << covered_range.first << ", " << covered_range.second << "]";
  return out.str();
}

namespace {

// The data rows of the problem: the EMoR basis and mean at each observation's x, its value, weight, group and kind.
Problem dataProblem(std::span<const ScaledObservation> observations, int terms, const ScaledFitOptions& options) {
  Problem p;
  p.terms = terms;
  const auto n = static_cast<Eigen::Index>(observations.size());
  for (const auto& o : observations) p.groups = std::max(p.groups, o.group + 1);
  p.basis.resize(n, terms);
  p.mean.resize(n);
  p.y.resize(n);
  p.w.resize(n);
  p.group.resize(static_cast<size_t>(n));
  p.kind.resize(static_cast<size_t>(n));
  p.normaliser = 0;
  p.smoothness = options.smoothness;
  p.profile_scales = options.profile_scales;
  for (Eigen::Index i = 0; i < n; ++i) {
    const ScaledObservation& o = observations[static_cast<size_t>(i)];
    for (int k = 0; k < terms; ++k) p.basis(i, k) = lerp(emor::inverseBasis(k + 1), o.x);
    p.mean[i] = lerp(emor::inverseMean(), o.x);
    p.y[i] = o.y;
    p.w[i] = o.weight;
    p.group[static_cast<size_t>(i)] = o.group;
    p.kind[static_cast<size_t>(i)] = o.kind;
    if (o.kind == ScaledObservation::Kind::Exact) p.normaliser += o.weight * o.y * o.y;
  }
  return p;
}

// The roughness penalty's rows: second differences of the basis and mean on a 64-node grid.
void addRoughnessRows(Problem& p) {
  constexpr int kRoughGrid = 64;
  p.rough_a.resize(kRoughGrid - 2, p.terms);
  p.rough_b.resize(kRoughGrid - 2);
  for (int j = 1; j + 1 < kRoughGrid; ++j) {
    const double x0 = double(j - 1) / (kRoughGrid - 1), x1 = double(j) / (kRoughGrid - 1),
                 x2 = double(j + 1) / (kRoughGrid - 1);
    auto d2 = [&](std::span<const double, emor::kSamples> curve) {
      return lerp(curve, x2) - 2 * lerp(curve, x1) + lerp(curve, x0);
    };
    for (int k = 0; k < p.terms; ++k) p.rough_a(j - 1, k) = d2(emor::inverseBasis(k + 1));
    p.rough_b[j - 1] = d2(emor::inverseMean());
  }
}

// The exponent-smoothness rows. Nodes x_j = j/64 from the last one inside the data to 1: the penalty only decides
// the continuation of φ beyond the brightest exact sample (where the data cannot), and links it to the exponent the
// data show.
void addExponentRows(Problem& p, std::span<const ScaledObservation> observations, double exponent_smoothness) {
  constexpr int kExponentGrid = 64, kFirst = 4;
  double top = 0;
  for (const auto& o : observations)
    if (o.kind == ScaledObservation::Kind::Exact) top = std::max(top, o.x);
  int first = std::max(kFirst, int(std::floor(top * kExponentGrid)) - 1);
  first = std::min(first, kExponentGrid - 2);
  p.exponent_smoothness = exponent_smoothness;
  const int m = kExponentGrid - first + 1;
  p.exponent_a.resize(m, p.terms);
  p.exponent_b.resize(m);
  p.exponent_dlog.resize(m - 1);
  for (int j = 0; j < m; ++j) {
    const double x = double(j + first) / kExponentGrid;
    for (int k = 0; k < p.terms; ++k) p.exponent_a(j, k) = lerp(emor::inverseBasis(k + 1), x);
    p.exponent_b[j] = lerp(emor::inverseMean(), x);
    if (j + 1 < m) p.exponent_dlog[j] = std::log(double(j + first + 1) / (j + first));
  }
}

// The monotonicity constraint's rows on `grid` nodes: φ(x_{j+1}) − φ(x_j) = monotone_a.row(j)·c + monotone_b[j].
void addMonotoneRows(Problem& p, int grid) {
  p.monotone_a.resize(grid - 1, p.terms);
  p.monotone_b.resize(grid - 1);
  for (int j = 0; j + 1 < grid; ++j) {
    const double x0 = double(j) / (grid - 1), x1 = double(j + 1) / (grid - 1);
    for (int k = 0; k < p.terms; ++k)
      p.monotone_a(j, k) = lerp(emor::inverseBasis(k + 1), x1) - lerp(emor::inverseBasis(k + 1), x0);
    p.monotone_b[j] = lerp(emor::inverseMean(), x1) - lerp(emor::inverseMean(), x0);
  }
}

// SLSQP (NLopt) on the EMoR coefficients (and the groups' scales unless profiled), φ non-decreasing on the monotone
// grid, the scales non-negative; `v` holds the start and receives the solution. `p` is only read (NLopt's callbacks
// take a non-const pointer).
void minimiseWithSlsqp(Problem& p, const ScaledFitOptions& options, std::vector<double>& v) {
  const int grid = options.monotone_grid;
  nlopt::opt optimizer(nlopt::LD_SLSQP, static_cast<unsigned>(v.size()));
  optimizer.set_min_objective(
      [](const std::vector<double>& x, std::vector<double>& g, void* data) {
        return cost(*static_cast<const Problem*>(data), x.data(), g.empty() ? nullptr : g.data());
      },
      &p);
  // φ(x_{j+1}) − φ(x_j) ≥ 0  ⇔  −(A c + b) ≤ 0 (one vector-valued constraint).
  optimizer.add_inequality_mconstraint(
      [](unsigned m, double* result, unsigned nv, const double* x, double* grad, void* data) {
        const auto& pr = *static_cast<const Problem*>(data);
        const Eigen::Map<const Eigen::VectorXd> c(x, pr.terms);
        Eigen::Map<Eigen::VectorXd>(result, m) = -(pr.monotone_a * c + pr.monotone_b);
        if (grad) {
          Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> g(grad, m, nv);
          g.setZero();
          g.leftCols(pr.terms) = -pr.monotone_a;
        }
      },
      &p, std::vector<double>(static_cast<size_t>(grid - 1), 1e-12));
  std::vector<double> lower(v.size(), -std::numeric_limits<double>::infinity());
  if (!p.profile_scales)
    for (int g = 0; g < p.groups; ++g) lower[static_cast<size_t>(p.terms + g)] = 0;
  optimizer.set_lower_bounds(lower);
  optimizer.set_ftol_rel(1e-14);
  optimizer.set_xtol_rel(1e-10);
  optimizer.set_maxeval(options.max_evaluations);
  double value = 0;
  try {
    optimizer.optimize(v, value);
  } catch (const nlopt::roundoff_limited&) {
  } catch (const std::runtime_error&) {
  }
}

// The result for the fitted coefficients: φ's table, the groups' scales polished for it, residuals (censored ones
// one-sided), the weighted RMSE over the exact observations and the range of x they cover.
ScaledFitResult scaledFitResult(const Problem& p, std::span<const ScaledObservation> observations,
                                const std::vector<double>& v) {
  const auto n = static_cast<Eigen::Index>(observations.size());
  ScaledFitResult result;
  result.terms = p.terms;
  result.model.coefficients.assign(v.begin(), v.begin() + p.terms);
  result.inverse = emorSamples(result.model.coefficients);
  // Tiny negative steps the SLSQP tolerance (or a monotone grid coarser than the 1024 nodes) lets through: make the
  // table exactly non-decreasing and ≤ φ(1) = 1.
  for (size_t j = 1; j < result.inverse.size(); ++j)
    result.inverse[j] = std::min(std::max(result.inverse[j], result.inverse[j - 1]), 1.0);
  result.inverse.front() = 0;
  result.inverse.back() = 1;
  Eigen::VectorXd phi(n);
  for (Eigen::Index i = 0; i < n; ++i) phi[i] = evaluateInverse(result.model, observations[static_cast<size_t>(i)].x);
  result.scales = bestScales(p, phi);  // polish (exact optimum for the final φ)
  result.residuals.resize(static_cast<size_t>(n));
  double sum = 0, weight = 0;
  result.covered_range = {1.0, 0.0};
  for (Eigen::Index i = 0; i < n; ++i) {
    const ScaledObservation& o = observations[static_cast<size_t>(i)];
    const double s = result.scales[static_cast<size_t>(o.group)];
    double r = s > 0 ? o.y / s - phi[i] : 0.0;
    if (o.kind != ScaledObservation::Kind::Exact) {
      r = o.kind == ScaledObservation::Kind::AtMost ? std::min(r, 0.0) : std::max(r, 0.0);
      result.residuals[static_cast<size_t>(i)] = r;
      ++result.censored;
      continue;
    }
    result.residuals[static_cast<size_t>(i)] = r;
    sum += o.weight * r * r;
    weight += o.weight;
    result.max_error = std::max(result.max_error, std::abs(r));
    result.covered_range.first = std::min(result.covered_range.first, o.x);
    result.covered_range.second = std::max(result.covered_range.second, o.x);
  }
  result.rmse = weight > 0 ? std::sqrt(sum / weight) : 0;
  result.observations = int(n) - result.censored;
  return result;
}

}  // namespace

ScaledFitResult fitScaledInverseFixed(std::span<const ScaledObservation> observations, int terms,
                                      const ScaledFitOptions& options) {
  options.check();
  validate(observations);
  if (terms < 0 || terms > emor::kMaxTerms) throw InvalidInput("fit terms must be in 0..25");
  Problem p = dataProblem(observations, terms, options);
  if (terms > 0 && options.smoothness > 0) addRoughnessRows(p);
  if (terms > 0 && options.exponent_smoothness > 0) addExponentRows(p, observations, options.exponent_smoothness);
  if (!(p.normaliser > 0)) throw InvalidInput("response fit: all weights are zero");
  std::vector<double> v(static_cast<size_t>(terms + (p.profile_scales ? 0 : p.groups)), 0.0);
  if (!p.profile_scales) {
    const std::vector<double> s = bestScales(p, p.mean);
    std::copy(s.begin(), s.end(), v.begin() + terms);
  }
  if (terms > 0) {
    addMonotoneRows(p, options.monotone_grid);
    minimiseWithSlsqp(p, options, v);
  }
  return scaledFitResult(p, observations, v);
}

ScaledFitResult fitScaledInverse(std::span<const ScaledObservation> observations, const ScaledFitOptions& options) {
  options.check();
  validate(observations);
  if (options.terms > 0) return fitScaledInverseFixed(observations, options.terms, options);

  std::vector<int> folds;
  for (const auto& o : observations) folds.push_back(o.fold);
  std::sort(folds.begin(), folds.end());
  folds.erase(std::unique(folds.begin(), folds.end()), folds.end());
  if (folds.size() < 2) throw InvalidInput("cross-validation needs at least two folds");

  std::vector<std::pair<int, double>> cv;
  for (int k = options.min_terms; k <= options.max_terms; ++k) {
    double sum = 0;
    int count = 0;
    for (int fold : folds) {
      std::vector<ScaledObservation> train, test;
      for (const auto& o : observations) {
        if (o.fold != fold) train.push_back(o);
        else if (o.kind == ScaledObservation::Kind::Exact) test.push_back(o);
      }
      // Groups renumbered densely for training; a test group absent from training gets its own best scale.
      std::map<int, int> dense;
      for (auto& o : train) o.group = dense.emplace(o.group, int(dense.size())).first->second;
      if (train.size() < 3 || int(train.size()) <= k) continue;
      const ScaledFitResult fit = fitScaledInverseFixed(train, k, options);
      std::map<int, std::pair<double, double>> own;  // group → (Σ y φ, Σ φ²) of the test data
      std::vector<double> phi(test.size());
      for (size_t i = 0; i < test.size(); ++i) {
        phi[i] = evaluateInverse(fit.model, test[i].x);
        auto& acc = own[test[i].group];
        acc.first += test[i].weight * test[i].y * phi[i];
        acc.second += test[i].weight * phi[i] * phi[i];
      }
      for (size_t i = 0; i < test.size(); ++i) {
        const auto it = dense.find(test[i].group);
        double s = 0;
        if (it != dense.end()) s = fit.scales[static_cast<size_t>(it->second)];
        else if (own[test[i].group].second > 0) s = own[test[i].group].first / own[test[i].group].second;
        if (!(s > 0)) continue;
        const double r = test[i].y / s - phi[i];
        sum += r * r;
        ++count;
      }
    }
    cv.emplace_back(k, count > 0 ? std::sqrt(sum / count) : std::numeric_limits<double>::infinity());
  }
  double best = std::numeric_limits<double>::infinity();
  for (const auto& [k, e] : cv) best = std::min(best, e);
  int chosen = options.max_terms;
  for (const auto& [k, e] : cv)
    if (e <= best * (1 + options.cv_tolerance)) {
      chosen = k;
      break;
    }
  ScaledFitResult result = fitScaledInverseFixed(observations, chosen, options);
  result.cv_rmse = std::move(cv);
  return result;
}

// ---- ColorChecker calibration ------------------------------------------------------------------------------------

std::string channelName(int channel) {
  static const char* names[] = {"R", "G", "B"};
  if (channel < 0 || channel > 2) throw InvalidInput("channel must be 0, 1 or 2");
  return names[channel];
}

void ChartCalibrationOptions::check() const {
  fit.check();
  band.check();
  if (channels.empty()) throw InvalidInput("chart calibration: no channels");
  for (int c : channels)
    if (c < 0 || c > 2) throw InvalidInput("chart calibration: channel must be 0, 1 or 2");
  if (exposure_rounds < 0) throw InvalidInput("chart calibration: exposure_rounds must be ≥ 0");
  if (!(colour_floor >= 0 && colour_floor < 0.5)) throw InvalidInput("chart calibration: colour_floor must be in [0, 0.5)");
  if (!(colour_outlier_factor >= 0)) throw InvalidInput("chart calibration: colour_outlier_factor must be ≥ 0");
  if (!(grey_weight > 0)) throw InvalidInput("chart calibration: grey_weight must be > 0");
}

std::string ChartCalibrationResult::summary() const {
  std::ostringstream out;
  for (const auto& c : channels)
    out << channelName(c.channel) << ": " << c.fit.summary() << ", GGCM deviation " << c.ggcm_rmse << ", "
        << c.rejected << " patch samples rejected\n";
  return out.str();
}

namespace detail {

ChartChannelResult fitChartChannel(int c, std::vector<ScaledObservation> observations, size_t exact,
                                   const std::vector<std::pair<int, int>>& origin, const ChartCalibrationOptions& options,
                                   std::vector<std::string>& warnings) {
  ChartChannelResult channel;
  channel.channel = c;
  if (exact < 4)
    throw InvalidInput("channel " + channelName(c) + ": only " + std::to_string(exact) +
                       " usable patch samples (need ≥ 4)");
  // Leave-one-out folds need at least two distinct folds; fall back to a fixed K otherwise.
  ScaledFitOptions fit_options = options.fit;
  {
    std::vector<int> folds;
    for (const auto& o : observations) folds.push_back(o.fold);
    std::sort(folds.begin(), folds.end());
    const auto distinct = std::unique(folds.begin(), folds.end()) - folds.begin();
    if (distinct < 3 && fit_options.terms == 0) {
      fit_options.terms = std::min(3, options.fit.max_terms);
      warnings.push_back("channel " + channelName(c) + ": too few folds for cross-validation, K = " +
                         std::to_string(fit_options.terms));
    }
  }
  channel.fit = fitScaledInverse(observations, fit_options);
  const ggcm::FitResult g = ggcm::fitInverse(channel.fit.inverse, options.ggcm);
  channel.ggcm = g.model;
  channel.ggcm_valid = g.valid;
  channel.ggcm_rmse = curveRmse(sampleInverse(g.model, kCurveSamples), channel.fit.inverse);
  for (size_t i = 0; i < exact; ++i) {
    const double s = channel.fit.scales[static_cast<size_t>(observations[i].group)];
    channel.patches.push_back({origin[i].first, origin[i].second, observations[i].x,
                               s > 0 ? observations[i].y / s : 0.0, channel.fit.residuals[i]});
  }
  if (channel.fit.covered_range.second - channel.fit.covered_range.first < 0.5)
    warnings.push_back("channel " + channelName(c) + ": data cover only x in [" +
                       std::to_string(channel.fit.covered_range.first) + ", " +
                       std::to_string(channel.fit.covered_range.second) +
                       "]; the rest of the curve is the EMoR model's extrapolation");
  return channel;
}

}  // namespace detail

ChartCalibrationResult calibrateChart(const std::vector<ChartShot>& shots, const ChartCalibrationOptions& options,
                                      const ProgressCallback& progress) {
  options.check();
  if (shots.empty()) throw InvalidInput("chart calibration needs at least one shot");
  if (!options.use_raw && options.reference == chart::ReferenceSet::AllPatches)
    return detail::calibrateChartAllPatches(shots, options, progress);
  bool all_exposures = true;
  double reference_exposure = 0;
  for (const auto& shot : shots) {
    if (shot.measured.size() != size_t(chart::kPatches))
      throw InvalidInput("shot " + shot.name + ": expected 24 sampled patches");
    if (options.use_raw && shot.raw.size() != size_t(chart::kPatches))
      throw InvalidInput("shot " + shot.name + ": RAW reference requested but no RAW patches");
    all_exposures = all_exposures && shot.exposure > 0;
    reference_exposure = std::max(reference_exposure, shot.exposure);
  }
  ChartCalibrationResult result;
  const bool common_scale = options.use_raw ? options.raw_common_scale : all_exposures;
  // The scale group of each shot: all in one, one per scene (RAW, raw_scale_per_scene), or one per shot.
  std::vector<int> group_of(shots.size(), 0);
  if (common_scale && options.use_raw && options.raw_scale_per_scene) {
    std::map<int, int> scene_group;
    for (size_t s = 0; s < shots.size(); ++s)
      group_of[s] = scene_group.emplace(shots[s].scene, int(scene_group.size())).first->second;
  } else if (!common_scale) {
    std::iota(group_of.begin(), group_of.end(), 0);
  }
  if (!options.use_raw && shots.size() > 1 && !all_exposures)
    result.warnings.push_back("no exposure ratios for all shots: one free exposure scale per shot");

  for (size_t ci = 0; ci < options.channels.size(); ++ci) {
    const int c = options.channels[ci];
    ChartChannelResult channel;
    channel.channel = c;
    std::vector<ScaledObservation> observations;
    std::vector<std::pair<int, int>> origin;  // (shot, patch)
    std::vector<ScaledObservation> censored;   // bounds from patches clipped on one side
    for (size_t s = 0; s < shots.size(); ++s) {
      for (int p = 0; p < chart::kPatches; ++p) {
        const chart::PatchStats& m = shots[s].measured[static_cast<size_t>(p)];
        std::optional<double> y;
        bool usable = m.usable();
        auto kind = ScaledObservation::Kind::Exact;
        if (options.use_raw && options.raw_neutral_only && !chart::reference()[static_cast<size_t>(p)].neutral) continue;
        if (options.use_raw) {
          const chart::PatchStats& r = shots[s].raw[static_cast<size_t>(p)];
          usable = usable && r.usable();
          if (r.median[static_cast<size_t>(c)] > 1e-4) y = r.median[static_cast<size_t>(c)];
          // One side clipped at the top, the other clean: a bound on the curve (see ScaledObservation::Kind).
          if (m.clipped_high && r.usable()) kind = ScaledObservation::Kind::AtMost;
          if (r.clipped_high && m.usable()) kind = ScaledObservation::Kind::AtLeast;
        } else {
          y = chart::referenceValue(options.reference, p, c);
          if (y && all_exposures) *y *= shots[s].exposure / reference_exposure;
          if (m.clipped_high) kind = ScaledObservation::Kind::AtMost;
        }
        if (!y) continue;  // not part of the reference set
        if (kind != ScaledObservation::Kind::Exact) {
          ScaledObservation o;
          o.kind = kind;
          o.x = std::clamp(m.median[static_cast<size_t>(c)], 0.0, 1.0);
          o.y = *y;
          o.group = group_of[s];
          o.fold = options.use_raw ? int(s) : p;
          censored.push_back(o);
          ++channel.rejected;
          continue;
        }
        if (!usable) {
          ++channel.rejected;
          continue;
        }
        ScaledObservation o;
        o.x = std::clamp(m.median[static_cast<size_t>(c)], 0.0, 1.0);
        o.y = *y;
        o.group = group_of[s];
        o.fold = options.use_raw ? int(s) : p;
        observations.push_back(o);
        origin.emplace_back(int(s), p);
      }
    }
    const size_t exact = observations.size();
    observations.insert(observations.end(), censored.begin(), censored.end());
    const int rejected = channel.rejected;
    channel = detail::fitChartChannel(c, std::move(observations), exact, origin, options, result.warnings);
    channel.rejected = rejected;
    result.channels.push_back(std::move(channel));
    if (progress) progress(double(ci + 1) / double(options.channels.size()), channelName(c));
  }
  return result;
}

}  // namespace crfcal
