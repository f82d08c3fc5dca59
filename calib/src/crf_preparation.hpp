#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the data every objective works on — the pair on a level grid, σ of
// I's noise, the usable pixels (inside the border, away from saturation, on edges: the weights W of seed Eq. 23/24
// or B's local range for the moments) and the noise operators (debias R, Jensen J, the transition matrix T).
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_debias.hpp"

namespace crfcal::crf_fit {

struct Prepared {
  int levels = 256;
  cv::Mat kernel;                  // normalised CV_64F
  cv::Mat sharp_unit, blurred_unit;
  cv::Mat sharp_used;              // sharp_unit, or its denoised version (NoiseHandling::denoise)
  LevelImage sharp, blurred;       // sharp_used and blurred_unit on the level grid
  // B's local min/max over K's support (moment objectives only): the pixel selection and the instrument bins both
  // read it, so it is formed once per fit.
  LocalRange blurred_range;
  double sigma = 0;                // σ of I's noise (given or estimated; mean over levels when per level)
  std::vector<cv::Point> pixels;
  std::vector<double> seed_weight;  // W_p (seed objective)
  // Censored observations (crf_censored.hpp; CrfFitOptions::censored_weight): B clipped (+1) or below the clip
  // next to one (−1). Empty when the term is off or B has no usable clipped pixel.
  std::vector<cv::Point> censored_pixels;
  std::vector<signed char> censored_side;
};

// Checks the pair, converts it to levels, estimates σ and selects the usable pixels. Fills result.levels,
// result.noise_sigma(_estimated) and result.pixels; throws InvalidInput for a bad pair (see fitInverseCrf).
Prepared preparePair(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                     const CrfFitOptions& options, CrfFitResult& result);

// The level operators of the noise handling (CrfFitOptions::Experimental::noise).
struct NoiseOperators {
  NoiseDebias debias;          // g = R φ (NoiseHandling::debias)
  bool debias_active = false;
  Eigen::MatrixXd jensen;      // g = J φ (NoiseHandling::jensen, moments); empty: not used
  NoiseDebias noise_only;      // the transition matrix for the CUE variances when φ is not debiased
  bool noise_only_active = false;

  // The operator applied to the moment rows (R, J or none).
  const Eigen::MatrixXd* levelOperator() const {
    return debias_active ? &debias.matrix() : jensen.size() ? &jensen : nullptr;
  }
  // I's noise transition matrix T (null: I treated as noise-free).
  const NoiseDebias* transition() const {
    if (debias_active) return &debias;
    return noise_only_active ? &noise_only : nullptr;
  }
};

NoiseOperators makeNoiseOperators(const Prepared& prep, const CrfFitOptions& options);

}  // namespace crfcal::crf_fit
