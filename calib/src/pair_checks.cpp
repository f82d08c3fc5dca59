#include "crfcal/pair_checks.hpp"

#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"

namespace crfcal {

void PairCheckOptions::check() const {
  if (!(black_level >= 0 && black_level < 1)) throw InvalidInput("pair check: black_level must be in [0,1)");
  if (!(black_pixel_fraction >= 0 && black_pixel_fraction < 1))
    throw InvalidInput("pair check: black_pixel_fraction must be in [0,1)");
  if (!(uniform_stddev >= 0 && uniform_stddev < 1)) throw InvalidInput("pair check: uniform_stddev must be in [0,1)");
}

void requireDistinctImages(const cv::Mat& a, const cv::Mat& b) {
  if (a.empty() || b.empty() || a.size() != b.size() || a.type() != b.type()) return;
  if (cv::norm(a, b, cv::NORM_INF) == 0)
    throw InvalidInput("the two images are identical (the same shot twice; a pair needs a short and a long exposure)");
}

void requireUsableExposure(const cv::Mat& image, const std::string& which, double white, double black,
                           const PairCheckOptions& options) {
  options.check();
  if (image.empty()) throw InvalidInput("the " + which + " image is empty");
  if (image.depth() != CV_8U && image.depth() != CV_16U)
    throw InvalidInput("the " + which + " image is not 8 or 16 bit");
  if (white <= 0) white = image.depth() == CV_8U ? 255.0 : 65535.0;
  if (!(black >= 0 && black < white)) black = 0;
  // The brightest channel of each pixel: a pixel lit in any channel is not black.
  cv::Mat brightest = image.reshape(1, static_cast<int>(image.total()));
  cv::reduce(brightest, brightest, 1, cv::REDUCE_MAX);
  const double level = black + options.black_level * (white - black);
  const double lit = cv::countNonZero(brightest > level);
  if (lit <= options.black_pixel_fraction * static_cast<double>(image.total())) {
    char text[200];
    std::snprintf(text, sizeof text, "the %s image is black (%.1f %% of pixels <= %.0f of %.0f)", which.c_str(),
                  100.0 * (1.0 - lit / static_cast<double>(image.total())), std::floor(level), white);
    throw InvalidInput(text);
  }
  cv::Scalar mean, stddev;
  cv::meanStdDev(image.reshape(1), mean, stddev);
  if (stddev[0] < options.uniform_stddev * (white - black)) {
    char text[200];
    if (mean[0] >= black + (1 - options.black_level) * (white - black)) {
      std::snprintf(text, sizeof text, "the %s image is saturated (uniform at %.0f of %.0f): no edges to use",
                    which.c_str(), mean[0], white);
      throw InvalidInput(text);
    }
    std::snprintf(text, sizeof text, "the %s image is uniform (standard deviation %.3g of %.0f): no edges to use",
                  which.c_str(), stddev[0], white);
    throw InvalidInput(text);
  }
}

}  // namespace crfcal
