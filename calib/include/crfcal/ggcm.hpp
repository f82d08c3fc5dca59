#pragma once
// Generalized Gamma Curve Model (Ng, Chang & Tsui, CVPR 2007 [28]; seed Eq. 19): φ(x) = x^(1/P(x)).
#include <span>
#include <vector>

#include "crfcal/response_model.hpp"

namespace crfcal::ggcm {

// P(x) = Σ α_i x^i.
double polynomial(std::span<const double> alpha, double x);
// φ(x) = x^(1/P(x)); 0 at x = 0, 1 at x = 1.
double evaluate(std::span<const double> alpha, double x);
// ∂φ(x)/∂α_i, written into `gradient` (size = alpha.size()).
void gradient(std::span<const double> alpha, double x, std::span<double> gradient);

// The identity curve φ(x) = x as a GGCM of degree n (α = [1, 0, …]).
GgcmModel identity(int degree = 4);
// γ curve x^γ as a GGCM (α_0 = 1/γ).
GgcmModel fromGamma(double gamma, int degree = 4);

struct FitOptions {
  int degree = 4;            // n of Eq. 19 ("n = 4 is usually accurate enough", Sec. 4)
  int max_evaluations = 4000;
  double tolerance = 1e-12;  // relative tolerance on the least-squares cost
};

struct FitResult {
  GgcmModel model;
  double rmse = 0;
  double max_error = 0;
  bool valid = true;  // monotone with P > 0 (checked after the fit)
};

// Least-squares GGCM fit of an inverse curve given by samples at x = i/(n−1) — how a ColorChecker PCA result
// becomes a GGCM [28]. Linearised start (P(x) = ln x / ln φ(x)), then NLopt L-BFGS refinement with a penalty
// that keeps P > 0 and φ monotone.
FitResult fitInverse(std::span<const double> phi_samples, const FitOptions& options = {});

}  // namespace crfcal::ggcm
