// Registration of a handheld pair: homography recovery under exposure/tone change and blur; non-overlap.
#include <cmath>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/registration.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A handheld-like motion: rotation about the centre + shift.
cv::Mat handheld(cv::Size size, double degrees, cv::Point2d shift) {
  cv::Mat A = cv::getRotationMatrix2D(cv::Point2f(size.width / 2.0f, size.height / 2.0f), degrees, 1.0);
  A.at<double>(0, 2) += shift.x;
  A.at<double>(1, 2) += shift.y;
  cv::Mat H = cv::Mat::eye(3, 3, CV_64F);
  A.copyTo(H.rowRange(0, 2));
  return H;
}

double cornerError(const cv::Mat& H, const cv::Mat& truth, cv::Size size) {
  std::vector<cv::Point2d> corners{{0, 0}, {size.width - 1.0, 0}, {0, size.height - 1.0},
                                   {size.width - 1.0, size.height - 1.0}};
  std::vector<cv::Point2d> a, b;
  cv::perspectiveTransform(corners, a, H);
  cv::perspectiveTransform(corners, b, truth);
  double worst = 0;
  for (size_t i = 0; i < a.size(); ++i) worst = std::max(worst, cv::norm(a[i] - b[i]));
  return worst;
}

cv::Mat mosaic() {
  // 510x510 from the four Levin images: enough texture for features.
  cv::Mat top, bottom, out;
  cv::hconcat(test::levinImage(1), test::levinImage(2), top);
  cv::hconcat(test::levinImage(3), test::levinImage(4), bottom);
  cv::vconcat(top, bottom, out);
  return out;
}

TEST(Registration, RecoversHandheldMotionDespiteToneAndBlur) {
  const cv::Mat sharp = mosaic();
  const cv::Mat truth = handheld(sharp.size(), 1.2, {6.4, -4.3});
  cv::Mat blurred = warpToBlurred(sharp, truth, sharp.size());
  blurred = convolve(blurred, test::levinKernel(2));
  cv::pow(blurred, 0.6, blurred);  // a different exposure/tone curve
  const RegistrationResult r = registerPair(sharp, blurred);
  EXPECT_LT(cornerError(r.homography, truth, sharp.size()), 1.5) << r.summary();
  EXPECT_GT(r.overlap_fraction, 0.9);
  EXPECT_GT(r.ecc_correlation, 0.8);
  EXPECT_NEAR(r.rotationDegrees(), 1.2, 0.2);
}

TEST(Registration, DifferentScenesDoNotOverlap) {
  const cv::Mat a = test::levinImage(1), b = test::levinImage(3);
  try {
    registerPair(a, b);
    FAIL() << "expected InvalidInput";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("does not overlap"), std::string::npos) << e.what();
  }
}

TEST(Registration, OptionsAreChecked) {
  RegistrationOptions o;
  o.ecc_smoothing = 4;
  EXPECT_THROW(o.check(), InvalidInput);
}

}  // namespace
}  // namespace crfcal
