#include "crfcal/kernel.hpp"

#include <cmath>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"

namespace crfcal {

KernelCheck checkKernel(const cv::Mat& kernel, double tolerance) {
  if (kernel.empty()) return {false, "kernel is empty"};
  if (kernel.channels() != 1) return {false, "kernel must have one channel"};
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  if (!cv::checkRange(k)) return {false, "kernel has non-finite entries"};
  double lo = 0, hi = 0;
  cv::minMaxLoc(k, &lo, &hi);
  if (lo < -tolerance) return {false, "kernel has negative entries"};
  const double sum = cv::sum(k)[0];
  if (std::abs(sum - 1.0) > tolerance) return {false, "kernel sums to " + std::to_string(sum) + ", not 1"};
  return {};
}

cv::Mat normalizeKernel(const cv::Mat& kernel) {
  if (kernel.empty()) throw InvalidInput("kernel is empty");
  if (kernel.channels() != 1) throw InvalidInput("kernel must have one channel");
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  if (!cv::checkRange(k)) throw InvalidInput("kernel has non-finite entries");
  double lo = 0, hi = 0;
  cv::minMaxLoc(k, &lo, &hi);
  if (hi <= 0) throw InvalidInput("kernel has no positive entry");
  if (lo < -1e-6 * hi) throw InvalidInput("kernel has negative entries");
  k.setTo(0.0, k < 0);
  return k / cv::sum(k)[0];
}

cv::Mat boxKernel(int length) {
  if (length < 1) throw InvalidInput("box kernel length must be positive");
  return cv::Mat(1, length, CV_64F, cv::Scalar(1.0 / length));
}

cv::Mat cropKernel(const cv::Mat& kernel, double threshold) {
  const cv::Mat k = normalizeKernel(kernel);
  double hi = 0;
  cv::minMaxLoc(k, nullptr, &hi);
  const cv::Mat mask = k > threshold * hi;
  const cv::Rect box = cv::boundingRect(mask);
  const int cx = k.cols / 2, cy = k.rows / 2;
  // keep the centre: trim the same amount from both sides
  const int half_w = std::max(cx - box.x, box.x + box.width - 1 - cx);
  const int half_h = std::max(cy - box.y, box.y + box.height - 1 - cy);
  const int x0 = std::max(0, cx - half_w), y0 = std::max(0, cy - half_h);
  const int x1 = std::min(k.cols - 1, cx + half_w), y1 = std::min(k.rows - 1, cy + half_h);
  cv::Mat cropped = k(cv::Rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1)).clone();
  cropped.setTo(0.0, cropped <= threshold * hi);
  return normalizeKernel(cropped);
}

cv::Mat kernelSupport(const cv::Mat& kernel) {
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  return k > 0;
}

cv::Point2d kernelCentroid(const cv::Mat& kernel) {
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  const cv::Moments m = cv::moments(k);
  if (!(m.m00 > 0)) return {0, 0};
  return {m.m10 / m.m00 - k.cols / 2, m.m01 / m.m00 - k.rows / 2};
}

double kernelRmsRadius(const cv::Mat& kernel) {
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  const cv::Moments m = cv::moments(k);
  if (!(m.m00 > 0)) return 0;
  return std::sqrt(std::max(0.0, (m.mu20 + m.mu02) / m.m00));  // central second moments
}

}  // namespace crfcal
