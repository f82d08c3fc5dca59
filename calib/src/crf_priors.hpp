#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the priors of the moment objective. They only break ties the data
// leave open — with r = 1 the moments (and the seed's Eq. 22) fix φ on the covered levels only up to an affine map
// a + bφ, and φ^γ with r^γ fits a plain two-exposure pair equally well (the exponential ambiguity):
//  * the extrapolation prior on φ's local exponent below the covered levels (CrfFitOptions::exponent_smoothness)
//    and above them (shoulder_prior; one-sided, or the EMoR mean's shoulder),
//    and, when given, the prior learned from measured curves (learned_prior: the joint Gaussian of the exponents),
//  * the lower bound on the local exponent everywhere (min_local_exponent),
//  * the Gaussian prior on log r around the nominal ratio (ratio_prior_sigma).
#include <array>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "crf_objective.hpp"
#include "crf_optimisation.hpp"
#include "crfcal/crf_fitter.hpp"

namespace crfcal::crf_fit {

// Node triples of the extrapolation prior outside the covered levels [covered_lo, covered_hi].
std::vector<std::array<int, 3>> exponentTriples(int L, int covered_lo, int covered_hi);
// Consecutive node pairs for the local-exponent lower bound.
std::vector<std::array<int, 2>> exponentPairs(int L);

// Sets the extrapolation prior and the local-exponent bound of a system from the options.
void setExtrapolationPrior(MomentSystem& sys, const CrfFitOptions& options, std::pair<int, int> covered_levels);
// Exposure-ratio prior, in the units of the data rows: each bin's residual has the variance s² estimated from the
// fit without the prior (residual_variance; 0: not known yet, no prior), so the data rows and the prior row add up
// to −2 log posterior · s² / weight.
void setRatioPrior(MomentSystem& sys, double residual_variance, const CrfFitOptions& options);

// The prior rows appended to the moment residuals (MomentResiduals): extrapolation prior and learned prior (with_prior only),
// local-exponent bound, ratio prior (r fitted only), in this order.
class PriorRows {
 public:
  PriorRows(const MomentSystem& sys, bool fit_ratio, bool with_prior);
  int count() const { return prior_rows_ + learned_rows_ + bound_rows_ + ratio_rows_; }
  // The local exponents need log φ at every node they use (the first node of a chain is its smallest).
  bool defined(const std::vector<double>& f) const;
  // res[offset .. offset + count()); scale: the extrapolation rows' weights at f (for the Jacobian).
  void residuals(const std::vector<double>& f, double log_r, Eigen::VectorXd& res, int offset,
                 std::vector<double>& scale) const;
  // jm: d × L Jacobian of f; columns 0..d−1 are the model parameters, column d is log r.
  void jacobian(const std::vector<double>& f,
                const Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>& jm,
                const Eigen::VectorXd& res, int offset, const std::vector<double>& scale, int d,
                Eigen::MatrixXd& jac) const;

 private:
  double logx(int v) const;
  double localExponent(const std::vector<double>& f, int a, int b) const;  // d log φ / d log x between a < b

  const MomentSystem& sys_;
  int prior_rows_, learned_rows_, bound_rows_, ratio_rows_;
};

// Fits φ without the extrapolation priors, then with them from the same starts (and the plain fit), and keeps the
// regularised fit while its data energy stays within `energy_factor` of the unregularised one
// (CrfFitOptions::prior_energy_factor).
ModelFit fitModelMomentsWithPrior(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                                  double r0, bool fit_ratio, int max_iterations, double energy_factor);

}  // namespace crfcal::crf_fit
