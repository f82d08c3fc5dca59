#include "crfcal/reference_comparison.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include "crfcal/error.hpp"
#include "crfcal/image_quality.hpp"

namespace crfcal {
namespace {

std::vector<double> maskedValues(const cv::Mat& plane, const cv::Mat& mask) {
  std::vector<double> values;
  for (int y = 0; y < plane.rows; ++y) {
    const double* p = plane.ptr<double>(y);
    const unsigned char* m = mask.ptr<unsigned char>(y);
    for (int x = 0; x < plane.cols; ++x)
      if (m[x]) values.push_back(p[x]);
  }
  std::sort(values.begin(), values.end());
  return values;
}

void checkPair(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  if (a.size() != b.size() || a.type() != b.type() || a.depth() != CV_64F || mask.size() != a.size() ||
      mask.type() != CV_8U)
    throw InvalidInput("reference comparison needs CV_64F images of one size and type and a CV_8U mask");
  if (cv::countNonZero(mask) < 64) throw InvalidInput("reference comparison: fewer than 64 common pixels");
}

}  // namespace

cv::Mat matchBrightness(const cv::Mat& reference, const cv::Mat& target, const cv::Mat& mask) {
  checkPair(reference, target, mask);
  std::vector<cv::Mat> ref_planes, target_planes;
  cv::split(reference, ref_planes);
  cv::split(target, target_planes);
  const int quantiles = 256;
  for (size_t c = 0; c < ref_planes.size(); ++c) {
    const std::vector<double> from = maskedValues(ref_planes[c], mask), to = maskedValues(target_planes[c], mask);
    std::vector<double> knots_from(quantiles + 1), knots_to(quantiles + 1);
    for (int q = 0; q <= quantiles; ++q) {
      const double at = static_cast<double>(q) / quantiles;
      knots_from[q] = from[static_cast<size_t>(at * (from.size() - 1))];
      knots_to[q] = to[static_cast<size_t>(at * (to.size() - 1))];
    }
    ref_planes[c].forEach<double>([&](double& v, const int*) {
      const auto upper = std::upper_bound(knots_from.begin(), knots_from.end(), v);
      if (upper == knots_from.begin()) { v = knots_to.front(); return; }
      if (upper == knots_from.end()) { v = knots_to.back(); return; }
      const size_t i = static_cast<size_t>(upper - knots_from.begin());
      const double span = knots_from[i] - knots_from[i - 1];
      const double t = span > 0 ? (v - knots_from[i - 1]) / span : 0.5;
      v = knots_to[i - 1] + t * (knots_to[i] - knots_to[i - 1]);
    });
  }
  cv::Mat matched;
  cv::merge(ref_planes, matched);
  return matched;
}

ReferenceScore scoreAgainstReference(const cv::Mat& estimate, const cv::Mat& reference, const cv::Mat& mask) {
  checkPair(estimate, reference, mask);
  cv::Mat clamped = cv::min(cv::max(estimate, 0.0), 1.0);
  cv::Mat difference = clamped - reference;
  difference = difference.mul(difference);
  const double sum = cv::sum(cv::mean(difference, mask))[0] / estimate.channels();
  ReferenceScore score;
  score.psnr = 10 * std::log10(1.0 / std::max(sum, 1e-20));
  cv::Mat filled = reference.clone();
  clamped.copyTo(filled, ~mask);
  score.ssim = ssim(clamped, filled);
  return score;
}

}  // namespace crfcal
