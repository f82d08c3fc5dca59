// Measured noise against a noise law (noise_law_comparison.hpp).
#include "crfcal/noise_law_comparison.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "crfcal/error.hpp"

namespace crfcal {

void NoiseLawOptions::check() const {
  levels.check();
  if (!(reduced_below > 0 && reduced_below < 1))
    throw InvalidInput("noise reduction threshold must be in (0, 1)", ErrorSubject::options);
}

NoiseLawComparison compareNoiseToLaw(const cv::Mat& image, const std::function<double(double)>& law,
                                     const NoiseLawOptions& options) {
  options.check();
  NoiseLawComparison result;
  for (const NoiseLevelBin& bin : measureNoiseLevels(image, options.levels)) {
    const double expected = law(bin.intensity);
    if (!(std::isfinite(expected) && expected > 0) || !(bin.sigma > 0)) continue;
    result.bins.push_back(bin);
    result.law_sigma.push_back(expected);
    result.ratio.push_back(bin.sigma / expected);
  }
  if (result.ratio.empty()) {
    result.median_ratio = std::numeric_limits<double>::quiet_NaN();
    return result;
  }
  std::vector<double> sorted = result.ratio;
  std::sort(sorted.begin(), sorted.end());
  const std::size_t m = sorted.size() / 2;
  result.median_ratio = sorted.size() % 2 ? sorted[m] : std::sqrt(sorted[m - 1] * sorted[m]);
  result.reduced = result.median_ratio < options.reduced_below;
  result.noisier = result.median_ratio > 1 / options.reduced_below;
  return result;
}

std::function<double(double)> noiseLawFromBins(const std::vector<NoiseLevelBin>& bins) {
  std::vector<NoiseLevelBin> sorted = bins;
  std::sort(sorted.begin(), sorted.end(), [](const auto& a, const auto& b) { return a.intensity < b.intensity; });
  return [sorted](double v) {
    if (sorted.empty() || v < sorted.front().intensity || v > sorted.back().intensity)
      return std::numeric_limits<double>::quiet_NaN();
    if (sorted.size() == 1) return sorted.front().sigma;
    for (std::size_t i = 0; i + 1 < sorted.size(); ++i)
      if (v <= sorted[i + 1].intensity) {
        const double span = sorted[i + 1].intensity - sorted[i].intensity;
        const double t = span > 0 ? (v - sorted[i].intensity) / span : 0.0;
        return (1 - t) * sorted[i].sigma + t * sorted[i + 1].sigma;
      }
    return sorted.back().sigma;
  };
}

}  // namespace crfcal
