#pragma once
// Unbiased level functions for a noisy sharp image (errors in variables).
//
// The sharp image is observed as I = Q(clip(c + n)), c the clean intensity, n ~ N(0, σ²) per pixel, Q the
// rounding to L levels. For a convex φ, E[φ(I)] ≠ φ(c) (Jensen), so the mixture Σ_v w_p(v) φ(x_v) of a
// noisy I is biased. This operator finds, for any function f on the level grid, the function g = R f with
//   E[g(I) | c] = Σ_v T(c, v) g(x_v) ≈ f(c)   for every clean level c,
// T the noise/clip/quantisation transition matrix, by Tikhonov-regularised deconvolution
//   R = (TᵀT + λ D₂ᵀD₂)⁻¹ Tᵀ   (D₂ second differences, λ = `regularization` · trace(TᵀT)/L; or λ I: ridge).
// T is the clipped noise law: observed levels 0 and L−1 carry the point masses P(c + n ≤ ½ step) and
// P(c + n ≥ 1 − ½ step), so every row sums to 1. g is the corrected score function of Nakamura (1990) /
// Stefanski (1989) for the level function f.
// Then Σ_v w_p(v) g(x_v) is an unbiased estimate of (f(c) ⊗ K)(p) and, with u_p the squared masses,
// Σ_v u_p(v) [g(x_v)² − (R f²)(x_v)] is an unbiased estimate of its variance (level_mixture.hpp).
#include <span>
#include <vector>

#include <Eigen/Core>

namespace crfcal {

// How the deconvolution is regularised: smoothness penalises R f's second differences (λ D₂ᵀD₂, the default),
// ridge its size (λ I, plain Tikhonov).
enum class DebiasRegularizer { smoothness, ridge };

// Every field defines the operator: a new one must also be compared in calib/src/noise_debias_cache.cpp.
struct NoiseDebiasOptions {
  int levels = 256;              // L
  double sigma = 0;              // noise std of I, intensities in [0,1]; 0 → R = identity
  double regularization = 1e-4;  // λ relative to trace(TᵀT)/L
  DebiasRegularizer regularizer = DebiasRegularizer::smoothness;
  // Optional signal-dependent noise: σ of I at each clean level (size = levels); overrides `sigma` when set.
  std::vector<double> sigma_per_level;
  void check() const;            // throws InvalidInput
};

class NoiseDebias {
 public:
  NoiseDebias() = default;
  explicit NoiseDebias(const NoiseDebiasOptions& options);

  bool identity() const { return identity_; }
  int levels() const { return levels_; }
  double sigma() const { return sigma_; }  // σ (mean over levels when per level)
  // g = R f.
  void apply(std::span<const double> f, std::span<double> g) const;
  std::vector<double> apply(std::span<const double> f) const;
  // The L×L matrix R (identity when σ = 0) and the transition matrix T (rows: clean level, cols: observed).
  const Eigen::MatrixXd& matrix() const { return r_; }
  const Eigen::MatrixXd& transition() const { return t_; }

 private:
  bool identity_ = true;
  int levels_ = 0;
  double sigma_ = 0;
  Eigen::MatrixXd r_, t_;
};

}  // namespace crfcal
