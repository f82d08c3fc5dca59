#include "crfcal/noise_model.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal {

double PoissonGaussianNoise::variance(double x) const { return std::max(a * x + b, 0.0); }

double intensityNoiseSigma(const ResponseCurve& curve, const PoissonGaussianNoise& noise, double v) {
  const double h = 1.0 / 1024;
  const double lo = std::max(0.0, v - h), hi = std::min(1.0, v + h);
  const double slope = (curve.inverse(hi) - curve.inverse(lo)) / (hi - lo);  // φ'(v)
  const double x = curve.inverse(v);
  if (!(slope > 1e-12)) return 0.0;
  return std::sqrt(noise.variance(x)) / slope;
}

cv::Mat addPoissonGaussianNoise(const cv::Mat& irradiance, const PoissonGaussianNoise& noise, std::uint64_t seed) {
  CV_Assert(irradiance.type() == CV_64FC1);
  cv::Mat out(irradiance.size(), CV_64F);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int y = 0; y < irradiance.rows; ++y) {
    const double* in = irradiance.ptr<double>(y);
    double* o = out.ptr<double>(y);
    for (int x = 0; x < irradiance.cols; ++x)
      o[x] = std::clamp(in[x] + std::sqrt(noise.variance(in[x])) * normal(rng), 0.0, 1.0);
  }
  return out;
}

void RealisticSimulationOptions::check() const {
  if (!(ratio > 0)) throw InvalidInput("exposure ratio must be positive");
  if (bits != 8 && bits != 16) throw InvalidInput("bits must be 8 or 16");
  for (const auto* n : {&sharp_noise, &blurred_noise})
    if (!std::isfinite(n->a) || !std::isfinite(n->b) || n->a < 0) throw InvalidInput("noise: a must be >= 0, finite");
}

SimulationResult simulatePairPoissonGaussian(const cv::Mat& image, const ResponseModel& model, const cv::Mat& kernel,
                                             const RealisticSimulationOptions& options) {
  options.check();
  const cv::Mat k = normalizeKernel(kernel);
  const ResponseCurve curve(model);
  SimulationResult result;
  result.irradiance = toUnitGray(image);
  result.sharp_clean = curve.forward(result.irradiance);
  cv::Mat blurred_irradiance = convolve(result.irradiance, k) * options.ratio;
  result.clipped_pixels = cv::countNonZero(blurred_irradiance > 1.0);
  cv::min(blurred_irradiance, 1.0, blurred_irradiance);
  const cv::Mat noisy_b = addPoissonGaussianNoise(blurred_irradiance, options.blurred_noise, options.seed * 2 + 1);
  result.blurred = quantize(curve.forward(noisy_b), options.bits);
  result.intensity_blurred = intensityBlur(result.sharp_clean, k);
  const cv::Mat noisy_i = addPoissonGaussianNoise(result.irradiance, options.sharp_noise, options.seed * 2);
  result.sharp = quantize(curve.forward(noisy_i), options.bits);
  return result;
}

void NoiseLevelOptions::check() const {
  if (bins < 1) throw InvalidInput("noise levels: bins must be positive");
  if (!(low >= 0 && high <= 1 && low < high)) throw InvalidInput("noise levels: need 0 <= low < high <= 1");
  if (min_samples < 10) throw InvalidInput("noise levels: min_samples must be >= 10");
  if (!(flat_quantile > 0 && flat_quantile <= 1)) throw InvalidInput("noise levels: flat_quantile in (0, 1]");
}

std::vector<NoiseLevelBin> measureNoiseLevels(const cv::Mat& image, const NoiseLevelOptions& options) {
  options.check();
  const cv::Mat unit = toUnitGray(image);
  if (unit.rows < 9 || unit.cols < 9) throw InvalidInput("noise levels: image smaller than 9x9");
  const cv::Mat op = (cv::Mat_<double>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1) / 6.0;
  cv::Mat residual, mean, gx, gy, smooth;
  cv::filter2D(unit, residual, CV_64F, op, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  cv::blur(unit, mean, cv::Size(5, 5), cv::Point(-1, -1), cv::BORDER_REFLECT);
  cv::GaussianBlur(unit, smooth, cv::Size(5, 5), 1.5, 1.5, cv::BORDER_REFLECT);
  cv::Sobel(smooth, gx, CV_64F, 1, 0, 3);
  cv::Sobel(smooth, gy, CV_64F, 0, 1, 3);
  struct Item {
    double grad, res, mean;
  };
  std::vector<std::vector<Item>> bins(static_cast<size_t>(options.bins));
  const double width = (options.high - options.low) / options.bins;
  for (int y = 3; y < unit.rows - 3; ++y) {
    for (int x = 3; x < unit.cols - 3; ++x) {
      const double m = mean.at<double>(y, x);
      if (m < options.low || m >= options.high) continue;
      const int b = std::min(options.bins - 1, static_cast<int>((m - options.low) / width));
      const double g = std::hypot(gx.at<double>(y, x), gy.at<double>(y, x));
      bins[static_cast<size_t>(b)].push_back({g, residual.at<double>(y, x), m});
    }
  }
  std::vector<NoiseLevelBin> out;
  for (auto& items : bins) {
    if (static_cast<int>(items.size()) < options.min_samples) continue;
    std::sort(items.begin(), items.end(), [](const Item& p, const Item& q) { return p.grad < q.grad; });
    const size_t keep = std::max<size_t>(static_cast<size_t>(options.min_samples) / 2,
                                         static_cast<size_t>(options.flat_quantile * double(items.size())));
    items.resize(std::min(keep, items.size()));
    std::vector<double> a;
    double msum = 0;
    for (const auto& it : items) {
      a.push_back(std::abs(it.res));
      msum += it.mean;
    }
    std::nth_element(a.begin(), a.begin() + static_cast<std::ptrdiff_t>(a.size() / 2), a.end());
    NoiseLevelBin bin;
    bin.sigma = 1.4826 * a[a.size() / 2];
    bin.intensity = msum / double(items.size());
    bin.samples = static_cast<int>(items.size());
    out.push_back(bin);
  }
  return out;
}

PoissonGaussianNoise fitPoissonGaussian(const std::vector<double>& x, const std::vector<double>& sigma,
                                        const std::vector<double>& weights) {
  if (x.size() != sigma.size() || x.size() < 2) throw InvalidInput("noise fit: need >= 2 (x, sigma) pairs");
  const auto n = static_cast<Eigen::Index>(x.size());
  Eigen::MatrixXd A(n, 2);
  Eigen::VectorXd y(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    // relative weighting: each variance error counts relative to the variance itself
    const double v = sigma[static_cast<size_t>(i)] * sigma[static_cast<size_t>(i)];
    double w = weights.empty() ? 1.0 : weights[static_cast<size_t>(i)];
    w /= std::max(v, 1e-12);
    A(i, 0) = w * x[static_cast<size_t>(i)];
    A(i, 1) = w;
    y(i) = w * v;
  }
  const Eigen::Vector2d p = A.colPivHouseholderQr().solve(y);
  return {p(0), p(1)};
}

PoissonGaussianNoise fitPoissonGaussianThroughCurve(const std::vector<NoiseLevelBin>& bins, const ResponseCurve& curve) {
  std::vector<double> x, s, w;
  const double h = 1.0 / 512;
  for (const auto& b : bins) {
    const double lo = std::max(0.0, b.intensity - h), hi = std::min(1.0, b.intensity + h);
    const double slope = (curve.inverse(hi) - curve.inverse(lo)) / (hi - lo);
    x.push_back(curve.inverse(b.intensity));
    s.push_back(b.sigma * slope);
    w.push_back(1.0);
  }
  return fitPoissonGaussian(x, s, w);
}

double logSigmaMisfit(const std::vector<NoiseLevelBin>& bins, const std::vector<double>& model_sigma) {
  if (bins.size() != model_sigma.size() || bins.empty()) throw InvalidInput("noise misfit: size mismatch");
  double sum = 0;
  for (size_t i = 0; i < bins.size(); ++i) {
    const double r = std::log(std::max(model_sigma[i], 1e-9) / std::max(bins[i].sigma, 1e-9));
    sum += r * r;
  }
  return std::sqrt(sum / double(bins.size()));
}

}  // namespace crfcal
