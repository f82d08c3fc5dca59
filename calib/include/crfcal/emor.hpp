#pragma once
// The EMoR / PCA response basis of Grossberg & Nayar (PAMI 2004), compiled in from samples/emor.
#include <span>
#include <vector>

#include "crfcal/response_model.hpp"

namespace crfcal::emor {

inline constexpr int kSamples = 1024;  // samples at x = i/1023
inline constexpr int kMaxTerms = 25;

// Inverse basis (invemor.txt): g0 = mean inverse CRF, hinv(k), k = 1..25.
std::span<const double, kSamples> inverseMean();
std::span<const double, kSamples> inverseBasis(int k);  // 1-based k
// Forward basis (emor.txt): f0 = mean CRF, h(k) — used for Hugin's EMoR coefficients.
std::span<const double, kSamples> forwardMean();
std::span<const double, kSamples> forwardBasis(int k);

struct FitOptions {
  int terms = 5;                // K: number of basis curves (Grossberg & Nayar: 3–5 reach DoRF's accuracy)
  bool enforce_monotone = true;  // constrained least squares when the unconstrained fit is not monotone
  int monotone_grid = 1024;     // grid on which φ' ≥ 0 is imposed (1024 = the basis nodes: then φ is monotone everywhere)
};

struct FitResult {
  EmorModel model;
  double rmse = 0;       // over the given samples
  double max_error = 0;
  bool constrained = false;  // monotonicity constraints were active
};

// Least-squares EMoR fit of an inverse curve given by samples at x = i/(n−1) (optionally weighted).
// φ(0) = 0 and φ(1) = 1 hold by construction (every basis curve vanishes at both ends).
FitResult fitInverse(std::span<const double> phi_samples, const FitOptions& options = {},
                     std::span<const double> weights = {});

// Same for a forward curve ψ in the forward basis (f0, h_k); returns the coefficients.
std::vector<double> fitForward(std::span<const double> psi_samples, int terms);
// ψ(x) = f0(x) + Σ c_k h_k(x), at 1024 points.
std::vector<double> evaluateForward(std::span<const double> coefficients);

}  // namespace crfcal::emor
