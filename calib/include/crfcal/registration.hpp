#pragma once
// Registration of a handheld sharp/blurred pair (seed Sec. 4: "We first align the two images").
// The two shots differ in exposure, ISO noise and blur, so both are first photometrically normalised (each grey
// image histogram-equalised: the CRF and the exposure ratio are monotone maps, which equalisation removes).
// 1. Coarse: a global motion on a downscaled copy: AKAZE features + ratio-test matching + RANSAC, refined by ECC
//    (cv::findTransformECC, both images Gaussian-smoothed so that the blur difference matters less). Without
//    enough feature matches (e.g. strong blur), phase correlation gives the translation that seeds ECC.
//    With translation_first (brackets): phase correlation + ECC is tried before the features, which are detected
//    only when that alignment's correlation stays below translation_first_correlation.
// 2. Kernel-aware refinement (refineRegistration): once a kernel K is known, ECC between I ⊗ K and B — now
//    equally blurred, so the blur no longer biases the alignment (an asymmetric handheld kernel drags a plain
//    sharp-vs-blurred ECC towards its centroid and, with a homography's 8 degrees of freedom, into spurious
//    scale and shear that no kernel can absorb).
// Motion model: Euclidean (rotation + translation) by default — a handheld camera turns by a fraction of a
// degree, whose perspective terms are far below a pixel; affine and homography are options. The sub-pixel
// residual translation is left to the kernel, which absorbs it (Sec. 4, [27]).
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

enum class RegistrationMotion { euclidean, affine, homography };
const char* toString(RegistrationMotion motion);

struct RegistrationOptions {
  RegistrationMotion motion = RegistrationMotion::euclidean;
  int max_dimension = 1024;        // working copy: longest side downscaled to this (cost independent of size)
  int refine_max_dimension = 1536; // working copy of the kernel-aware refinement (sub-pixel precision matters)
  int max_features = 3000;         // AKAZE keypoints kept per image
  double match_ratio = 0.8;        // Lowe's ratio test
  double ransac_threshold = 2.5;   // RANSAC reprojection threshold, working-copy pixels
  int min_inliers = 15;            // fewer RANSAC inliers: fall back to phase correlation + ECC
  bool refine_ecc = true;          // ECC refinement of the coarse motion
  int ecc_iterations = 80;
  double ecc_epsilon = 1e-5;
  int ecc_smoothing = 5;           // Gaussian filter size used inside ECC (odd)
  double min_correlation = 0.5;    // ECC correlation below this after alignment: the pair does not overlap
  double min_overlap = 0.4;        // fraction of the blurred frame covered by the warped sharp frame
  // Tripod-like frames (a bracket): phase correlation + ECC first, and the AKAZE features (three quarters of a
  // registration's cost) only when that alignment's ECC correlation stays below `translation_first_correlation`
  // (ECC did not converge, or it stopped in a poorer optimum: a larger rotation or scale change than ECC's capture
  // range from a translation). Off by default: the pair registration keeps its features-first path.
  bool translation_first = false;
  double translation_first_correlation = 0.9;
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
  bool kernel_refined = false;   // refineRegistration succeeded
  double refinement_shift = 0;   // largest corner displacement the kernel-aware refinement applied, pixels
  std::string method;            // e.g. "features+ransac+ecc", "phase+ecc", "+kernel-ecc"
  double scale = 1;              // working-copy scale
  cv::Point2d shift() const;     // translation part (image of the origin), pixels
  double rotationDegrees() const;  // counter-clockwise positive (cv::getRotationMatrix2D convention)
  std::string summary() const;
};

// Registers `sharp` onto `blurred` (any depth, grey or BGR; sizes may differ slightly). Throws InvalidInput
// "the pair does not overlap ..." when no consistent alignment exists.
RegistrationResult registerPair(const cv::Mat& sharp, const cv::Mat& blurred, const RegistrationOptions& options = {});

// The target (`blurred`) side of registerPair prepared once: its photometrically normalised working copy and its
// AKAZE features. Registering several frames onto one reference (a bracket) detects the reference's features once
// instead of once per frame; the result is the same as registerPair(sharp, blurred).
struct RegistrationTarget {
  cv::Size size;                        // the target's full-resolution size
  double scale = 1;                     // working-copy scale (registerPair's, for images of `sharp_size`)
  cv::Mat normalised;                   // 8-bit, histogram-equalised, at `scale`
  bool with_features = false;           // keypoints and descriptors detected
  std::vector<cv::KeyPoint> keypoints;  // AKAZE, at most options.max_features
  cv::Mat descriptors;
};
// Prepares `blurred` for registering images of `sharp_size` onto it (the working scale depends on both sizes).
// `features` false: the normalised copy only (translation-first registrations may never need the features;
// addTargetFeatures adds them later).
RegistrationTarget prepareRegistrationTarget(const cv::Mat& blurred, cv::Size sharp_size,
                                             const RegistrationOptions& options = {}, bool features = true);
void addTargetFeatures(RegistrationTarget& target, const RegistrationOptions& options = {});
// registerPair onto a prepared target. Throws InvalidInput when `sharp` needs another working scale than the one the
// target was prepared for, or as registerPair does. A target without features has them detected for this call
// (when the features are needed).
RegistrationResult registerPair(const cv::Mat& sharp, const RegistrationTarget& target,
                                const RegistrationOptions& options = {});
// The translation-first step of registerPair alone (phase correlation + ECC, no features): the registration when its
// ECC correlation reaches options.translation_first_correlation and it passes registerPair's overlap checks, else
// nothing (the caller then needs the features: registerPair with translation_first off).
std::optional<RegistrationResult> registerByTranslation(const cv::Mat& sharp, const RegistrationTarget& target,
                                                        const RegistrationOptions& options = {});

// Kernel-aware refinement of `coarse`: ECC (the options' motion model) between I ⊗ K and B, both normalised.
// `sharp`, `blurred`: single-channel, any depth; `sharp_valid` (optional CV_8U, sharp frame): pixels of I to use.
// Returns `coarse` unchanged (kernel_refined = false) when ECC fails, does not improve the correlation of the
// equally blurred copies, or jumps by more than the kernel's extent + 4 working-copy pixels (ECC running away).
RegistrationResult refineRegistration(const cv::Mat& sharp, const cv::Mat& blurred, const RegistrationResult& coarse,
                                      const cv::Mat& kernel, const cv::Mat& sharp_valid = {},
                                      const RegistrationOptions& options = {});

// The sharp image resampled into the blurred frame (bilinear; any type/channels). Pixels with no source are 0.
cv::Mat warpToBlurred(const cv::Mat& sharp, const cv::Mat& homography, cv::Size blurred_size);

// The blurred image resampled into the sharp frame: out(p) = blurred(H p). The blurred shot is smooth, so
// resampling it costs almost nothing, whereas resampling the sharp, noisy shot would low-pass it by a
// position-dependent amount (bilinear weights) and change its noise — which the kernel would then have to undo
// (checkerboard kernels) and the CRF fit would mistake for signal. Bicubic. Pixels with no source are 0.
cv::Mat warpToSharp(const cv::Mat& blurred, const cv::Mat& homography, cv::Size sharp_size);

// CV_8U mask (255) of the sharp frame whose image under `homography` lies inside the blurred frame, eroded by
// `margin` pixels (the frame's own border excluded too).
cv::Mat overlapMaskInSharp(cv::Size sharp_size, const cv::Mat& homography, cv::Size blurred_size, int margin = 0);

// CV_8U mask (255) of the blurred frame covered by the warped sharp image, eroded by `margin` pixels.
cv::Mat overlapMask(cv::Size sharp_size, const cv::Mat& homography, cv::Size blurred_size, int margin = 0);

// 8-bit grey copy of an image, histogram-equalised (photometric normalisation used by the registration).
cv::Mat photometricNormalise(const cv::Mat& image);

}  // namespace crfcal
