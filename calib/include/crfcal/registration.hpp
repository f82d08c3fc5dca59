#pragma once
// Coarse registration of a handheld sharp/blurred pair (seed Sec. 4: "We first align the two images").
// The two shots differ in exposure, ISO noise and blur, so both are first photometrically normalised (each grey
// image histogram-equalised: the CRF and the exposure ratio are monotone maps, which equalisation removes),
// then a global homography is found on a downscaled copy: AKAZE features + ratio-test matching + RANSAC
// (cv::findHomography), refined by ECC (cv::findTransformECC, both images Gaussian-smoothed so that the blur
// difference matters less). Without enough feature matches (e.g. strong blur), phase correlation gives the
// translation that seeds ECC. Sub-pixel residual shift is left to the kernel, which absorbs it (Sec. 4, [27]).
#include <string>

#include <opencv2/core.hpp>

namespace crfcal {

struct RegistrationOptions {
  int max_dimension = 1024;        // working copy: longest side downscaled to this (cost independent of size)
  int max_features = 3000;         // AKAZE keypoints kept per image
  double match_ratio = 0.8;        // Lowe's ratio test
  double ransac_threshold = 2.5;   // RANSAC reprojection threshold, working-copy pixels
  int min_inliers = 15;            // fewer RANSAC inliers: fall back to phase correlation + ECC
  bool refine_ecc = true;          // ECC refinement of the homography
  int ecc_iterations = 80;
  double ecc_epsilon = 1e-5;
  int ecc_smoothing = 5;           // Gaussian filter size used inside ECC (odd)
  double min_correlation = 0.5;    // ECC correlation below this after alignment: the pair does not overlap
  double min_overlap = 0.4;        // fraction of the blurred frame covered by the warped sharp frame
  void check() const;              // throws InvalidInput
};

struct RegistrationResult {
  cv::Mat homography = cv::Mat::eye(3, 3, CV_64F);  // sharp pixel → blurred pixel, full resolution, CV_64F
  double ecc_correlation = 0;    // enhanced correlation coefficient of the aligned (normalised, smoothed) copies
  double overlap_fraction = 0;   // of the blurred frame covered by the warped sharp image
  int keypoints_sharp = 0, keypoints_blurred = 0;
  int matches = 0;               // after the ratio test
  int inliers = 0;               // RANSAC inliers
  bool ecc_refined = false;
  std::string method;            // "features+ransac+ecc", "features+ransac", "phase+ecc"
  double scale = 1;              // working-copy scale
  cv::Point2d shift() const;     // translation part at the image centre (blurred − sharp), pixels
  double rotationDegrees() const;  // counter-clockwise positive (cv::getRotationMatrix2D convention)
  std::string summary() const;
};

// Registers `sharp` onto `blurred` (any depth, grey or BGR; sizes may differ slightly). Throws InvalidInput
// "the pair does not overlap ..." when no consistent alignment exists.
RegistrationResult registerPair(const cv::Mat& sharp, const cv::Mat& blurred, const RegistrationOptions& options = {});

// The sharp image resampled into the blurred frame (bilinear; any type/channels). Pixels with no source are 0.
cv::Mat warpToBlurred(const cv::Mat& sharp, const cv::Mat& homography, cv::Size blurred_size);

// CV_8U mask (255) of the blurred frame covered by the warped sharp image, eroded by `margin` pixels.
cv::Mat overlapMask(cv::Size sharp_size, const cv::Mat& homography, cv::Size blurred_size, int margin = 0);

// 8-bit grey copy of an image, histogram-equalised (photometric normalisation used by the registration).
cv::Mat photometricNormalise(const cv::Mat& image);

}  // namespace crfcal
