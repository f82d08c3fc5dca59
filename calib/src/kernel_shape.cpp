// The shape of a blur kernel (kernel_shape.hpp).
#include "crfcal/kernel_shape.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal {

void KernelShapeOptions::check() const {
  if (!(support_fraction > 0 && support_fraction < 1))
    throw InvalidInput("kernel support fraction must be in (0, 1)", ErrorSubject::options);
  if (!(min_component_mass > 0 && min_component_mass < 1))
    throw InvalidInput("kernel component mass must be in (0, 1)", ErrorSubject::options);
}

KernelShape describeKernelShape(const cv::Mat& kernel, const KernelShapeOptions& options) {
  options.check();
  if (kernel.empty() || kernel.channels() != 1) throw InvalidInput("kernel must be a single-channel matrix", ErrorSubject::kernel);
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  double lo = 0, hi = 0;
  cv::minMaxLoc(k, &lo, &hi);
  const double total = cv::sum(k)[0];
  if (lo < 0 || !(hi > 0) || !(total > 0)) throw InvalidInput("kernel must be non-negative and not all zero", ErrorSubject::kernel);
  KernelShape shape;
  const cv::Mat support = k > options.support_fraction * hi;
  shape.support = cv::countNonZero(support);
  cv::Mat labels;
  const int n = cv::connectedComponents(support, labels, 8, CV_32S);
  std::vector<double> mass(static_cast<std::size_t>(n), 0.0);
  for (int y = 0; y < k.rows; ++y)
    for (int x = 0; x < k.cols; ++x) mass[static_cast<std::size_t>(labels.at<int>(y, x))] += k.at<double>(y, x);
  for (int c = 1; c < n; ++c) {
    const double share = mass[static_cast<std::size_t>(c)] / total;
    shape.largest_mass = std::max(shape.largest_mass, share);
    if (share >= options.min_component_mass) ++shape.components;
  }
  shape.rms_radius = kernelRmsRadius(k);
  // Second moments about the centroid.
  double cx = 0, cy = 0;
  for (int y = 0; y < k.rows; ++y)
    for (int x = 0; x < k.cols; ++x) {
      cx += x * k.at<double>(y, x) / total;
      cy += y * k.at<double>(y, x) / total;
    }
  double sxx = 0, syy = 0, sxy = 0;
  for (int y = 0; y < k.rows; ++y)
    for (int x = 0; x < k.cols; ++x) {
      const double w = k.at<double>(y, x) / total;
      sxx += w * (x - cx) * (x - cx);
      syy += w * (y - cy) * (y - cy);
      sxy += w * (x - cx) * (y - cy);
    }
  const double mean = 0.5 * (sxx + syy), dev = std::sqrt(0.25 * (sxx - syy) * (sxx - syy) + sxy * sxy);
  const double lmax = mean + dev, lmin = std::max(mean - dev, 1e-12);
  shape.elongation = std::sqrt(lmax / lmin);
  return shape;
}

}  // namespace crfcal
