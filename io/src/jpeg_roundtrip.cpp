#include "crfcal/io/jpeg_roundtrip.hpp"

#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "crfcal/error.hpp"

namespace crfcal::io {

cv::Mat jpegRoundTrip(const cv::Mat& image, int quality) {
  if (image.empty() || image.depth() != CV_8U) throw Error("JPEG round trip: needs a non-empty 8-bit image");
  if (quality < 1 || quality > 100) throw Error("JPEG round trip: quality must be 1–100, got " + std::to_string(quality));
  std::vector<uchar> bytes;
  // OpenCV 4.6 (Debian 12) has no sampling-factor parameter; its libjpeg encoder writes colour as 4:2:0
  // (io/jpeg_info.hpp reads it back that way: tests/test_jpeg_info.cpp).
  const std::vector<int> params{cv::IMWRITE_JPEG_QUALITY, quality};
  if (!cv::imencode(".jpg", image, bytes, params)) throw Error("JPEG round trip: the encoder failed");
  cv::Mat decoded = cv::imdecode(bytes, image.channels() == 1 ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR);
  if (decoded.empty()) throw Error("JPEG round trip: the decoder failed");
  return decoded;
}

}  // namespace crfcal::io
