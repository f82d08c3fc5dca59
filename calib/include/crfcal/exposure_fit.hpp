#pragma once
// Exposure ratios measured from the images themselves, to check the EXIF ratio r of Eq. 4 (footnote 4).
//
// The seed takes r from the EXIF exposure times and ISOs and treats it as exact. Nominal shutter speeds are
// rounded (a "1/60 s" step is really 1/64 s in a 1-EV sequence, "1/125" is 1/128), ISO is nominal, and phones
// re-meter. Two estimators:
//  * estimateExposureRatio: with a known φ, the median of φ(z₂)/φ(z₁) over well-exposed pixels of both frames
//    (registered frames), or of the matched quantiles of φ(z₂) and φ(z₁) (not registered: histogram
//    specification, Grossberg & Nayar 2003 — valid for the same scene content).
//  * fitBracket: φ unknown — a joint fit of an EMoR inverse curve (Grossberg & Nayar 2004) and the per-frame log
//    exposures of a registered bracket, Mitsunaga–Nayar style: Σ_p Σ_j (log φ(z_{j+1,p}) − log φ(z_{j,p}) −
//    (e_{j+1} − e_j))² over pixels well exposed in both frames. The exponential ambiguity (φ^γ with all ratios
//    raised to γ fits equally well, Grossberg & Nayar 2003) is removed by fixing the total span e_last − e_first to
//    the nominal one; the fit then tells how the individual steps deviate from nominal. NLopt (BOBYQA).
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal {

struct ExposureRatioOptions {
  double low = 0.06;        // intensities (both frames) used: in [low, high]
  double high = 0.92;
  bool registered = true;   // false: quantile matching instead of per-pixel ratios
  int min_pixels = 100;
  void check() const;
};

struct ExposureRatioEstimate {
  double ratio = 0;     // frame 2 over frame 1 (irradiance units)
  double spread = 0;    // robust relative spread (1.4826·MAD/median of the per-pixel ratios; quantiles: of the
                        // quantile ratios)
  int pixels = 0;
};

// `first`, `second`: single channel images of the same size (registered) or of the same scene. Throws
// InvalidInput when too few pixels are usable.
ExposureRatioEstimate estimateExposureRatio(const cv::Mat& first, const cv::Mat& second, const ResponseCurve& curve,
                                            const ExposureRatioOptions& options = {});

struct BracketFitOptions {
  int terms = 4;            // EMoR terms K
  double low = 0.04, high = 0.94;
  int samples = 4000;       // pixel positions drawn (deterministic)
  int max_evaluations = 6000;
  std::uint64_t seed = 7;
  bool fixed_exposures = false;  // every exposure at its nominal value (the EXIF assumption): only φ is fitted
  cv::Rect region;               // draw the pixels from this region only (empty: the whole frame)
  void check() const;
};

struct BracketFitResult {
  EmorModel model;                    // fitted φ
  std::vector<double> inverse_crf;    // φ(i/1023)
  std::vector<double> log_exposure;   // e_j (natural log), e_0 = 0
  std::vector<double> step_ratio;     // exp(e_{j+1} − e_j), j = 0..n−2
  double rms_residual = 0;            // of the log-domain residuals
  int pairs_used = 0;
  std::string summary() const;
};

// `frames`: registered single-channel images ordered by exposure (any depth); `nominal_exposure`: their nominal
// relative exposures (e.g. EXIF times), used for the start and for the span. Throws InvalidInput.
BracketFitResult fitBracket(const std::vector<cv::Mat>& frames, const std::vector<double>& nominal_exposure,
                            const BracketFitOptions& options = {});

// Held-out check of a bracket fit: each frame j + 1 predicted from frame j through the fit, ẑ = ψ(s_j φ(z_j))
// (s_j the fit's step ratio), on the pixels of `region` (empty: whole frame) well exposed in both frames; RMS of
// ẑ − z_{j+1} in intensity units (per step and over all steps, last entry).
std::vector<double> bracketPredictionRmse(const std::vector<cv::Mat>& frames, const BracketFitResult& fit,
                                          const cv::Rect& region = {}, double low = 0.04, double high = 0.94);

}  // namespace crfcal
