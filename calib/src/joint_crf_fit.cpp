// One φ from several pairs (joint_crf_fit.hpp): each pair's moment problem built as fitInverseCrf builds it, the
// rows stacked with r_p folded into Ĥ (r held for the fit), then the fitter's own candidates and choice at r = 1;
// optionally alternated with each pair's least-squares r at the joint φ (JointCrfFitOptions::ratio_rounds).
#include "crfcal/joint_crf_fit.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <limits>
#include <sstream>

#include "crf_model_selection.hpp"
#include "crf_objective.hpp"
#include "crf_preparation.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"

namespace crfcal {
namespace {

using namespace crf_fit;

// Appends pair p's sums to the stacked moments: Ĥ = r_p H (the level operator of its noise handling applied
// first, as MomentProblem::system would), N and the counts as they are; no squared masses (the joint fit has no CUE).
void appendMoments(const MomentProblem& pair, double ratio, MomentProblem& joint) {
  const Moments& m = pair.moments;
  Moments& j = joint.moments;
  const int rows = j.bins + m.bins;
  for (int f = 0; f < 2; ++f) {
    Eigen::MatrixXd h = pair.level_operator ? Eigen::MatrixXd(m.h[f] * (*pair.level_operator)) : m.h[f];
    auto stack = [&](Eigen::MatrixXd& into, const Eigen::MatrixXd& add) {
      Eigen::MatrixXd out(rows, m.levels);
      if (j.bins > 0) out.topRows(j.bins) = into;
      out.bottomRows(m.bins) = add;
      into = std::move(out);
    };
    stack(j.h[f], ratio * h);
    stack(j.n[f], m.n[f]);
    Eigen::VectorXd c(rows);
    if (j.bins > 0) c.head(j.bins) = j.count[f];
    c.tail(m.bins) = m.count[f];
    j.count[f] = std::move(c);
  }
  j.levels = m.levels;
  j.bins = rows;
  joint.bin_level_bin.insert(joint.bin_level_bin.end(), pair.bin_level_bin.begin(), pair.bin_level_bin.end());
  Eigen::VectorXd omega(rows);
  if (joint.omega.size() > 0) omega.head(joint.omega.size()) = joint.omega;
  omega.tail(m.bins) = pair.omega;
  joint.omega = std::move(omega);
}

// The least-squares r of one pair's rows at φ (f on its level grid): min_r Σ_k ((r a_k − b_k) / s_k)².
double ratioAt(const MomentSystem& sys, const std::vector<double>& f) {
  const int L = sys.levels();
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
  const Eigen::VectorXd a = sys.h * fv, b = sys.n * fv;
  double num = 0, den = 0;
  for (int i = 0; i < static_cast<int>(a.size()); ++i) {
    const double slope = (f[sys.v1[i]] - f[sys.v0[i]]) * (L - 1) / double(sys.v1[i] - sys.v0[i]);
    if (!(slope > 1e-9)) continue;
    num += a[i] * b[i] / (slope * slope);
    den += a[i] * a[i] / (slope * slope);
  }
  return den > 0 ? num / den : 0.0;
}

}  // namespace

void JointCrfFitOptions::check() const {
  if (ratio_rounds < 0 || ratio_rounds > 20) throw InvalidInput("joint fit: ratio_rounds must be in 0..20");
  if (!(ratio_tolerance > 0)) throw InvalidInput("joint fit: ratio_tolerance must be positive");
  model.check();
  if (model.experimental.objective != CrfObjective::moments)
    throw InvalidInput("joint fit: only the moments objective can fit several pairs jointly");
}

double JointCrfFitResult::misfit(std::size_t p) const {
  if (p >= energies.size() || p >= own_energies.size() || !(own_energies[p] > 0) || !std::isfinite(own_energies[p]))
    return std::numeric_limits<double>::quiet_NaN();
  return energies[p] / own_energies[p];
}

std::string JointCrfFitResult::summary() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(4);
  s << "joint phi: " << describe(fit.model) << " (" << fit.chosen << ", " << fit.choice_reason << ")";
  for (std::size_t p = 0; p < ratios.size(); ++p) {
    s << "\n  pair " << p + 1 << ": r " << ratios[p] << " (from " << start_ratios[p] << " after " << ratio_rounds
      << " rounds; at the joint phi " << ratios_at_joint_phi[p] << "), levels " << covered_levels[p].first << "-"
      << covered_levels[p].second << ", " << pixels[p].used
      << " pixels, energy " << energies[p];
    if (std::isfinite(misfit(p))) s << " (" << misfit(p) << "x that of a fit of this pair alone at its r)";
  }
  return s.str();
}

namespace {

// Every pair's moment problem, built once as fitInverseCrf builds it: its rows do not depend on r (r_p multiplies
// Ĥ when the rows are stacked). Fills the per-pair parts of `out` (covered levels, pixels, mixture counts).
struct PairProblems {
  std::deque<NoiseOperators> noise;  // the problems point into them
  std::vector<MomentProblem> problems;
};

PairProblems buildPairProblems(const std::vector<JointFitPair>& pairs, const JointCrfFitOptions& options, int threads,
                               JointCrfFitResult& out) {
  PairProblems built;
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    const JointFitPair& pair = pairs[p];
    const std::string name = "pair " + std::to_string(p + 1) + ": ";
    if (!(pair.ratio > 0) || !std::isfinite(pair.ratio)) throw InvalidInput(name + "its exposure ratio must be positive");
    CrfFitOptions o = pair.options;
    o.experimental.objective = CrfObjective::moments;
    o.level_bins = options.model.level_bins;  // one bin grid for the stacked rows (MomentProblem::system)
    o.experimental.variance_correction = false;  // the joint fit never reads the squared masses (CUE only, see below)
    o.progress = nullptr;
    CrfFitResult pair_result;
    try {
      o.check();
      const Prepared prep = preparePair(pair.sharp, pair.blurred, pair.kernel, o, pair_result);
      built.noise.push_back(makeNoiseOperators(prep, o));
      built.problems.push_back(buildMomentProblem(prep, built.noise.back(), o, threads, pair_result));
    } catch (const InvalidInput& e) {
      throw InvalidInput(name + e.reason(), e.subject());
    }
    if (p > 0 && built.problems.back().moments.levels != built.problems.front().moments.levels)
      throw InvalidInput(name + "its level grid (" + std::to_string(built.problems.back().moments.levels) +
                         " levels) differs from pair 1's (" + std::to_string(built.problems.front().moments.levels) +
                         "): fit pairs of one bit depth together");
    out.covered_levels.push_back(built.problems.back().covered_levels);
    out.pixels.push_back(pair_result.pixels);
    out.fit.mixture_nonzeros += pair_result.mixture_nonzeros;
    if (p == 0) {
      out.fit.levels = pair_result.levels;
      out.fit.noise_sigma = pair_result.noise_sigma;
      out.fit.noise_sigma_estimated = pair_result.noise_sigma_estimated;
    }
  }
  return built;
}

// The pairs' rows stacked at the ratios given, as one moment problem at r = 1.
MomentProblem stackAt(const PairProblems& built, const std::vector<double>& ratios, int level_bins,
                      std::pair<int, int> covered) {
  MomentProblem joint;
  joint.omega.resize(0);
  for (std::size_t p = 0; p < built.problems.size(); ++p) appendMoments(built.problems[p], ratios[p], joint);
  joint.level_bins = level_bins;
  joint.level_operator = nullptr;  // applied per pair in appendMoments
  joint.covered_levels = covered;
  return joint;
}

// The fitter's own candidates and choice on the stacked rows (r held: the rows carry r_p, so the candidates run at
// r = 1 without a ratio prior). Replaces the model, the candidates and the choice in `result`.
void fitStacked(const MomentProblem& joint, const NoiseOperators& noise, const CrfFitOptions& options,
                CrfFitResult& result) {
  CrfFitOptions model = options;
  model.fit_ratio = false;
  model.nominal_ratio = 1.0;
  model.ratio_prior_sigma = 0;
  model.experimental.variance_correction = false;  // the CUE variances assume one pair's noise operator
  const auto t_opt = std::chrono::steady_clock::now();
  MomentSystem full;
  std::vector<CrfCandidate> candidates =
      momentCandidates(joint, noise, model, result, [&](double f, const std::string& stage) {
        if (model.progress) model.progress(f, stage);
      }, full);
  result.timings.optimise_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - t_opt).count();
  chooseCandidate(candidates, model, result);
  result.candidates = std::move(candidates);
  result.inverse_crf = sampleValidTable(result.model);
  if (!checkValidity(TableModel{result.inverse_crf}, kCurveSamples, 1e-6)) {
    result.model = ggcm::fromGamma(2.2, model.ggcm_degree);
    result.inverse_crf = sampleValidTable(result.model);
    result.chosen = "fallback";
    result.choice_reason = "the chosen curve failed validation; returned the gamma 2.2 start";
  }
}

// The energy of pair p's rows (`sys`) at a φ fitted to them alone at r (the same model, priors and choice as the
// joint fit): the reference of the pair's misfit. The pair's problem is stacked alone, so r_p is held as in the
// joint fit.
double ownEnergy(const PairProblems& built, std::size_t p, const MomentSystem& sys, double ratio,
                 const CrfFitOptions& model) {
  const MomentProblem& problem = built.problems[p];
  MomentProblem alone;
  alone.omega.resize(0);
  appendMoments(problem, ratio, alone);
  alone.level_bins = problem.level_bins;
  alone.level_operator = nullptr;  // applied in appendMoments
  alone.covered_levels = problem.covered_levels;
  CrfFitResult fit;
  fit.covered_levels = problem.covered_levels;
  fitStacked(alone, built.noise[p], model, fit);
  return momentEnergy(sys, onLevelGrid(fit.inverse_crf, sys.levels()), ratio);
}

}  // namespace

JointCrfFitResult fitInverseCrfJointly(const std::vector<JointFitPair>& pairs, const JointCrfFitOptions& options) {
  options.check();
  if (pairs.empty()) throw InvalidInput("joint fit: no pairs");
  const auto start = std::chrono::steady_clock::now();
  const int threads = options.model.threads > 0 ? options.model.threads : std::max(1, cv::getNumThreads());
  JointCrfFitResult out;
  const PairProblems built = buildPairProblems(pairs, options, threads, out);
  std::pair<int, int> covered = out.covered_levels.front();
  for (const auto& c : out.covered_levels)
    covered = {std::min(covered.first, c.first), std::max(covered.second, c.second)};

  CrfFitResult& result = out.fit;
  result.nominal_ratio = 1.0;
  result.objective = CrfObjective::moments;
  result.optimizer = options.model.experimental.optimizer;
  result.covered_levels = covered;
  for (const auto& px : out.pixels) result.pixels.used += px.used, result.pixels.total += px.total;
  for (const JointFitPair& pair : pairs) out.start_ratios.push_back(pair.ratio);
  out.ratios = out.start_ratios;
  std::vector<MomentSystem> systems;  // each pair's rows without r (Ĥ and N apart): for its r and its energies
  for (const MomentProblem& problem : built.problems) systems.push_back(problem.system(-1));
  // φ at the ratios; with ratio_rounds, each pair's r moved to its own least-squares r at that φ and φ refitted
  // (the pairs' relative exposures from all their data; the common exponent φ^γ, r^γ stays where the starts put it).
  for (int round = 0;; ++round) {
    const MomentProblem joint = stackAt(built, out.ratios, options.model.level_bins, covered);
    int nonempty = 0;
    for (int k = 0; k < joint.moments.bins; ++k)
      nonempty += (joint.moments.count[0][k] + joint.moments.count[1][k]) > 0;
    result.moment_bins = nonempty;
    fitStacked(joint, built.noise.front(), options.model, result);
    out.ratios_at_joint_phi.clear();
    for (const MomentSystem& sys : systems)
      out.ratios_at_joint_phi.push_back(ratioAt(sys, onLevelGrid(result.inverse_crf, sys.levels())));
    out.ratio_rounds = round;
    double moved = 0;  // in log r
    for (std::size_t p = 0; p < out.ratios.size(); ++p)
      if (out.ratios_at_joint_phi[p] > 0)
        moved = std::max(moved, std::abs(std::log(out.ratios_at_joint_phi[p] / out.ratios[p])));
    if (round >= options.ratio_rounds || !(moved > options.ratio_tolerance)) break;
    for (std::size_t p = 0; p < out.ratios.size(); ++p)
      if (out.ratios_at_joint_phi[p] > 0) out.ratios[p] = out.ratios_at_joint_phi[p];
  }
  result.ratio = 1.0;
  for (std::size_t p = 0; p < systems.size(); ++p) {
    const MomentSystem& sys = systems[p];
    out.energies.push_back(momentEnergy(sys, onLevelGrid(result.inverse_crf, sys.levels()), out.ratios[p]));
    out.own_energies.push_back(options.pair_misfits ? ownEnergy(built, p, sys, out.ratios[p], options.model) : -1.0);
  }
  result.timings.total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

}  // namespace crfcal
