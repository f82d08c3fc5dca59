#include "crfcal/image_quality.hpp"

#include <cmath>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"

namespace crfcal {
namespace {

void checkSameShape(const cv::Mat& estimate, const cv::Mat& reference, const char* what) {
  if (estimate.empty() || estimate.size() != reference.size() || estimate.channels() != reference.channels())
    throw InvalidInput(std::string(what) + " needs two non-empty images of the same size and channels");
}

cv::Mat inside(const cv::Mat& image, int border, const char* what, int smallest) {
  const cv::Rect rect(border, border, image.cols - 2 * border, image.rows - 2 * border);
  if (border < 0 || rect.width < smallest || rect.height < smallest)
    throw InvalidInput(std::string(what) + ": the border leaves too few pixels");
  cv::Mat converted;
  image(rect).convertTo(converted, CV_MAKETYPE(CV_64F, image.channels()));
  return converted;
}

// The Gaussian window of Wang et al. 2004: 11×11, σ = 1.5 (only windows fully inside the image are averaged).
cv::Mat localMean(const cv::Mat& image) {
  cv::Mat mean;
  cv::GaussianBlur(image, mean, cv::Size(11, 11), 1.5, 1.5, cv::BORDER_REFLECT);
  return mean;
}

}  // namespace

double ssim(const cv::Mat& estimate, const cv::Mat& reference, int border) {
  checkSameShape(estimate, reference, "SSIM");
  const cv::Mat x = inside(estimate, border, "SSIM", 11), y = inside(reference, border, "SSIM", 11);
  // (K1 L)², (K2 L)² with L = 1; Scalar::all, since a plain double would only reach a Mat's first channel
  const cv::Scalar c1 = cv::Scalar::all(0.01 * 0.01), c2 = cv::Scalar::all(0.03 * 0.03);
  const cv::Mat mx = localMean(x), my = localMean(y);
  const cv::Mat sxx = localMean(x.mul(x)) - mx.mul(mx);
  const cv::Mat syy = localMean(y.mul(y)) - my.mul(my);
  const cv::Mat sxy = localMean(x.mul(y)) - mx.mul(my);
  cv::Mat numerator = (2 * mx.mul(my) + c1).mul(2 * sxy + c2);
  cv::Mat denominator = (mx.mul(mx) + my.mul(my) + c1).mul(sxx + syy + c2);
  cv::Mat map;
  cv::divide(numerator, denominator, map);
  const cv::Rect valid(5, 5, map.cols - 10, map.rows - 10);  // windows that lie inside the compared region
  const cv::Scalar means = cv::mean(map(valid));
  double sum = 0;
  for (int c = 0; c < map.channels(); ++c) sum += means[c];
  return sum / map.channels();
}

void EdgeBandOptions::check() const {
  if (!(contrast > 0 && contrast <= 1)) throw InvalidInput("edge-band contrast must lie in (0, 1]");
  if (band < 0 || border < 0) throw InvalidInput("edge band and border must be >= 0");
}

EdgeBandError edgeBandError(const cv::Mat& estimate, const cv::Mat& reference, const EdgeBandOptions& options) {
  options.check();
  checkSameShape(estimate, reference, "edge-band error");
  const cv::Mat x = inside(estimate, options.border, "edge-band error", 3);
  const cv::Mat y = inside(reference, options.border, "edge-band error", 3);
  std::vector<cv::Mat> xs, ys;
  cv::split(x, xs);
  cv::split(y, ys);
  const cv::Mat square3 = cv::getStructuringElement(cv::MORPH_RECT, {3, 3});
  const cv::Mat band = cv::getStructuringElement(cv::MORPH_RECT, {2 * options.band + 1, 2 * options.band + 1});
  double squared = 0;
  EdgeBandError result;
  for (size_t c = 0; c < xs.size(); ++c) {
    cv::Mat high, low, near;
    cv::dilate(ys[c], high, square3, {-1, -1}, 1, cv::BORDER_REPLICATE);
    cv::erode(ys[c], low, square3, {-1, -1}, 1, cv::BORDER_REPLICATE);
    cv::dilate(cv::Mat(high - low >= options.contrast), near, band);
    const cv::Mat error = xs[c] - ys[c];
    squared += cv::norm(error, cv::NORM_L2SQR, near);
    result.pixels += cv::countNonZero(near);
  }
  if (result.pixels > 0) result.rmse = std::sqrt(squared / static_cast<double>(result.pixels));
  return result;
}

}  // namespace crfcal
