// One channel's fit of the residual model (effect_problem.hpp): its design rows, the linear start, the samples by
// weight group and the Levenberg–Marquardt on them (effect_grouped_residuals.hpp), one plateau level's fit and the
// fit with the plateau searched (effect_plateau_grid.cpp). Split from effect_problem.cpp, the model it fits.
#include <algorithm>
#include <cmath>

#include "effect_problem.hpp"

namespace crfcal::effect {

Problem::DesignRows Problem::designRows(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx) const {
  DesignRows rows;
  if (idx.empty()) return rows;
  double buffer[48], t;
  rows.cols = row(s, idx[0], spec, buffer, t);
  rows.values.resize(idx.size() * static_cast<std::size_t>(rows.cols));
  rows.target.resize(idx.size());
  rows.position.assign(s.size(), -1);
  for (std::size_t k = 0; k < idx.size(); ++k) {
    row(s, idx[k], spec, rows.values.data() + k * rows.cols, rows.target[k]);
    rows.position[idx[k]] = static_cast<int>(k);
  }
  return rows;
}

const double* Problem::designRow(const Samples& s, std::size_t i, const Spec& spec, const DesignRows* rows,
                                 double* buffer, double& t) const {
  if (rows) {
    t = rows->targetAt(i);
    return rows->at(i);
  }
  row(s, i, spec, buffer, t);
  return buffer;
}

Eigen::VectorXd Problem::linearStart(const Samples& s, const Spec& spec, const std::vector<std::size_t>& use,
                                     int cols, const DesignRows* rows) const {
  double buffer[48], t;
  const int terms = static_cast<int>(s.Dh.size());
  Eigen::VectorXd theta = Eigen::VectorXd::Zero(cols);
  const int lin = cols - terms;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(lin, lin);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(lin);
  for (auto i : use) {
    const double* x = designRow(s, i, spec, rows, buffer, t);
    const double w = weight(s, i, nullptr), w2 = w * w;
    for (int a = 0; a < lin; ++a) {
      b(a) += w2 * x[a] * t;
      for (int c = 0; c <= a; ++c) A(a, c) += w2 * x[a] * x[c];
    }
  }
  for (int a = 0; a < lin; ++a)
    for (int c = a + 1; c < lin; ++c) A(a, c) = A(c, a);
  if (lin > 0) {
    A.diagonal().array() += 1e-12 * (A.diagonal().array().abs().maxCoeff() + 1e-30);
    theta.head(lin) = A.ldlt().solve(b);
  }
  return theta;
}

// The used samples' design rows and targets by weight group (every sample its own without groups), the groups
// numbered in order of first use.
GroupedResiduals Problem::groupedResiduals(const Samples& s, const Spec& spec, const std::vector<std::size_t>& use,
                                           int cols, const DesignRows* rows) const {
  const int terms = static_cast<int>(s.Dh.size());
  const bool grouped = s.weight_group.size() == s.size();
  std::vector<int> compact(grouped ? static_cast<std::size_t>(s.weight_groups) : 0, -1), group_of(use.size());
  std::vector<std::size_t> first;
  std::vector<int> size;
  for (std::size_t k = 0; k < use.size(); ++k) {
    int* id = grouped ? &compact[static_cast<std::size_t>(s.weight_group[use[k]])] : nullptr;
    if (!id || *id < 0) {
      if (id) *id = static_cast<int>(first.size());
      group_of[k] = static_cast<int>(first.size());
      first.push_back(use[k]);
      size.push_back(0);
    } else {
      group_of[k] = *id;
    }
    ++size[static_cast<std::size_t>(group_of[k])];
  }
  GroupedResiduals residuals(cols, terms, min_derivative_);
  double buffer[48], slope[48];
  for (std::size_t g = 0; g < first.size(); ++g) {
    for (int j = 0; j < terms; ++j) slope[j] = s.Dh[static_cast<std::size_t>(j)][first[g]];
    residuals.addGroup(s.d[first[g]], slope, size[g]);
  }
  for (std::size_t k = 0; k < use.size(); ++k) {
    double t = 0;
    const double* x = designRow(s, use[k], spec, rows, buffer, t);
    residuals.add(group_of[k], x, t, s.level[use[k]]);
  }
  return residuals;
}

// Levenberg–Marquardt on r_i = w_i(θ) (t_i − c_i·θ): w depends on the φ re-fit through φ'(B). The samples are
// factorised once per run and weight group (effect_grouped_residuals.hpp), so every pass costs O(groups · cols²)
// instead of O(samples · cols²), in the search's hundreds of fits per pair. With `state`, a run stopped by a
// `tolerance` above kFitTolerance can be run on later from θ and `state` through the same passes as one run to
// kFitTolerance.
void Problem::levenbergMarquardt(const Samples& s, const Spec& spec, const std::vector<std::size_t>& use,
                                 Eigen::VectorXd& theta, const DesignRows* rows, double tolerance, LmState* state,
                                 GroupedResiduals* grouped) const {
  GroupedResiduals own_groups(0, 0, min_derivative_);
  if (!grouped) own_groups = groupedResiduals(s, spec, use, static_cast<int>(theta.size()), rows);
  GroupedResiduals& residuals = grouped ? *grouped : own_groups;
  LmState own;
  LmState& st = state ? *state : own;
  st.finished = true;  // unless paused below
  double mu = st.mu, current = residuals.evaluate(theta);
  Eigen::MatrixXd JtJ;
  Eigen::VectorXd Jtr;
  for (int iteration = st.iteration; iteration < kFitPasses; ++iteration) {
    residuals.normalEquations(JtJ, Jtr);
    bool improved = false;
    for (int attempt = 0; attempt < 6 && !improved; ++attempt) {
      Eigen::MatrixXd H = JtJ;
      H.diagonal() += mu * JtJ.diagonal().cwiseMax(1e-30);
      const Eigen::VectorXd step = H.ldlt().solve(-Jtr);
      if (!step.allFinite()) break;
      const Eigen::VectorXd next = theta + step;
      const double c = residuals.evaluate(next);  // the groups now at `next`: the next pass linearises there if kept
      if (c < current) {
        improved = true;
        const double drop = (current - c) / std::max(current, 1e-300);
        theta = next;
        current = c;
        mu = std::max(mu / 3, 1e-9);
        if (drop < kFitTolerance) {
          iteration = 1000;
        } else if (drop < tolerance) {  // paused: `state` can run it on
          st = LmState{mu, iteration + 1, false};
          return;
        }
      } else {
        mu *= 4;
      }
    }
    if (!improved) break;
  }
}

// Least squares of the intensity-scaled residuals r_i = w_i(θ) (t_i − c_i·θ), Levenberg–Marquardt (w depends on
// the φ re-fit; without φ terms one linear solve). Samples on B's plateau (clip level `clip`, B intensity) are
// censored: they do not enter the fit.
ChannelFit Problem::fitLevel(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx, double clip,
                             const Eigen::VectorXd* start, const DesignRows* rows, double tolerance, LmState* state,
                             const GroupedResiduals* all_groups) const {
  double buffer[48], t;
  const int cols = rows ? rows->cols : row(s, idx[0], spec, buffer, t);
  const int terms = static_cast<int>(s.Dh.size());
  std::vector<std::size_t> use;
  for (auto i : idx)
    if (!(clip > 0 && s.level[i] >= clip)) use.push_back(i);  // clip > 1: none
  ChannelFit f;
  if (use.size() < 20) return f;
  // Start: the given one, else the linear solution without the φ terms (weights of φ̂).
  Eigen::VectorXd theta;
  if (start && start->size() == cols && start->allFinite()) {
    theta = *start;
  } else {
    theta = linearStart(s, spec, use, cols, rows);
    if (!theta.allFinite()) return f;
  }
  if (terms > 0) {
    GroupedResiduals below_clip(0, 0, min_derivative_);
    const bool shared = all_groups && all_groups->below(clip > 0 ? clip : 2.0, below_clip);
    levenbergMarquardt(s, spec, use, theta, rows, tolerance, state, shared ? &below_clip : nullptr);
  } else if (state) {
    state->finished = true;
  }
  f.theta = theta;
  f.clip = clip;
  f.ok = theta.allFinite();
  return f;
}

ChannelFit Problem::fit(const Samples& s, const Spec& spec, int fold, const Eigen::VectorXd* start) const {
  std::vector<std::size_t> idx;
  for (std::size_t i = 0; i < s.size(); ++i)
    if (fold < 0 || s.fold[i] == fold) idx.push_back(i);
  if (idx.size() < 20) return {};
  if (!spec.clipping) return fitLevel(s, spec, idx, 0, start);
  // Plateau level of B on a grid of its upper quantiles; the best (lowest in-sample error) is kept.
  // Every plateau level's fit and error reads the same design rows: formed once (12 fits × 2 passes before).
  const DesignRows rows = designRows(s, spec, idx);
  return bestPlateau(s, spec, idx, plateauGrid(s, idx), start, rows);
}

}  // namespace crfcal::effect
