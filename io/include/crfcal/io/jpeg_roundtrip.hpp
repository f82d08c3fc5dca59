#pragma once
// An image through a camera-like JPEG in memory: encoded with 4:2:0 chroma (libjpeg through OpenCV, as camera
// JPEGs mostly are) and decoded again. For benches that must see what a camera's JPEG does to a pair without
// writing files.
#include <opencv2/core.hpp>

namespace crfcal::io {

// `image`: 8-bit grey or BGR; quality 1–100. Returns the decoded 8-bit image of the same size and channels.
// Throws crfcal::Error when the codec fails.
cv::Mat jpegRoundTrip(const cv::Mat& image, int quality);

}  // namespace crfcal::io
