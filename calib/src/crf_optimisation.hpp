#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the solvers and the per-model fits.
//  * Nelder–Mead (NLopt) for the seed's Eq. 22, alternated with the closed-form r of Eq. 25 (alternateRatio);
//  * Levenberg–Marquardt on the moment residuals (crf_objective.hpp) from several starts, jointly in (φ, log r);
//    EMoR first from its linear least-squares solution at the nominal r;
//  * the ablations: Nelder–Mead on the moment energy with r profiled out, and the CUE refinement.
#include <functional>
#include <vector>

#include <Eigen/Core>

#include "crf_curve.hpp"
#include "crf_objective.hpp"
#include "crfcal/crf_fitter.hpp"

namespace crfcal::crf_fit {

struct Minimum {
  std::vector<double> x;
  double value = kInf;
  int evaluations = 0;
};
// Nelder–Mead through NLopt (LN_NELDERMEAD), keeping the best point seen.
Minimum nelderMead(const std::vector<double>& x0, const std::function<double(const std::vector<double>&)>& objective,
                   int max_evaluations, double step, double ftol = 1e-10);

// Levenberg–Marquardt on a residual vector. `residuals(x, r, jac)` returns false outside the domain. Hand-written
// for a measured reason (see crf_optimisation.cpp: Eigen's MINPACK LM changes the bench tables).
using ResidualFn = std::function<bool(const Eigen::VectorXd& x, Eigen::VectorXd& r, Eigen::MatrixXd* jac)>;
struct LmResult {
  Eigen::VectorXd x;
  double cost = kInf;
  int iterations = 0;
  int evaluations = 0;
};
LmResult levenbergMarquardt(const Eigen::VectorXd& x0, const ResidualFn& residuals, int max_iterations);

// One model fitted to one system.
struct ModelFit {
  std::vector<double> x;
  double ratio = 1;
  double energy = kInf;  // per unit weight
  bool valid = false;
  int evaluations = 0;
  int iterations = 0;
};

// Levenberg–Marquardt on the moment residuals from every start (EMoR without starts: its linear least-squares
// solution at r0 and the mean curve); the best end point. with_prior: include the extrapolation prior rows (the
// lower bound on the local exponent is always included).
ModelFit fitModelMoments(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                         double r0, bool fit_ratio, int max_iterations, bool with_prior);
// Levenberg–Marquardt on the CUE residuals (finite-difference Jacobian).
ModelFit fitModelCue(const Curve& curve, const MomentSystem& sys, const CueModel& cue,
                     std::vector<std::vector<double>> starts, double r0, bool fit_ratio, int max_iterations);
// Ablation (CrfOptimizer::nelder_mead): Nelder–Mead on the moment energy of GGCM, r profiled out (closed form).
ModelFit fitGgcmNelderMead(const Curve& ggcm_curve, const MomentSystem& full,
                           const std::vector<std::vector<double>>& starts, double ratio, bool fit_ratio,
                           int max_evaluations);

// The seed's optimisation: Nelder–Mead on Eq. 22 at fixed r, then r from Eq. 25, alternated until r changes by
// less than 10⁻⁴ (at most ratio_rounds rounds; one when r is not fitted). objective.ratio ends at the final r.
struct SeedFit {
  std::vector<double> x;
  int evaluations = 0;
  int rounds = 0;
};
SeedFit alternateRatio(SeedObjective& objective, std::vector<double> x, const CrfFitOptions& options,
                       const std::function<void(double fraction)>& progress);

}  // namespace crfcal::crf_fit
