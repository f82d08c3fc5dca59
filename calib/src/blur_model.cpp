#include "crfcal/blur_model.hpp"

#include <cmath>
#include <cstdint>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal {
namespace {

// filter2D correlates; convolution = correlation with the flipped kernel, anchored so that the kernel's
// centre (cols/2, rows/2) stays the centre.
cv::Point flippedAnchor(const cv::Mat& kernel) {
  return {kernel.cols - 1 - kernel.cols / 2, kernel.rows - 1 - kernel.rows / 2};
}

void requireSameSize(const cv::Mat& a, const cv::Mat& b, const char* what) {
  if (a.size() != b.size()) throw InvalidInput(std::string(what) + ": images differ in size");
}

}  // namespace

cv::Mat toUnitGray(const cv::Mat& image) {
  if (image.empty()) throw InvalidInput("image is empty");
  cv::Mat gray = image;
  if (image.channels() == 3) cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  else if (image.channels() == 4) cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
  else if (image.channels() != 1) throw InvalidInput("image must have 1, 3 or 4 channels");
  double scale = 1.0;
  if (gray.depth() == CV_8U) scale = 1.0 / 255.0;
  else if (gray.depth() == CV_16U) scale = 1.0 / 65535.0;
  else if (gray.depth() != CV_32F && gray.depth() != CV_64F) throw InvalidInput("unsupported image depth");
  cv::Mat out;
  gray.convertTo(out, CV_64F, scale);
  return out;
}

cv::Mat convolve(const cv::Mat& image, const cv::Mat& kernel) {
  if (auto check = checkKernel(kernel, 1e-6); !check) throw InvalidInput("blur kernel: " + check.reason);
  cv::Mat source, k, flipped, out;
  image.convertTo(source, CV_64F);
  kernel.convertTo(k, CV_64F);
  cv::flip(k, flipped, -1);
  cv::filter2D(source, out, CV_64F, flipped, flippedAnchor(k), 0.0, cv::BORDER_REPLICATE);
  return out;
}

cv::Mat irradianceBlur(const cv::Mat& sharp, const ResponseCurve& curve, const cv::Mat& kernel, double ratio) {
  if (!(ratio > 0)) throw InvalidInput("exposure ratio must be positive");
  cv::Mat irradiance = convolve(curve.inverse(sharp), kernel) * ratio;
  cv::min(irradiance, 1.0, irradiance);  // sensor saturation
  return curve.forward(irradiance);
}

cv::Mat intensityBlur(const cv::Mat& sharp, const cv::Mat& kernel) { return convolve(sharp, kernel); }

cv::Mat blurInconsistency(const cv::Mat& blurred, const cv::Mat& intensity_blurred) {
  requireSameSize(blurred, intensity_blurred, "blur inconsistency");
  cv::Mat a, b;
  blurred.convertTo(a, CV_64F);
  intensity_blurred.convertTo(b, CV_64F);
  return a - b;
}

namespace {

// The integer codes of an image whose every value is q · (1 / (2^bits − 1)) with q an integer code, as toUnitGray
// makes them from 8- or 16-bit storage (empty when some value is not: then the image is taken as it is).
cv::Mat integerCodes(const cv::Mat& unit, int bits) {
  const double top = bits == 8 ? 255.0 : 65535.0, scale = 1.0 / top;
  cv::Mat codes(unit.size(), bits == 8 ? CV_8U : CV_16U);
  for (int y = 0; y < unit.rows; ++y) {
    const double* v = unit.ptr<double>(y);
    for (int x = 0; x < unit.cols; ++x) {
      const double q = std::round(v[x] * top);
      if (!(q >= 0 && q <= top) || q * scale != v[x]) return {};
      if (bits == 8) codes.at<std::uint8_t>(y, x) = static_cast<std::uint8_t>(q);
      else codes.at<std::uint16_t>(y, x) = static_cast<std::uint16_t>(q);
    }
  }
  return codes;
}

}  // namespace

LocalRange localRange(const cv::Mat& sharp, const cv::Mat& kernel) {
  cv::Mat source, k, support;
  sharp.convertTo(source, CV_64F);
  kernel.convertTo(k, CV_64F);
  cv::flip(kernelSupport(k), support, -1);
  LocalRange range;
  // Minimum and maximum commute with the increasing map q → q / (2^bits − 1): on an image of 8- or 16-bit codes they
  // are taken on the codes, where OpenCV's morphology is vectorised (the fitter pays this in every refit, with supports
  // up to 35 px), and the result is q · scale again: the same doubles to the bit.
  for (int bits : {8, 16}) {
    const cv::Mat codes = integerCodes(source, bits);
    if (codes.empty()) continue;
    const double scale = bits == 8 ? 1.0 / 255.0 : 1.0 / 65535.0;
    cv::Mat lo, hi;
    cv::erode(codes, lo, support, flippedAnchor(k), 1, cv::BORDER_REPLICATE);
    cv::dilate(codes, hi, support, flippedAnchor(k), 1, cv::BORDER_REPLICATE);
    // q · scale, the product integerCodes found equal to every pixel's value
    lo.convertTo(range.min, CV_64F);
    hi.convertTo(range.max, CV_64F);
    range.min *= scale;
    range.max *= scale;
    return range;
  }
  cv::erode(source, range.min, support, flippedAnchor(k), 1, cv::BORDER_REPLICATE);
  cv::dilate(source, range.max, support, flippedAnchor(k), 1, cv::BORDER_REPLICATE);
  return range;
}

cv::Mat quantize(const cv::Mat& image, int bits) {
  if (bits != 8 && bits != 16) throw InvalidInput("quantisation must be 8 or 16 bits");
  const double levels = bits == 8 ? 255.0 : 65535.0;
  cv::Mat out;
  image.convertTo(out, CV_64F);
  cv::max(cv::min(out, 1.0), 0.0, out);
  out.forEach<double>([levels](double& v, const int*) { v = std::round(v * levels) / levels; });
  return out;
}

cv::Mat addGaussianNoise(const cv::Mat& image, double variance, std::uint64_t seed) {
  if (variance < 0) throw InvalidInput("noise variance must be non-negative");
  cv::Mat out;
  image.convertTo(out, CV_64F);
  if (variance == 0) return out;
  cv::Mat noise(out.size(), CV_64F);
  cv::RNG rng(seed);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, std::sqrt(variance));
  out += noise;
  cv::max(cv::min(out, 1.0), 0.0, out);
  return out;
}

}  // namespace crfcal
