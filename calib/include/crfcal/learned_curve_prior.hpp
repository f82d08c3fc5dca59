#pragma once
// A prior over the inverse response φ outside the range a pair's data cover, learned from measured curves (issue 19).
//
// Why: with ΣK = 1, φ → bφ leaves Eq. 4 unchanged at every r (and φ → a + bφ at r = 1), so inside the covered range
// [x_lo, x_hi] the data fix φ only up to its scale, and φ(1) = 1 is reached by extrapolating from x_hi to 1. The
// hand-set priors (a rising exponent free above the data, or the EMoR mean's shoulder) were chosen on ten cameras.
// This prior is a Gaussian over the local-exponent curve g_j = Δlog φ / Δlog x between the nodes x_j = j/64,
// j = 1..64 (63 exponents; invariant under φ → bφ, so it can be conditioned on the shape the data fix), estimated
// from training curves with shrinkage of the covariance towards its diagonal. Conditioned on the exponents inside
// the covered range, its mean and covariance outside set the extrapolation — and so the scale of the whole curve.
// Built from curves given as vectors (no file I/O here): a bench can pass a prior learned without the case's camera.
#include <cstdint>
#include <memory>
#include <utility>
#include <vector>

#include <Eigen/Core>

namespace crfcal {

struct LearnedCurvePriorOptions {
  // Weight α of the covariance's diagonal in the estimate (1 − α) S + α diag(S): a few curves give a rank-deficient
  // sample covariance S, whose conditional would claim certainty along every direction they do not span.
  // Leave-one-camera-out on the ten bundled camera curves (docs/RESULTS.md#learned-prior): less shrinkage is better
  // when the shape inside is exact; 0.1 keeps some room for a fitted curve's errors.
  double shrinkage = 0.1;
  // Floor of each exponent's standard deviation (no direction of the prior is certain from a handful of curves).
  double exponent_sigma_floor = 0.05;
  // σ of the noise of a fitted curve's exponents inside the covered range: added to the observed block's variance
  // before conditioning (a fit's local exponent near the top of its data is not exact).
  double observed_exponent_sigma = 0.1;
  void check() const;  // throws InvalidInput
};

struct LearnedCurvePrior {
  static constexpr int kNodes = 64;                 // nodes x_j = j / 64, j = 1..64 (x = 0 has no logarithm)
  static constexpr int kExponents = kNodes - 1;     // g_j between x_j and x_{j+1}
  Eigen::VectorXd mean;                             // kExponents
  Eigen::MatrixXd covariance;                       // kExponents × kExponents (shrunk, floored)
  double observed_exponent_sigma = 0.1;             // LearnedCurvePriorOptions::observed_exponent_sigma
  int curves = 0;                                   // training curves
  bool empty() const { return curves == 0; }
};

// The prior from training curves: each a table φ(i / (n − 1)), i = 0..n−1 (n ≥ 65), φ(0) = 0, φ(1) = 1,
// non-decreasing. At least 2 curves. Throws InvalidInput (subject: curve) otherwise.
LearnedCurvePrior learnCurvePrior(const std::vector<std::vector<double>>& inverse_crfs,
                                  const LearnedCurvePriorOptions& options = {});

// The local exponents g_j of a curve table (as above) on the prior's nodes (φ floored at 1e-9 before the logarithm).
Eigen::VectorXd localExponents(const std::vector<double>& inverse_crf);

// The Gaussian of the exponents outside a covered range given those inside: g_U | g_O ~ N(offset + gain · g_O, cov).
// Exponent j is observed when both its nodes lie inside `covered` (x in [0, 1]); the observed block's variance gets
// observed_exponent_sigma².
struct ConditionalExponents {
  std::vector<int> observed, unobserved;  // exponent indices j − 1 (0-based)
  Eigen::MatrixXd gain;                   // |U| × |O|
  Eigen::VectorXd offset;                 // |U|
  Eigen::MatrixXd covariance;             // |U| × |U|
};
ConditionalExponents conditionOnCovered(const LearnedCurvePrior& prior, std::pair<double, double> covered);

// φ kept inside the covered range up to a common factor, continued outside with the prior's conditional mean
// exponents (power laws between nodes; below x = 1/64 the first exponent), the factor making φ(1) = 1. Same size as
// the input. What the prior alone says the curve's scale is, given its shape on the data (tests, bench tables).
std::vector<double> extrapolateWithPrior(const LearnedCurvePrior& prior, const std::vector<double>& inverse_crf,
                                         std::pair<double, double> covered);

// Whether a node x = j/64 (j ≥ 1) lies inside the covered range: what extrapolateWithPrior and continuationQuantiles
// continue the curve from (without one they throw).
bool coversANode(std::pair<double, double> covered);

// The prior's spread of φ beyond the data, as pointwise quantiles (issue 19: a band above the covered range that is a
// probability, not a bound). Each draw takes the exponents outside the covered range from the conditional Gaussian
// (conditionOnCovered, given the curve's own exponents inside), continues the curve from its highest node inside the
// covered range with them, and scales the whole curve so that φ(1) = 1; `lower` / `upper` are the draws' pointwise
// quantiles at (1 ∓ level) / 2, `scale_range` the same quantiles of the factor s each draw applies to the curve
// (s·φ on the covered range). Samples at or below the highest node inside take s·φ of each draw. Deterministic
// for a seed.
struct PriorContinuation {
  std::vector<double> lower, upper;              // same size as the curve; φ(1) = 1
  std::pair<double, double> scale_range{1, 1};   // quantiles of s
  double top_node_x = 1;                         // x of the highest node inside the covered range
  int draws = 0;
};
PriorContinuation continuationQuantiles(const LearnedCurvePrior& prior, const std::vector<double>& inverse_crf,
                                        std::pair<double, double> covered, double level, int draws = 512,
                                        std::uint64_t seed = 1);

}  // namespace crfcal
