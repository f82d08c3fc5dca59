// calibrate's pictures (io/figures): scales a person can read.
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "crfcal/io/figures.hpp"
#include "crfcal/io/image_io.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

int strongRedPixels(const cv::Mat& bgr) {
  int n = 0;
  for (auto it = bgr.begin<cv::Vec3b>(); it != bgr.end<cv::Vec3b>(); ++it)
    if ((*it)[2] > 90 && (*it)[1] < 40 && (*it)[0] < 60) ++n;  // the dark red end of the colour map
  return n;
}

// One outlier 10⁴ times the rest must not wash the map out: the scale is the 99th percentile of |Γ|, so the
// typical pixels are saturated red, not white (they were white with a max-|Γ| scale).
TEST(Figures, SignedMapScaleIgnoresOutliers) {
  test::TempDir dir;
  cv::Mat map(100, 100, CV_64F, cv::Scalar(0.01));
  map.at<double>(50, 50) = 100;
  io::writeSignedMapFigure(dir / "gamma.png", map, {"title", {}}, {"Gamma"});
  const cv::Mat picture = io::readImage(dir / "gamma.png");
  EXPECT_GT(strongRedPixels(picture), 100 * 100 * 16);  // the map is shown at least 4x enlarged (≥ 480 px)
}

// The kernel picture is enlarged to a readable size (≥ 280 px of kernel), not written 1:1.
TEST(Figures, KernelPictureIsEnlarged) {
  test::TempDir dir;
  cv::Mat kernel(35, 35, CV_64F, cv::Scalar(0));
  kernel.at<double>(17, 17) = 1;
  io::writeKernelFigure(dir / "kernel.png", kernel, {"kernel", {}});
  const cv::Mat picture = io::readImage(dir / "kernel.png");
  EXPECT_GE(picture.cols, 280 + 35);
  EXPECT_GE(picture.rows, 280 + 35);
}

}  // namespace
}  // namespace crfcal
