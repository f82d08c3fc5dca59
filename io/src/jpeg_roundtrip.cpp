#include "crfcal/io/jpeg_roundtrip.hpp"

#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "crfcal/error.hpp"

namespace crfcal::io {

cv::Mat jpegRoundTrip(const cv::Mat& image, int quality) {
  if (image.depth() != CV_8U || quality < 1 || quality > 100)
    throw Error("JPEG round trip: an 8-bit image and a quality in 1..100 are needed");
  std::vector<uchar> bytes;
  if (!cv::imencode(".jpg", image, bytes, {cv::IMWRITE_JPEG_QUALITY, quality})) throw Error("JPEG encoding failed");
  return cv::imdecode(bytes, image.channels() == 1 ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR);
}

}  // namespace crfcal::io
