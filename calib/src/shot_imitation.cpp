// A reference shot made to look like another shot (shot_imitation.hpp).
#include "crfcal/shot_imitation.hpp"

#include <algorithm>
#include <cmath>

#include "crfcal/error.hpp"

namespace crfcal {

void ShotImitationOptions::check() const {
  if (levels < 0 || levels == 1) throw InvalidInput("imitation levels must be 0 or >= 2", ErrorSubject::options);
}

namespace {

std::vector<double> sortedUnit(const cv::Mat& image, cv::Mat& unit) {
  if (image.empty() || image.channels() != 1) throw InvalidInput("shot imitation needs single-channel images", ErrorSubject::unspecified);
  image.convertTo(unit, CV_64F, image.depth() == CV_8U ? 1.0 / 255 : 1.0);
  std::vector<double> values(unit.begin<double>(), unit.end<double>());
  std::sort(values.begin(), values.end());
  return values;
}

double sigmaAt(const std::vector<NoiseLevelBin>& bins, double v) {
  if (bins.empty()) return 0;
  if (v <= bins.front().intensity) return bins.front().sigma;
  for (std::size_t i = 0; i + 1 < bins.size(); ++i)
    if (v <= bins[i + 1].intensity) {
      const double span = bins[i + 1].intensity - bins[i].intensity;
      const double t = span > 0 ? (v - bins[i].intensity) / span : 0.0;
      return (1 - t) * bins[i].sigma + t * bins[i + 1].sigma;
    }
  return bins.back().sigma;
}

}  // namespace

cv::Mat imitateShot(const cv::Mat& reference, const cv::Mat& target, const std::vector<NoiseLevelBin>& target_noise,
                    const ShotImitationOptions& options) {
  options.check();
  cv::Mat ref, tgt;
  const std::vector<double> ref_sorted = sortedUnit(reference, ref);
  const std::vector<double> tgt_sorted = sortedUnit(target, tgt);
  std::vector<NoiseLevelBin> bins = target_noise;
  std::sort(bins.begin(), bins.end(), [](const auto& a, const auto& b) { return a.intensity < b.intensity; });
  cv::RNG rng(options.seed);
  cv::Mat out(ref.size(), CV_64F);
  const double n = double(ref_sorted.size()), last = double(tgt_sorted.size() - 1);
  for (int y = 0; y < ref.rows; ++y)
    for (int x = 0; x < ref.cols; ++x) {
      const double v = ref.at<double>(y, x);
      // mid-rank of v among the reference's values (ties share it), read off the target's quantile function
      const auto lo = std::lower_bound(ref_sorted.begin(), ref_sorted.end(), v);
      const auto hi = std::upper_bound(lo, ref_sorted.end(), v);
      const double cdf = (double(lo - ref_sorted.begin()) + double(hi - ref_sorted.begin()) - 1) / (2 * std::max(n - 1, 1.0));
      const double pos = std::clamp(cdf, 0.0, 1.0) * last;
      const auto i = static_cast<std::size_t>(std::floor(pos));
      const double t = pos - double(i);
      const double mapped = i + 1 < tgt_sorted.size() ? (1 - t) * tgt_sorted[i] + t * tgt_sorted[i + 1] : tgt_sorted[i];
      double noisy = mapped + rng.gaussian(1.0) * sigmaAt(bins, mapped);
      noisy = std::clamp(noisy, 0.0, 1.0);
      if (options.levels > 0) noisy = std::round(noisy * (options.levels - 1)) / (options.levels - 1);
      out.at<double>(y, x) = noisy;
    }
  return out;
}

}  // namespace crfcal
