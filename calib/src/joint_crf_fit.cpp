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

#include <Eigen/Cholesky>

#include "crf_model_selection.hpp"
#include "crf_objective.hpp"
#include "crf_preparation.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"

namespace crfcal {
namespace {

using namespace crf_fit;

// N with an additive irradiance offset c in the pair's blurred shot: each row's N_k φ − c m_k, m_k = N_k 1 its pixel
// mass, carried by φ's top level, where every model has φ(1) = 1 (and no Jacobian: the offset is a constant).
Eigen::MatrixXd offsetRows(const Eigen::MatrixXd& n, double offset) {
  if (offset == 0 || n.cols() == 0) return n;
  Eigen::MatrixXd out = n;
  out.col(n.cols() - 1) -= offset * n.rowwise().sum();
  return out;
}

// Appends pair p's sums to the stacked moments: Ĥ = r_p H (the level operator of its noise handling applied
// first, as MomentProblem::system would), N with its offset c_p (offsetRows) and the counts as they are; no squared
// masses (the joint fit has no CUE).
void appendMoments(const MomentProblem& pair, double ratio, double offset, MomentProblem& joint) {
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
    stack(j.n[f], offsetRows(m.n[f], offset));
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

struct RatioAndOffset {
  double ratio = 0;   // 0: no r (no row with a rising φ)
  double offset = 0;
};

// The least-squares values of the free ones of (r, c) of one pair's rows at φ (f on its level grid), the others held
// at `held`: min Σ_k ((r a_k + c m_k − b_k) / s_k)², a_k = Ĥ_k φ, b_k = N_k φ, m_k = N_k 1, s_k the row's slope of φ.
// r = 0: no row with a rising φ.
RatioAndOffset ratioAt(const MomentSystem& sys, const std::vector<double>& f, RatioAndOffset held, bool free_ratio,
                       bool free_offset) {
  const int L = sys.levels();
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), L);
  const Eigen::VectorXd a = sys.h * fv, b = sys.n * fv, m = sys.n.rowwise().sum();
  Eigen::Matrix2d normal = Eigen::Matrix2d::Zero();
  Eigen::Vector2d rhs = Eigen::Vector2d::Zero();
  for (int i = 0; i < static_cast<int>(a.size()); ++i) {
    const double slope = (f[sys.v1[i]] - f[sys.v0[i]]) * (L - 1) / double(sys.v1[i] - sys.v0[i]);
    if (!(slope > 1e-9)) continue;
    const Eigen::Vector2d row(a[i], m[i]);
    normal += row * row.transpose() / (slope * slope);
    rhs += row * b[i] / (slope * slope);
  }
  if (!(normal(0, 0) > 0) || !(normal(1, 1) > 0)) return {};
  if (free_ratio && free_offset) {
    const Eigen::Vector2d x = normal.ldlt().solve(rhs);
    if (x.allFinite() && x[0] > 0) return {x[0], x[1]};
  }
  if (free_ratio) held.ratio = (rhs[0] - held.offset * normal(0, 1)) / normal(0, 0);
  else if (free_offset) held.offset = (rhs[1] - held.ratio * normal(0, 1)) / normal(1, 1);
  return held;
}

// The pair's rows with its offset in N (offsetRows), for its energies.
MomentSystem withOffset(const MomentSystem& sys, double offset) {
  MomentSystem out = sys;
  out.n = offsetRows(sys.n, offset);
  return out;
}

}  // namespace

void JointCrfFitOptions::check() const {
  if (ratio_rounds < 0 || ratio_rounds > 20) throw InvalidInput("joint fit: ratio_rounds must be in 0..20");
  if (!(ratio_tolerance > 0)) throw InvalidInput("joint fit: ratio_tolerance must be positive");
  if (!(offset_tolerance > 0)) throw InvalidInput("joint fit: offset_tolerance must be positive");
  if (pair_offsets && ratio_rounds < 1)
    throw InvalidInput("joint fit: pair_offsets move in the ratio rounds: ratio_rounds must be at least 1");
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
    if (p < offsets.size() && offsets[p] != 0) s << ", offset " << offsets[p];
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

// The pairs' rows stacked at the ratios and offsets given, as one moment problem at r = 1.
MomentProblem stackAt(const PairProblems& built, const std::vector<double>& ratios, const std::vector<double>& offsets,
                      int level_bins, std::pair<int, int> covered) {
  MomentProblem joint;
  joint.omega.resize(0);
  for (std::size_t p = 0; p < built.problems.size(); ++p)
    appendMoments(built.problems[p], ratios[p], offsets[p], joint);
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
// joint fit): the reference of the pair's misfit. The pair's problem is stacked alone, so r_p (and its offset) is
// held as in the joint fit. `sys`: the pair's rows with that offset.
double ownEnergy(const PairProblems& built, std::size_t p, const MomentSystem& sys, double ratio, double offset,
                 const CrfFitOptions& model) {
  const MomentProblem& problem = built.problems[p];
  MomentProblem alone;
  alone.omega.resize(0);
  appendMoments(problem, ratio, offset, alone);
  alone.level_bins = problem.level_bins;
  alone.level_operator = nullptr;  // applied in appendMoments
  alone.covered_levels = problem.covered_levels;
  CrfFitResult fit;
  fit.covered_levels = problem.covered_levels;
  fitStacked(alone, built.noise[p], model, fit);
  return momentEnergy(sys, onLevelGrid(fit.inverse_crf, sys.levels()), ratio);
}

// φ at the pairs' ratios and offsets; with ratio_rounds, each pair's r (unless held) and its offset (where free)
// moved to its own least-squares values at that φ and φ refitted (the pairs' relative exposures from all their data;
// the common exponent φ^γ, r^γ stays where the starts put it). Fills out.fit, ratios, offsets and the rounds.
void fitRounds(const PairProblems& built, const std::vector<MomentSystem>& systems,
               const std::vector<JointFitPair>& pairs, const std::vector<char>& free_offsets,
               const JointCrfFitOptions& options, std::pair<int, int> covered, JointCrfFitResult& out) {
  CrfFitResult& result = out.fit;
  out.ratios = out.start_ratios;
  out.offsets.clear();
  for (const JointFitPair& pair : pairs) out.offsets.push_back(pair.offset);
  for (int round = 0;; ++round) {
    const MomentProblem joint = stackAt(built, out.ratios, out.offsets, options.model.level_bins, covered);
    int nonempty = 0;
    for (int k = 0; k < joint.moments.bins; ++k)
      nonempty += (joint.moments.count[0][k] + joint.moments.count[1][k]) > 0;
    result.moment_bins = nonempty;
    fitStacked(joint, built.noise.front(), options.model, result);
    out.ratios_at_joint_phi.clear();
    out.offsets_at_joint_phi.clear();
    for (std::size_t p = 0; p < systems.size(); ++p) {
      const MomentSystem& sys = systems[p];
      const RatioAndOffset at = ratioAt(sys, onLevelGrid(result.inverse_crf, sys.levels()),
                                        {out.ratios[p], out.offsets[p]}, !options.hold_ratios, free_offsets[p] != 0);
      out.ratios_at_joint_phi.push_back(at.ratio);
      out.offsets_at_joint_phi.push_back(at.offset);
    }
    out.ratio_rounds = round;
    double moved = 0, offset_moved = 0;  // r in log r; offsets in full scale
    for (std::size_t p = 0; p < out.ratios.size(); ++p)
      if (out.ratios_at_joint_phi[p] > 0) {
        moved = std::max(moved, std::abs(std::log(out.ratios_at_joint_phi[p] / out.ratios[p])));
        offset_moved = std::max(offset_moved, std::abs(out.offsets_at_joint_phi[p] - out.offsets[p]));
      }
    if (round >= options.ratio_rounds ||
        !(moved > options.ratio_tolerance || offset_moved > options.offset_tolerance))
      break;
    for (std::size_t p = 0; p < out.ratios.size(); ++p)
      if (out.ratios_at_joint_phi[p] > 0) {
        out.ratios[p] = out.ratios_at_joint_phi[p];
        out.offsets[p] = out.offsets_at_joint_phi[p];
      }
  }
  result.ratio = 1.0;
}

// The stacked rows' energy per unit weight at out's φ, ratios and offsets (what the φ fit minimises, priors aside).
double totalEnergy(const JointCrfFitResult& out, const std::vector<MomentSystem>& systems) {
  double energy = 0, weight = 0;
  for (std::size_t p = 0; p < systems.size(); ++p) {
    const MomentSystem sys = withOffset(systems[p], out.offsets[p]);
    energy += sys.weight * momentEnergy(sys, onLevelGrid(out.fit.inverse_crf, sys.levels()), out.ratios[p]);
    weight += sys.weight;
  }
  return weight > 0 ? energy / weight : 0.0;
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
  std::vector<MomentSystem> systems;  // each pair's rows without r (Ĥ and N apart): for its r and its energies
  for (const MomentProblem& problem : built.problems) systems.push_back(problem.system(-1));
  const JointCrfFitResult base = out;  // the per-pair parts; the rounds fill the rest
  std::vector<char> free_offsets(pairs.size(), 0);
  fitRounds(built, systems, pairs, free_offsets, options, covered, out);
  if (options.pair_offsets) {
    // One pair's offset at a time, the others' held at theirs (0 unless given): with every offset free the pairs'
    // common shift φ + δ, c_p + δ (1 − r_p) is held only by φ(0) = 0, and the offsets wander along it.
    // The lowest total energy wins (docs/RESULTS.md#joint-offsets).
    out.offset_energies.assign(pairs.size(), -1.0);
    out.no_offset_energy = totalEnergy(out, systems);
    double best = out.no_offset_energy;
    JointCrfFitResult chosen = out;
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      JointCrfFitResult trial = base;
      std::fill(free_offsets.begin(), free_offsets.end(), 0);
      free_offsets[p] = 1;
      fitRounds(built, systems, pairs, free_offsets, options, covered, trial);
      out.offset_energies[p] = totalEnergy(trial, systems);
      if (out.offset_energies[p] < best) best = out.offset_energies[p], chosen = trial;
    }
    chosen.offset_energies = out.offset_energies;
    chosen.no_offset_energy = out.no_offset_energy;
    out = std::move(chosen);
  }
  for (std::size_t p = 0; p < systems.size(); ++p) {
    const MomentSystem sys = withOffset(systems[p], out.offsets[p]);
    out.energies.push_back(momentEnergy(sys, onLevelGrid(out.fit.inverse_crf, sys.levels()), out.ratios[p]));
    out.own_energies.push_back(options.pair_misfits
                                   ? ownEnergy(built, p, sys, out.ratios[p], out.offsets[p], options.model)
                                   : -1.0);
  }
  out.fit.timings.total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return out;
}

}  // namespace crfcal
