#pragma once
// An image compressed to JPEG and decoded again in memory (OpenCV's codec, libjpeg 4:2:0 chroma): the in-camera
// JPEG step of the semi-real brackets and pairs of the benches.
#include <opencv2/core.hpp>

namespace crfcal::io {

// `image`: 8-bit grey or BGR; quality 1–100. Throws crfcal::Error when encoding fails.
cv::Mat jpegRoundTrip(const cv::Mat& image, int quality);

}  // namespace crfcal::io
