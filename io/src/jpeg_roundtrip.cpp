#include "crfcal/io/jpeg_roundtrip.hpp"

#include <string>
#include <vector>


#include "crfcal/error.hpp"
#include "crfcal/io/image_codecs.hpp"

namespace crfcal::io {

cv::Mat jpegRoundTrip(const cv::Mat& image, int quality) {
  if (image.empty() || image.depth() != CV_8U) throw Error("JPEG round trip: needs a non-empty 8-bit image");
  if (quality < 1 || quality > 100) throw Error("JPEG round trip: quality must be 1–100, got " + std::to_string(quality));
  // libjpeg's defaults write colour as 4:2:0, as OpenCV 4.6's imencode did (the same bytes:
  // tests/test_image_codecs.cpp; io/jpeg_info.hpp reads the sampling back: tests/test_jpeg_info.cpp).
  const std::vector<unsigned char> bytes = encodeJpeg(image, quality, "JPEG round trip");
  return decodeImage(bytes, image.channels() == 1 ? ImageReadMode::grey : ImageReadMode::color, "JPEG round trip");
}

}  // namespace crfcal::io
