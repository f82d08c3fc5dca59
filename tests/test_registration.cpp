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

// An asymmetric handheld kernel drags a plain sharp-vs-blurred alignment towards its centroid; ECC of I ⊗ K
// against B (equally blurred) removes that bias, and the default Euclidean model has no spurious scale or shear.
TEST(Registration, KernelAwareRefinementRecoversTheTrueMotion) {
  const cv::Mat sharp = mosaic();
  const cv::Mat K = test::levinKernel(8);  // centroid ≈ (1.2, −2.1) px
  const cv::Mat truth = handheld(sharp.size(), -0.4, {3.1, 2.2});
  cv::Mat blurred = warpToBlurred(convolve(sharp, K), truth, sharp.size());  // blur, then the frame moves
  cv::pow(blurred, 0.7, blurred);
  const RegistrationResult coarse = registerPair(sharp, blurred);
  const double det = cv::determinant(coarse.homography(cv::Rect(0, 0, 2, 2)));
  EXPECT_NEAR(det, 1.0, 1e-6) << "euclidean: no scale";
  const RegistrationResult refined = refineRegistration(sharp, blurred, coarse, K);
  ASSERT_TRUE(refined.kernel_refined) << refined.summary();
  const double before = cornerError(coarse.homography, truth, sharp.size());
  const double after = cornerError(refined.homography, truth, sharp.size());
  EXPECT_LT(after, 0.5) << refined.summary();
  EXPECT_LT(after, before) << coarse.summary();
  EXPECT_NEAR(refined.rotationDegrees(), -0.4, 0.05);
}

// The blurred shot is resampled into the sharp frame (the noisy sharp one never is).
TEST(Registration, WarpToSharpInvertsTheMotion) {
  const cv::Mat sharp = mosaic();
  const cv::Mat H = handheld(sharp.size(), 0.8, {-4.0, 2.5});
  const cv::Mat blurred = warpToBlurred(sharp, H, sharp.size());
  const cv::Mat back = warpToSharp(blurred, H, sharp.size());
  const cv::Mat inside = overlapMaskInSharp(sharp.size(), H, sharp.size(), 4);
  cv::Mat diff;
  cv::absdiff(back, sharp, diff);
  EXPECT_LT(cv::mean(diff, inside)[0], 0.02);
  EXPECT_GT(cv::countNonZero(inside), 0.9 * sharp.total());
}

// A bracket's frames (same sharpness, another exposure, a steady hand): phase correlation + ECC settles them without
// the AKAZE features, at the warp the features-first path finds.
TEST(Registration, TranslationFirstGivesTheFeaturePathsWarp) {
  const cv::Mat reference = mosaic();
  const cv::Mat truth = handheld(reference.size(), 0.6, {7.3, -4.6});
  cv::Mat frame = warpToBlurred(reference, truth.inv(), reference.size());  // frame pixel → reference pixel: truth
  cv::pow(frame, 0.6, frame);                                             // another exposure / tone
  RegistrationOptions fast;
  fast.translation_first = true;
  const RegistrationResult full = registerPair(frame, reference);
  const RegistrationResult first = registerPair(frame, reference, fast);
  EXPECT_EQ(first.method.rfind("phase-first", 0), 0u) << first.summary();
  EXPECT_EQ(full.method.rfind("features", 0), 0u) << full.summary();
  EXPECT_LT(cornerError(first.homography, full.homography, reference.size()), 0.1) << first.summary();
  EXPECT_LT(cornerError(first.homography, truth, reference.size()), 0.5) << first.summary();
  // The same through a target prepared without features (as calibrateBracket does).
  const RegistrationTarget target = prepareRegistrationTarget(reference, reference.size(), fast, false);
  EXPECT_FALSE(target.with_features);
  const std::optional<RegistrationResult> alone = registerByTranslation(frame, target, fast);
  ASSERT_TRUE(alone.has_value());
  EXPECT_EQ(cv::norm(alone->homography, first.homography, cv::NORM_INF), 0.0);
}

// A turn beyond ECC's reach from a translation: the translation-first step declines and the features settle it.
TEST(Registration, TranslationFirstLeavesALargeTurnToTheFeatures) {
  const cv::Mat reference = mosaic();
  const cv::Mat truth = handheld(reference.size(), 30, {0, 0});
  const cv::Mat frame = warpToBlurred(reference, truth.inv(), reference.size());
  RegistrationOptions fast;
  fast.translation_first = true;
  const RegistrationTarget target = prepareRegistrationTarget(reference, reference.size(), fast, false);
  EXPECT_FALSE(registerByTranslation(frame, target, fast).has_value());
  const RegistrationResult r = registerPair(frame, target, fast);  // the target's features detected for this call
  EXPECT_EQ(r.method.rfind("features", 0), 0u) << r.summary();
  EXPECT_LT(cornerError(r.homography, truth, reference.size()), 0.5) << r.summary();
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
