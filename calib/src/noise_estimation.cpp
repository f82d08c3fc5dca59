#include "crfcal/noise_estimation.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"

namespace crfcal {

void NoiseEstimationOptions::check() const {
  if (!(clip_margin >= 0 && clip_margin < 0.5)) throw InvalidInput("noise estimation: clip_margin must be in [0, 0.5)");
  if (min_samples < 1) throw InvalidInput("noise estimation: min_samples must be positive");
}

NoiseEstimate estimateNoiseSigma(const cv::Mat& image, const NoiseEstimationOptions& options) {
  options.check();
  const cv::Mat unit = toUnitGray(image);
  if (unit.rows < 9 || unit.cols < 9) throw InvalidInput("noise estimation: image smaller than 9x9");
  const cv::Mat mask = (cv::Mat_<double>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1) / 6.0;
  cv::Mat response, mean;
  cv::filter2D(unit, response, CV_64F, mask, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  cv::blur(unit, mean, cv::Size(7, 7), cv::Point(-1, -1), cv::BORDER_REFLECT);
  std::vector<double> inside, all;
  for (int y = 1; y < unit.rows - 1; ++y) {
    const double* r = response.ptr<double>(y);
    const double* m = mean.ptr<double>(y);
    for (int x = 1; x < unit.cols - 1; ++x) {
      const double a = std::abs(r[x]);
      all.push_back(a);
      if (m[x] >= options.clip_margin && m[x] <= 1 - options.clip_margin) inside.push_back(a);
    }
  }
  std::vector<double>& use = static_cast<int>(inside.size()) >= options.min_samples ? inside : all;
  NoiseEstimate est;
  est.samples = static_cast<int>(use.size());
  auto mid = use.begin() + static_cast<std::ptrdiff_t>(use.size() / 2);
  std::nth_element(use.begin(), mid, use.end());
  est.sigma = 1.4826 * *mid;
  return est;
}

}  // namespace crfcal
