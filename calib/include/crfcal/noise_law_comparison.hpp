#pragma once
// An image's measured noise σ(v) against a noise law σ_law(v): noise reduction shows as a measured σ below the law.
//
// The seed's simulation (Sec. 5) adds noise to the sharp shot I and nothing else; a phone applies noise reduction
// (NR) at high ISO. The law is what the shot's noise would be without any extra processing: a sensor profile
// pushed through the curve (noise_model.hpp), or the measured σ(v) of another shot of the same camera at the same
// ISO (same analogue gain: at the same output level the same raw signal, hence the same noise, if both shots went
// through the same processing). σ(v) of the image: Immerkær residuals of its flattest pixels per level bin
// (measureNoiseLevels). Pure computation.
#include <functional>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/noise_model.hpp"

namespace crfcal {

struct NoiseLawOptions {
  NoiseLevelOptions levels = [] {
    NoiseLevelOptions o;
    // Equal-width bins over [0.02, 0.98]: a short shot underexposed by r holds most pixels below 0.3, so 20 bins
    // (5–6 there) rather than `study noise`'s 10; 100 pixels a bin keep a bin's robust σ within ≈ 9 %.
    o.bins = 20;
    o.min_samples = 100;
    return o;
  }();
  // The median ratio measured/law below which the image counts as noise-reduced: a 30 % deficit, beyond a bin's
  // robust-σ sampling error (≈ 9 % at 100 samples: 1.4826·MAD has ≈ 1.67× the variance of the sample σ) and the
  // 1/3-stop rounding of a nominal ISO (σ ∝ √gain: ±6 %). Above 1/reduced_below: noisier than the law.
  double reduced_below = 0.7;
  void check() const;  // throws InvalidInput
};

struct NoiseLawComparison {
  std::vector<NoiseLevelBin> bins;  // the image's measured bins that the law covers
  std::vector<double> law_sigma;    // the law at each bin's intensity
  std::vector<double> ratio;        // measured / law per bin
  double median_ratio = 0;          // NaN when no bin is covered
  bool reduced = false;             // median_ratio < reduced_below
  bool noisier = false;             // median_ratio > 1 / reduced_below
};

// `law` returns σ at an intensity in [0, 1], or NaN where it does not know (those bins are skipped).
NoiseLawComparison compareNoiseToLaw(const cv::Mat& image, const std::function<double(double)>& law,
                                     const NoiseLawOptions& options = {});

// A measured σ(v) as a law: linear between the bins' intensities, NaN outside them.
std::function<double(double)> noiseLawFromBins(const std::vector<NoiseLevelBin>& bins);

}  // namespace crfcal
