#include "crfcal/registration.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal {
namespace {

cv::Mat toGray8(const cv::Mat& image) {
  cv::Mat gray = image;
  if (image.channels() == 3) cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  else if (image.channels() == 4) cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
  cv::Mat out;
  switch (gray.depth()) {
    case CV_8U: out = gray.clone(); break;
    case CV_16U: gray.convertTo(out, CV_8U, 255.0 / 65535.0); break;
    default: gray.convertTo(out, CV_8U, 255.0); break;  // float in [0,1]
  }
  return out;
}

cv::Mat scaleMatrix(double s) {
  cv::Mat S = cv::Mat::eye(3, 3, CV_64F);
  S.at<double>(0, 0) = s;
  S.at<double>(1, 1) = s;
  return S;
}

bool saneHomography(const cv::Mat& H) {
  if (H.empty() || !cv::checkRange(H)) return false;
  const double det = H.at<double>(0, 0) * H.at<double>(1, 1) - H.at<double>(0, 1) * H.at<double>(1, 0);
  const double persp = std::abs(H.at<double>(2, 0)) + std::abs(H.at<double>(2, 1));
  return det > 0.5 && det < 2.0 && persp < 2e-3;
}

double coverage(cv::Size sharp, const cv::Mat& H, cv::Size blurred) {
  const cv::Mat mask = overlapMask(sharp, H, blurred);
  return static_cast<double>(cv::countNonZero(mask)) / (static_cast<double>(blurred.area()));
}

int eccMotion(RegistrationMotion m) {
  switch (m) {
    case RegistrationMotion::euclidean: return cv::MOTION_EUCLIDEAN;
    case RegistrationMotion::affine: return cv::MOTION_AFFINE;
    case RegistrationMotion::homography: return cv::MOTION_HOMOGRAPHY;
  }
  return cv::MOTION_EUCLIDEAN;
}

// A 3×3 matrix → the ECC warp of `motion` (2×3 or 3×3, CV_32F); Euclidean: the rotation part re-orthonormalised.
cv::Mat toEccWarp(const cv::Mat& W, int motion) {
  cv::Mat out;
  if (motion == cv::MOTION_HOMOGRAPHY) {
    W.convertTo(out, CV_32F);
    return out;
  }
  cv::Mat A = W.rowRange(0, 2).clone();
  if (motion == cv::MOTION_EUCLIDEAN) {
    const double angle = std::atan2(A.at<double>(1, 0) - A.at<double>(0, 1), A.at<double>(0, 0) + A.at<double>(1, 1));
    A.at<double>(0, 0) = A.at<double>(1, 1) = std::cos(angle);
    A.at<double>(1, 0) = std::sin(angle);
    A.at<double>(0, 1) = -std::sin(angle);
  }
  A.convertTo(out, CV_32F);
  return out;
}

cv::Mat fromEccWarp(const cv::Mat& warp, int motion) {
  cv::Mat R = cv::Mat::eye(3, 3, CV_64F);
  if (motion == cv::MOTION_HOMOGRAPHY) warp.convertTo(R, CV_64F);
  else warp.convertTo(R.rowRange(0, 2), CV_64F);
  return R;
}

double cornerShift(const cv::Mat& A, const cv::Mat& B, cv::Size size) {
  std::vector<cv::Point2d> corners{{0, 0}, {size.width - 1.0, 0}, {0, size.height - 1.0}, {size.width - 1.0, size.height - 1.0}};
  std::vector<cv::Point2d> a, b;
  cv::perspectiveTransform(corners, a, A);
  cv::perspectiveTransform(corners, b, B);
  double worst = 0;
  for (size_t i = 0; i < a.size(); ++i) worst = std::max(worst, cv::norm(a[i] - b[i]));
  return worst;
}

}  // namespace

const char* toString(RegistrationMotion motion) {
  switch (motion) {
    case RegistrationMotion::euclidean: return "euclidean";
    case RegistrationMotion::affine: return "affine";
    case RegistrationMotion::homography: return "homography";
  }
  return "?";
}

void RegistrationOptions::check() const {
  if (max_dimension < 64 || refine_max_dimension < 64) throw InvalidInput("registration: max_dimension must be >= 64");
  if (max_features < 50) throw InvalidInput("registration: max_features must be >= 50");
  if (!(match_ratio > 0 && match_ratio <= 1)) throw InvalidInput("registration: match_ratio must be in (0, 1]");
  if (!(ransac_threshold > 0)) throw InvalidInput("registration: ransac_threshold must be > 0");
  if (min_inliers < 4) throw InvalidInput("registration: min_inliers must be >= 4");
  if (ecc_iterations < 1 || !(ecc_epsilon > 0)) throw InvalidInput("registration: bad ECC criteria");
  if (ecc_smoothing < 1 || ecc_smoothing % 2 == 0) throw InvalidInput("registration: ecc_smoothing must be odd");
  if (!(min_overlap > 0 && min_overlap <= 1)) throw InvalidInput("registration: min_overlap must be in (0, 1]");
  if (!(translation_first_correlation > 0 && translation_first_correlation <= 1))
    throw InvalidInput("registration: translation_first_correlation must be in (0, 1]");
}

cv::Point2d RegistrationResult::shift() const {
  return {homography.at<double>(0, 2), homography.at<double>(1, 2)};
}

double RegistrationResult::rotationDegrees() const {
  return -std::atan2(homography.at<double>(1, 0), homography.at<double>(0, 0)) * 180.0 / CV_PI;  // CCW positive
}

std::string RegistrationResult::summary() const {
  char buffer[300];
  const cv::Point2d t = shift();
  std::snprintf(buffer, sizeof buffer,
                "%s: shift (%.2f, %.2f) px, rotation %.3f deg, %d/%d inliers, ECC correlation %.3f, overlap %.1f%%",
                method.c_str(), t.x, t.y, rotationDegrees(), inliers, matches, ecc_correlation,
                100.0 * overlap_fraction);
  return buffer;
}

cv::Mat photometricNormalise(const cv::Mat& image) {
  cv::Mat gray = toGray8(image), equalised;
  cv::equalizeHist(gray, equalised);
  return equalised;
}

cv::Mat overlapMask(cv::Size sharp_size, const cv::Mat& homography, cv::Size blurred_size, int margin) {
  cv::Mat ones(sharp_size, CV_8U, cv::Scalar(255)), mask;
  cv::warpPerspective(ones, mask, homography, blurred_size, cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
  if (margin > 0) {
    // Also exclude the blurred frame's own border.
    cv::Mat framed = cv::Mat::zeros(blurred_size, CV_8U);
    mask.copyTo(framed);
    cv::rectangle(framed, cv::Rect(0, 0, blurred_size.width, blurred_size.height), cv::Scalar(0), 1);
    cv::erode(framed, mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * margin + 1, 2 * margin + 1)),
              cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  }
  return mask;
}

cv::Mat warpToBlurred(const cv::Mat& sharp, const cv::Mat& homography, cv::Size blurred_size) {
  cv::Mat out;
  cv::warpPerspective(sharp, out, homography, blurred_size, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

cv::Mat warpToSharp(const cv::Mat& blurred, const cv::Mat& homography, cv::Size sharp_size) {
  cv::Mat out;
  // Bicubic: the blurred shot is band-limited by its kernel, where cubic interpolation is close to exact; bilinear
  // would low-pass it by a position-dependent amount (a spatially varying extra kernel).
  cv::warpPerspective(blurred, out, homography, sharp_size, cv::INTER_CUBIC | cv::WARP_INVERSE_MAP,
                      cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

cv::Mat overlapMaskInSharp(cv::Size sharp_size, const cv::Mat& homography, cv::Size blurred_size, int margin) {
  return overlapMask(blurred_size, homography.inv(), sharp_size, margin);
}

namespace {

// AKAZE keypoints and descriptors of one working copy, at most options.max_features (the strongest).
void detectFeatures(const cv::Mat& image, const RegistrationOptions& options, std::vector<cv::KeyPoint>& keypoints,
                    cv::Mat& descriptors) {
  auto akaze = cv::AKAZE::create(cv::AKAZE::DESCRIPTOR_MLDB, 0, 3, 0.0005f);
  akaze->detectAndCompute(image, cv::noArray(), keypoints, descriptors);
  if (static_cast<int>(keypoints.size()) > options.max_features) {
    cv::KeyPointsFilter::retainBest(keypoints, options.max_features);
    akaze->compute(image, keypoints, descriptors);
  }
}

// Step 1 of registerPair: AKAZE features, ratio-test matches and RANSAC (similarity for the Euclidean model, whose ECC
// step drops the scale). Returns the working-scale homography sharp → blurred, or an empty matrix when the features do
// not give a sane one; fills the keypoint, match and inlier counts and the method of `result`.
// The target's features come prepared (prepareRegistrationTarget).
cv::Mat featureHomography(const cv::Mat& a, const RegistrationTarget& target, const RegistrationOptions& options,
                          RegistrationResult& result) {
  cv::Mat H;
  std::vector<cv::KeyPoint> ka;
  cv::Mat da;
  detectFeatures(a, options, ka, da);
  const std::vector<cv::KeyPoint>& kb = target.keypoints;
  const cv::Mat& db = target.descriptors;
  result.keypoints_sharp = static_cast<int>(ka.size());
  result.keypoints_blurred = static_cast<int>(kb.size());
  if (ka.size() < 8 || kb.size() < 8) return H;
  cv::BFMatcher matcher(cv::NORM_HAMMING);
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(da, db, knn, 2);
  std::vector<cv::Point2f> pa, pb;
  for (const auto& m : knn) {
    if (m.size() == 2 && m[0].distance < options.match_ratio * m[1].distance) {
      pa.push_back(ka[m[0].queryIdx].pt);
      pb.push_back(kb[m[0].trainIdx].pt);
    }
  }
  result.matches = static_cast<int>(pa.size());
  if (pa.size() < 8) return H;
  std::vector<uchar> inlier_mask;
  cv::Mat candidate;
  if (options.motion == RegistrationMotion::homography) {
    candidate = cv::findHomography(pa, pb, cv::RANSAC, options.ransac_threshold, inlier_mask, 4000, 0.999);
  } else {
    const cv::Mat A = options.motion == RegistrationMotion::affine
                          ? cv::estimateAffine2D(pa, pb, inlier_mask, cv::RANSAC, options.ransac_threshold, 4000, 0.999)
                          : cv::estimateAffinePartial2D(pa, pb, inlier_mask, cv::RANSAC, options.ransac_threshold,
                                                        4000, 0.999);
    if (!A.empty()) {
      candidate = cv::Mat::eye(3, 3, CV_64F);
      A.copyTo(candidate.rowRange(0, 2));
    }
  }
  const int inliers = candidate.empty() ? 0 : cv::countNonZero(inlier_mask);
  if (inliers >= options.min_inliers && saneHomography(candidate)) {
    H = candidate;
    result.inliers = inliers;
    result.method = "features+ransac";
  }
  return H;
}

// Step 2 of registerPair, the fallback: phase correlation (translation) on the normalised copies.
cv::Mat phaseHomography(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat fa, fb;
  cv::Size common(std::min(a.cols, b.cols), std::min(a.rows, b.rows));
  a(cv::Rect(0, 0, common.width, common.height)).convertTo(fa, CV_64F);
  b(cv::Rect(0, 0, common.width, common.height)).convertTo(fb, CV_64F);
  cv::Mat window;
  cv::createHanningWindow(window, common, CV_64F);
  double response = 0;
  const cv::Point2d t = cv::phaseCorrelate(fa, fb, window, &response);
  cv::Mat H = cv::Mat::eye(3, 3, CV_64F);
  H.at<double>(0, 2) = t.x;
  H.at<double>(1, 2) = t.y;
  return H;
}

// The translation-first path's start: phase correlation on copies at most 256 px on their longer side, cropped to a
// size OpenCV's DFT handles fast (on 390×260 frames the full-size CV_64F phaseCorrelate took 25 ms, more than ECC;
// at 192×128 CV_32F 0.6 ms). ECC only needs a start within its capture range, a few working pixels; this one is
// within a pixel or two of the downscale factor.
cv::Mat phaseStart(const cv::Mat& a, const cv::Mat& b) {
  constexpr int kLongest = 256;
  const cv::Size common(std::min(a.cols, b.cols), std::min(a.rows, b.rows));
  const double f = std::min(1.0, double(kLongest) / std::max(common.width, common.height));
  cv::Mat sa = a(cv::Rect(0, 0, common.width, common.height)), sb = b(cv::Rect(0, 0, common.width, common.height));
  if (f < 1) {
    cv::resize(sa, sa, cv::Size(), f, f, cv::INTER_AREA);
    cv::resize(sb, sb, cv::Size(), f, f, cv::INTER_AREA);
  }
  const auto fast_length = [](int n) {  // the largest n' ≤ n that cv::dft handles fast
    while (n > 1 && cv::getOptimalDFTSize(n) != n) --n;
    return n;
  };
  const cv::Rect crop(0, 0, fast_length(std::min(sa.cols, sb.cols)), fast_length(std::min(sa.rows, sb.rows)));
  cv::Mat fa, fb, window;
  sa(crop).convertTo(fa, CV_32F);
  sb(crop).convertTo(fb, CV_32F);
  cv::createHanningWindow(window, crop.size(), CV_32F);
  const cv::Point2d t = cv::phaseCorrelate(fa, fb, window);
  cv::Mat H = cv::Mat::eye(3, 3, CV_64F);
  // The downscaled copies' pixel centres: x_full = (x_small + 0.5) / f − 0.5, so a shift scales by 1/f.
  H.at<double>(0, 2) = t.x / f;
  H.at<double>(1, 2) = t.y / f;
  return H;
}

// Step 3 of registerPair: ECC refinement of H (template = blurred, input = sharp; the warp maps blurred → sharp
// coordinates). Replaces H and marks `result` only when ECC converges to a sane homography.
void refineByEcc(const cv::Mat& fa, const cv::Mat& fb, int motion, const RegistrationOptions& options, cv::Mat& H,
                 RegistrationResult& result) {
  try {
    const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, options.ecc_iterations,
                                    options.ecc_epsilon);
    cv::Mat refined = toEccWarp(H.inv(), motion);
    result.ecc_correlation = cv::findTransformECC(fb, fa, refined, motion, criteria, cv::noArray(), options.ecc_smoothing);
    const cv::Mat Hr = fromEccWarp(refined, motion).inv();
    if (saneHomography(Hr)) {
      H = Hr;
      result.ecc_refined = true;
      result.method += "+ecc";
    }
  } catch (const cv::Exception&) {
    // ECC did not converge: keep the feature/phase estimate, judged below by its correlation.
  }
}

// Correlation of the alignment H of the working copies (smoothed, like ECC measures it), over their overlap.
double alignmentCorrelation(const cv::Mat& fa, const cv::Mat& fb, const cv::Mat& H, const RegistrationOptions& options) {
  cv::Mat warped, ga, gb;
  cv::warpPerspective(fa, warped, H, fb.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
  const cv::Mat mask = overlapMask(fa.size(), H, fb.size(), 2);
  cv::GaussianBlur(warped, ga, cv::Size(options.ecc_smoothing, options.ecc_smoothing), 0);
  cv::GaussianBlur(fb, gb, cv::Size(options.ecc_smoothing, options.ecc_smoothing), 0);
  cv::Scalar ma, sa, mb, sb;
  cv::meanStdDev(ga, ma, sa, mask);
  cv::meanStdDev(gb, mb, sb, mask);
  cv::Mat prod = (ga - ma[0]).mul(gb - mb[0]);
  const double n = std::max(1, cv::countNonZero(mask));
  cv::Mat masked;
  prod.copyTo(masked, mask);
  return cv::sum(masked)[0] / n / std::max(1e-12, sa[0] * sb[0]);
}

}  // namespace

namespace {

// The working-copy scale of registerPair: the longer side of either image brought to options.max_dimension.
double workingScale(cv::Size sharp, cv::Size blurred, const RegistrationOptions& options) {
  const int longest = std::max({sharp.width, sharp.height, blurred.width, blurred.height});
  return std::min(1.0, static_cast<double>(options.max_dimension) / longest);
}

}  // namespace

RegistrationTarget prepareRegistrationTarget(const cv::Mat& blurred, cv::Size sharp_size,
                                             const RegistrationOptions& options, bool features) {
  options.check();
  if (blurred.empty()) throw InvalidInput("registration: empty image");
  RegistrationTarget target;
  target.size = blurred.size();
  target.scale = workingScale(sharp_size, blurred.size(), options);
  const double scale = target.scale;
  target.normalised = photometricNormalise(blurred);
  if (scale < 1) cv::resize(target.normalised, target.normalised, cv::Size(), scale, scale, cv::INTER_AREA);
  if (features) addTargetFeatures(target, options);
  return target;
}

void addTargetFeatures(RegistrationTarget& target, const RegistrationOptions& options) {
  if (target.with_features) return;
  detectFeatures(target.normalised, options, target.keypoints, target.descriptors);
  target.with_features = true;
}

RegistrationResult registerPair(const cv::Mat& sharp, const cv::Mat& blurred, const RegistrationOptions& options) {
  options.check();
  if (sharp.empty() || blurred.empty()) throw InvalidInput("registration: empty image");
  // Translation first: the blurred side's features are detected only when that path does not settle it.
  return registerPair(sharp, prepareRegistrationTarget(blurred, sharp.size(), options, !options.translation_first),
                      options);
}

namespace {

// Both sides of a registration at the working scale: the sharp frame's normalised copy and both as float.
struct WorkingCopies {
  double scale = 1;
  cv::Mat a;       // sharp, 8-bit normalised, at `scale`
  cv::Mat fa, fb;  // sharp and target, CV_32F in [0, 1]
};

WorkingCopies workingCopies(const cv::Mat& sharp, const RegistrationTarget& target, const RegistrationOptions& options) {
  options.check();
  if (sharp.empty() || target.normalised.empty()) throw InvalidInput("registration: empty image");
  WorkingCopies w;
  w.scale = workingScale(sharp.size(), target.size, options);
  if (w.scale != target.scale)
    throw InvalidInput("registration: the target was prepared for images of another size (working scale " +
                       std::to_string(target.scale) + ", this image needs " + std::to_string(w.scale) + ")");
  w.a = photometricNormalise(sharp);
  if (w.scale < 1) cv::resize(w.a, w.a, cv::Size(), w.scale, w.scale, cv::INTER_AREA);
  w.a.convertTo(w.fa, CV_32F, 1.0 / 255);
  target.normalised.convertTo(w.fb, CV_32F, 1.0 / 255);
  return w;
}

// The working-scale alignment H (sharp → target) as the full-resolution result, and its overlap.
void completeResult(const cv::Mat& H, double s, cv::Size sharp_size, const RegistrationTarget& target,
                    const RegistrationOptions& options, RegistrationResult& result) {
  result.scale = s;
  result.method += std::string(" (") + toString(options.motion) + ")";
  result.homography = scaleMatrix(1.0 / s) * H * scaleMatrix(s);
  result.overlap_fraction = coverage(sharp_size, result.homography, target.size);
}

bool overlaps(const RegistrationResult& result, const RegistrationOptions& options) {
  return result.overlap_fraction >= options.min_overlap && result.ecc_correlation >= options.min_correlation;
}

// registerByTranslation on prepared working copies.
std::optional<RegistrationResult> translationFirst(const WorkingCopies& w, cv::Size sharp_size,
                                                   const RegistrationTarget& target,
                                                   const RegistrationOptions& options) {
  RegistrationResult result;
  cv::Mat H = phaseStart(w.a, target.normalised);
  result.method = "phase-first";
  refineByEcc(w.fa, w.fb, eccMotion(options.motion), options, H, result);
  if (!result.ecc_refined || !(result.ecc_correlation >= options.translation_first_correlation)) return std::nullopt;
  completeResult(H, w.scale, sharp_size, target, options, result);
  if (!overlaps(result, options)) return std::nullopt;
  return result;
}

}  // namespace

std::optional<RegistrationResult> registerByTranslation(const cv::Mat& sharp, const RegistrationTarget& target,
                                                        const RegistrationOptions& options) {
  return translationFirst(workingCopies(sharp, target, options), sharp.size(), target, options);
}

RegistrationResult registerPair(const cv::Mat& sharp, const RegistrationTarget& prepared,
                                const RegistrationOptions& options) {
  const WorkingCopies w = workingCopies(sharp, prepared, options);
  if (options.translation_first)
    if (auto fast = translationFirst(w, sharp.size(), prepared, options)) return *fast;
  RegistrationTarget with_features;
  if (!prepared.with_features) {  // a target prepared for translation first, which did not settle this frame
    with_features = prepared;
    addTargetFeatures(with_features, options);
  }
  const RegistrationTarget& target = prepared.with_features ? prepared : with_features;
  RegistrationResult result;
  const cv::Mat& b = target.normalised;
  cv::Mat H = featureHomography(w.a, target, options, result);  // working scale, sharp → blurred
  if (H.empty()) {
    H = phaseHomography(w.a, b);
    result.method = "phase";
  }
  if (options.refine_ecc || result.method == "phase") refineByEcc(w.fa, w.fb, eccMotion(options.motion), options, H, result);
  if (!result.ecc_refined) result.ecc_correlation = alignmentCorrelation(w.fa, w.fb, H, options);
  completeResult(H, w.scale, sharp.size(), target, options, result);
  if (!overlaps(result, options)) {
    char detail[200];
    std::snprintf(detail, sizeof detail,
                  "the pair does not overlap (best alignment: %.0f%% overlap, correlation %.2f, %d feature inliers)",
                  100.0 * result.overlap_fraction, result.ecc_correlation, result.inliers);
    throw InvalidInput(detail);
  }
  return result;
}

RegistrationResult refineRegistration(const cv::Mat& sharp, const cv::Mat& blurred, const RegistrationResult& coarse,
                                      const cv::Mat& kernel, const cv::Mat& sharp_valid,
                                      const RegistrationOptions& options) {
  options.check();
  if (sharp.channels() != 1 || blurred.channels() != 1) throw InvalidInput("refineRegistration: single-channel images expected");
  RegistrationResult result = coarse;
  const int longest = std::max({sharp.cols, sharp.rows, blurred.cols, blurred.rows});
  const double s = std::min(1.0, static_cast<double>(options.refine_max_dimension) / longest);
  // I ⊗ K, now as blurred as B (up to the tone curve, which the equalisation removes). On the working copy: the
  // image and the kernel are both scaled by s (area-averaged), which keeps their convolution consistent.
  cv::Mat a8 = toGray8(sharp), b8 = toGray8(blurred);
  cv::Mat K = normalizeKernel(kernel);
  cv::Mat mask;
  if (!sharp_valid.empty()) mask = sharp_valid.clone();
  if (s < 1) {
    cv::resize(a8, a8, cv::Size(), s, s, cv::INTER_AREA);
    cv::resize(b8, b8, cv::Size(), s, s, cv::INTER_AREA);
    const int kw = std::max(1, static_cast<int>(std::lround(K.cols * s))) | 1;
    const int kh = std::max(1, static_cast<int>(std::lround(K.rows * s))) | 1;
    cv::resize(K, K, cv::Size(kw, kh), 0, 0, cv::INTER_AREA);
    K = normalizeKernel(K);
    if (!mask.empty()) {
      cv::resize(mask, mask, a8.size(), 0, 0, cv::INTER_AREA);
      cv::threshold(mask, mask, 254, 255, cv::THRESH_BINARY);
    }
  }
  cv::Mat a = photometricNormalise(convolve(toUnitGray(a8), K)), b = photometricNormalise(b8);
  cv::Mat fa, fb;
  a.convertTo(fa, CV_32F, 1.0 / 255);
  b.convertTo(fb, CV_32F, 1.0 / 255);
  const int motion = eccMotion(options.motion);
  const cv::Mat H0 = scaleMatrix(s) * coarse.homography * scaleMatrix(1.0 / s);
  // The coarse alignment's correlation on the same working images: the refinement must beat it.
  auto correlationOf = [&](const cv::Mat& warp_input_to_template) {
    cv::Mat warped, warped_mask;
    cv::warpPerspective(fa, warped, warp_input_to_template, fb.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
    const cv::Mat valid = mask.empty() ? cv::Mat(fa.size(), CV_8U, cv::Scalar(255)) : mask;
    cv::warpPerspective(valid, warped_mask, warp_input_to_template, fb.size(), cv::INTER_NEAREST, cv::BORDER_CONSTANT,
                        cv::Scalar(0));
    return cv::computeECC(fb, warped, warped_mask);
  };
  try {
    const double before = correlationOf(H0);
    const cv::TermCriteria criteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, options.ecc_iterations,
                                    options.ecc_epsilon);
    cv::Mat warp = toEccWarp(H0.inv(), motion);
    cv::findTransformECC(fb, fa, warp, motion, criteria, mask.empty() ? cv::noArray() : mask, 3);
    const cv::Mat Hw = fromEccWarp(warp, motion).inv();
    const double after = saneHomography(Hw) ? correlationOf(Hw) : -1;
    // The coarse alignment is off by at most about the kernel's extent (the blur drags it towards the kernel's
    // mass); a larger jump is ECC running away, not refining.
    const double moved = saneHomography(Hw) ? cornerShift(Hw, H0, fa.size()) : 1e9;
    const double limit = 4.0 + std::max(K.rows, K.cols);
    const cv::Mat H = scaleMatrix(1.0 / s) * Hw * scaleMatrix(s);
    if (std::isfinite(after) && after > before && moved < limit) {
      result.refinement_shift = cornerShift(H, coarse.homography, sharp.size());
      result.homography = H;
      result.ecc_correlation = after;
      result.kernel_refined = true;
      result.method += "+kernel-ecc";
      result.overlap_fraction = coverage(sharp.size(), H, blurred.size());
    }
  } catch (const cv::Exception&) {
    // no convergence: keep the coarse alignment
  }
  return result;
}

}  // namespace crfcal
