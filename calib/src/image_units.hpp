#pragma once
// Internal helpers shared by the calibration's sources (not installed): pixel values in units of full scale and a
// mask's dilation. One home, so that every stage converts codes to [0,1] the same way.
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace crfcal::detail {

// The code of full scale of an image's storage: 255 (8-bit), 65535 (16-bit); floating-point images are already in
// units of full scale (1).
inline double fullScale(const cv::Mat& image) {
  return image.depth() == CV_16U ? 65535.0 : image.depth() == CV_8U ? 255.0 : 1.0;
}

// CV_64F copy in units of full scale ([0,1] for 8/16-bit input).
inline cv::Mat unit(const cv::Mat& image) {
  cv::Mat out;
  image.convertTo(out, CV_64F, 1.0 / fullScale(image));
  return out;
}

// `mask` dilated by an n×n square (a clipped pixel spoils every equation whose window reaches it).
inline cv::Mat dilateBy(const cv::Mat& mask, int n) {
  cv::Mat out;
  cv::dilate(mask, out, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(n, n)));
  return out;
}

}  // namespace crfcal::detail
