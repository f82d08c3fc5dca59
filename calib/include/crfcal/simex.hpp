#pragma once
// SIMEX — simulation–extrapolation (Cook & Stefanski 1994) for the noise of the sharp shot I.
//
// The noise is in I, the variable φ is evaluated at (Eq. 4 / Eq. 22: r·(φ(I) ⊗ K) = φ(B)): an errors-in-variables
// problem, and the naive fit is biased by it (docs/RESULTS.md#noise-scale: the error grows with σ up to ≈ 8 grey
// levels). SIMEX measures that bias as a function of the noise instead of modelling it: it adds extra Gaussian
// noise of variance λσ̂² to I (σ̂ the fitter's own noise estimate), refits at several λ > 0, and extrapolates every
// sample of φ (and log r) back along λ to λ = −1, where the total noise variance (1 + λ)σ̂² is zero. The extra noise
// is clipped to [0, 1] and quantised like I itself, so the refits see the same kind of data as the naive fit.
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/crf_fitter.hpp"

namespace crfcal {

struct SimexOptions {
  // λ: the added noise variance in multiples of σ̂². Cook & Stefanski's usual grid is 0.5 … 2.
  std::vector<double> added_variance_multiples{0.5, 1.0, 1.5, 2.0};
  int replicates = 2;            // noise re-draws per λ; their curves are averaged (the added noise's own variance)
  int extrapolation_degree = 2;  // polynomial in λ through the λ = 0 fit and the refits: 1 linear, 2 quadratic
  std::uint64_t seed = 1;        // of the added noise
  void check() const;            // throws InvalidInput
};

struct SimexSummary {
  double noise_sigma = 0;                   // σ̂ that scales the added noise (the naive fit's estimate or the given σ)
  std::vector<double> multiples;            // λ of every mean curve below, 0 first (the naive fit)
  std::vector<std::vector<double>> curves;  // mean φ at each λ (kCurveSamples samples)
  std::vector<double> ratios;               // geometric mean r at each λ
  int refits = 0;                           // refits that succeeded
  int failed_refits = 0;                    // refits the fitter rejected (e.g. too few usable pixels)
  bool extrapolated = false;                // false: too few λ survived; the naive fit was returned
};

// The naive fit (fitInverseCrf with `options`), then the SIMEX refits and the extrapolation. The returned φ is a
// TableModel of the extrapolated samples made monotone, with φ(0) = 0 and φ(1) = 1; r is extrapolated in log r
// when options.fit_ratio. Throws what fitInverseCrf throws for the naive fit.
CrfFitResult fitInverseCrfSimex(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                const CrfFitOptions& options, const SimexOptions& simex = {},
                                SimexSummary* summary = nullptr);

}  // namespace crfcal
