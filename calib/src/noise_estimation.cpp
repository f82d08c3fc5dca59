#include "crfcal/noise_estimation.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"

namespace crfcal {
namespace {

// Immerkær's operator N ⊗ I (white noise of std σ → std σ, locally linear signal → 0) and the 7×7 local mean.
struct NoiseResponse {
  cv::Mat response, mean;
};

NoiseResponse noiseResponse(const cv::Mat& image) {
  const cv::Mat unit = toUnitGray(image);
  if (unit.rows < 9 || unit.cols < 9) throw InvalidInput("noise estimation: image smaller than 9x9");
  const cv::Mat mask = (cv::Mat_<double>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1) / 6.0;
  NoiseResponse r;
  cv::filter2D(unit, r.response, CV_64F, mask, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  cv::blur(unit, r.mean, cv::Size(7, 7), cv::Point(-1, -1), cv::BORDER_REFLECT);
  return r;
}

}  // namespace

void NoiseEstimationOptions::check() const {
  if (!(clip_margin >= 0 && clip_margin < 0.5)) throw InvalidInput("noise estimation: clip_margin must be in [0, 0.5)");
  if (min_samples < 1) throw InvalidInput("noise estimation: min_samples must be positive");
}

NoiseEstimate estimateNoiseSigma(const cv::Mat& image, const NoiseEstimationOptions& options) {
  options.check();
  const NoiseResponse nr = noiseResponse(image);
  std::vector<double> inside, all;
  for (int y = 1; y < nr.response.rows - 1; ++y) {
    const double* r = nr.response.ptr<double>(y);
    const double* m = nr.mean.ptr<double>(y);
    for (int x = 1; x < nr.response.cols - 1; ++x) {
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

NoiseEstimate estimateNoiseSigmaAtHalfResolution(const cv::Mat& image, const NoiseEstimationOptions& options) {
  const cv::Mat unit = toUnitGray(image);
  if (unit.rows < 18 || unit.cols < 18) throw InvalidInput("noise estimation: image smaller than 18x18");
  cv::Mat half;
  cv::resize(unit, half, cv::Size(unit.cols / 2, unit.rows / 2), 0, 0, cv::INTER_AREA);
  NoiseEstimate est = estimateNoiseSigma(half, options);
  est.sigma *= 2;
  return est;
}

NoiseProfile estimateNoiseProfile(const cv::Mat& image, int max_bins, const NoiseEstimationOptions& options) {
  options.check();
  if (max_bins < 1) throw InvalidInput("noise estimation: max_bins must be positive");
  const NoiseResponse nr = noiseResponse(image);
  std::vector<std::pair<double, double>> samples;  // (local mean, |response|)
  samples.reserve(nr.response.total());
  for (int y = 1; y < nr.response.rows - 1; ++y)
    for (int x = 1; x < nr.response.cols - 1; ++x)
      samples.emplace_back(nr.mean.at<double>(y, x), std::abs(nr.response.at<double>(y, x)));
  std::sort(samples.begin(), samples.end());
  const int bins = std::clamp(static_cast<int>(samples.size()) / options.min_samples, 1, max_bins);
  NoiseProfile profile;
  for (int b = 0; b < bins; ++b) {
    const std::size_t lo = samples.size() * b / bins, hi = samples.size() * (b + 1) / bins;
    std::vector<double> a;
    a.reserve(hi - lo);
    for (std::size_t i = lo; i < hi; ++i) a.push_back(samples[i].second);
    auto mid = a.begin() + static_cast<std::ptrdiff_t>(a.size() / 2);
    std::nth_element(a.begin(), mid, a.end());
    const double level = samples[(lo + hi) / 2].first;
    if (!profile.level.empty() && level <= profile.level.back()) continue;  // a flat run of equal means
    profile.level.push_back(level);
    profile.sigma.push_back(1.4826 * *mid);
  }
  return profile;
}

std::vector<double> noiseSigmaPerLevel(const std::vector<double>& level, const std::vector<double>& sigma, int levels) {
  if (level.empty() || level.size() != sigma.size()) throw InvalidInput("noise profile: levels and sigmas differ in size");
  std::vector<double> out(levels);
  for (int v = 0; v < levels; ++v) {
    const double x = static_cast<double>(v) / (levels - 1);
    if (x <= level.front()) out[v] = sigma.front();
    else if (x >= level.back()) out[v] = sigma.back();
    else {
      std::size_t j = 1;
      while (j + 1 < level.size() && level[j] < x) ++j;
      const double t = (x - level[j - 1]) / std::max(level[j] - level[j - 1], 1e-12);
      out[v] = sigma[j - 1] + t * (sigma[j] - sigma[j - 1]);
    }
    out[v] = std::clamp(out[v], 0.0, 0.5);
  }
  return out;
}

}  // namespace crfcal
