#pragma once
// Checks on a sharp/blurred pair that need only the two images, run before any registration or fitting: a pair
// that cannot be calibrated is refused with the real reason instead of failing later with a misleading one (the
// same photo twice was "swapped" on a tied sharpness score and fitted; a black sharp shot became "the pair does not
// overlap").
#include <string>

#include <opencv2/core.hpp>

namespace crfcal {

struct PairCheckOptions {
  // An image is black when fewer than `black_pixel_fraction` of its pixels exceed `black_level` (a fraction of the
  // full scale `white`): 2/255 allows a JPEG's dark-frame noise; the pixel fraction ignores a few hot pixels.
  double black_level = 2.0 / 255.0;
  double black_pixel_fraction = 1e-3;
  // An image is uniform (nothing to register or to fit, Sec. 4 needs edges) when its standard deviation is below
  // this fraction of the full scale.
  double uniform_stddev = 1.0 / 1000.0;
  void check() const;  // throws InvalidInput
};

// Throws InvalidInput("the two images are identical") when `a` and `b` have the same size, type and pixels: the
// same file given twice, or two copies of one shot (a pair needs two exposures).
void requireDistinctImages(const cv::Mat& a, const cv::Mat& b);

// Throws InvalidInput("the <which> image is black (…)" or "… is uniform (…)") for an 8/16-bit grey or colour image.
// `white` is the full-scale value (0: 255 or 65535 from the depth; a RAW's white level otherwise), `black` the value
// of no light (a RAW's black level, else 0).
void requireUsableExposure(const cv::Mat& image, const std::string& which, double white = 0, double black = 0,
                           const PairCheckOptions& options = {});

}  // namespace crfcal
