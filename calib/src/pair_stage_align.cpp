// Stage "align" of calibratePair (seed Sec. 4: "We first align the two images"): the registration (registration.hpp),
// the blurred shot resampled into the sharp frame, the test that the two shots show one scene, and the kernel's
// tiles and canvas on the pixels usable in both shots.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "image_units.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

void turnSharpShot(PairCalibrationState& state, const cv::Mat& sharp_in) {
  // One shot held in portrait, the other in landscape (EXIF orientation not recorded): the sharp shot is turned
  // by ±90° (a lossless pixel permutation, no resampling of the noisy image) — whichever registers.
  PairCalibrationResult& result = state.result;
  state.report("register", 0, "frames transposed: trying the sharp shot turned by +90 and -90 degrees");
  double best = -1;
  std::string failures;
  for (const int code : {cv::ROTATE_90_CLOCKWISE, cv::ROTATE_90_COUNTERCLOCKWISE}) {
    cv::Mat candidate;
    cv::rotate(sharp_in, candidate, code);
    try {
      const RegistrationResult r = registerPair(candidate, state.blurred, state.options.registration);
      // The features are rotation invariant, so the wrong turn may still register as a ~180° rotation: a
      // handheld pair differs by a small angle, and that is the turn to keep.
      if (std::abs(r.rotationDegrees()) > 45) continue;
      if (r.ecc_correlation * r.overlap_fraction > best) {
        best = r.ecc_correlation * r.overlap_fraction;
        state.sharp = candidate;
        result.registration = r;
        result.sharp_rotation_deg = code == cv::ROTATE_90_CLOCKWISE ? -90 : 90;
      }
    } catch (const InvalidInput& e) {
      failures = e.what();
    }
  }
  if (state.sharp.empty())
    throw InvalidInput("the images differ in orientation and neither 90-degree turn aligns them: " + failures,
                       ErrorSubject::pair);
  result.warnings.push_back("the sharp shot is framed in the other orientation; it was turned by " +
                            std::to_string(static_cast<int>(result.sharp_rotation_deg)) +
                            " degrees (outputs are in the blurred shot's orientation)");
  state.registered = true;
}

namespace {

// The blurred shot's G plane in the sharp frame and the overlap of the two frames.
void warpBlurredShot(PairCalibrationState& state) {
  const bool warp = state.options.register_pair;
  const cv::Mat& H = state.result.registration.homography;
  state.blurred_g8 = warp ? warpToSharp(state.blurred_own_g8, H, state.sharp.size()) : state.blurred_own_g8;
  state.overlap = overlapMaskInSharp(state.sharp.size(), H, state.blurred.size(), warp ? 2 : 0);
  if (cv::countNonZero(state.overlap) < 0.2 * state.overlap.total())
    throw InvalidInput("the pair does not overlap enough after registration", ErrorSubject::pair);
}

// Refuses a pair whose shots do not show one scene. Registration alone does not catch it: ECC on two smoothed,
// equalised, unrelated photos can exceed its threshold, and the kernel then grows to its size limit trying to
// explain one image by the other.
void checkSameScene(PairCalibrationState& state) {
  const double correlation = sameSceneCorrelation(state.sharp_g8, state.blurred_g8, state.overlap);
  state.same_scene_correlation = correlation;
  if (correlation < min_same_scene_correlation) {
    char buffer[300];
    std::snprintf(buffer, sizeof buffer,
                  "the two images do not show the same scene (their edges correlate %.2f after registration, "
                  "below %.2f)",
                  correlation, min_same_scene_correlation);
    throw InvalidInput(buffer, ErrorSubject::pair);
  }
}

// Gradient magnitude of `image` smoothed by a Gaussian of `sigma` px (none for 0).
cv::Mat gradientMagnitude(const cv::Mat& image, double sigma) {
  cv::Mat smooth = image, gx, gy, magnitude;
  if (sigma > 0) cv::GaussianBlur(image, smooth, cv::Size(), sigma);
  cv::Sobel(smooth, gx, CV_64F, 1, 0, 3, 1.0 / 8);
  cv::Sobel(smooth, gy, CV_64F, 0, 1, 3, 1.0 / 8);
  cv::magnitude(gx, gy, magnitude);
  return magnitude;
}

double maskedCorrelation(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  cv::Scalar mean_a, std_a, mean_b, std_b;
  cv::meanStdDev(a, mean_a, std_a, mask);
  cv::meanStdDev(b, mean_b, std_b, mask);
  if (!(std_a[0] > 0 && std_b[0] > 0)) return 0;
  const cv::Mat product = (a - mean_a[0]).mul(b - mean_b[0]);
  return cv::mean(product, mask)[0] / (std_a[0] * std_b[0]);
}

}  // namespace

// Pixels usable for the kernel: inside the overlap and unclipped in both shots (the estimator itself keeps only
// equations whose whole window is usable); the edge-rich tiles among them and the canvas they make.
void selectKernelTiles(PairCalibrationState& state) {
  const cv::Mat sharp_bad =
      state.kernel_admits_sharp_black ? state.sharp_clipped & ~state.sharp_black : state.sharp_clipped;
  const cv::Mat bad = (state.blurred_g8 >= state.clip_high) | (state.blurred_g8 <= state.clip_low) | sharp_bad;
  cv::bitwise_and(state.overlap, ~dilateBy(bad, 3), state.usable);
  state.result.tiles = selectTiles(state.sharp_g8, state.usable, state.options.tiles);
  state.canvas = makeCanvas(state.sharp_g8, state.blurred_g8, state.usable, state.result.tiles,
                            state.kernel_options.kernel_size + 2);
}

double sameSceneCorrelation(const cv::Mat& sharp_g, const cv::Mat& blurred_g_in_sharp, const cv::Mat& overlap) {
  // A working copy of at most 512 px (the scene's layout, not its noise or texture), the sharp shot's levels
  // histogram-matched to the blurred one's (exposure and tone curve removed).
  constexpr int max_side = 512;
  const double s = std::min(1.0, static_cast<double>(max_side) / std::max(sharp_g.cols, sharp_g.rows));
  cv::Mat sharp = unit(sharp_g), blurred = unit(blurred_g_in_sharp), inside = overlap;
  if (s < 1) {
    cv::resize(sharp, sharp, cv::Size(), s, s, cv::INTER_AREA);
    cv::resize(blurred, blurred, cv::Size(), s, s, cv::INTER_AREA);
    cv::resize(overlap, inside, sharp.size(), 0, 0, cv::INTER_NEAREST);
  }
  sharp = histogramMatch(sharp, blurred, inside);
  // The blur is unknown here: the sharp shot is compared at a few extra smoothings (working-copy px) and the best
  // agreement counts. The mask is eroded past each filter's reach so that the overlap's border is no edge.
  const cv::Mat blurred_magnitude = gradientMagnitude(blurred, 1.0);
  double best = -1;
  for (const double extra : {0.0, 1.5, 3.0, 6.0}) {
    const double sigma = std::hypot(1.0, extra);
    cv::Mat mask;
    const int reach = 2 * static_cast<int>(std::ceil(3 * sigma)) + 3;
    cv::erode(inside, mask, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(reach, reach)), cv::Point(-1, -1), 1,
              cv::BORDER_CONSTANT, cv::Scalar(0));
    if (cv::countNonZero(mask) < 0.05 * mask.total()) continue;
    best = std::max(best, maskedCorrelation(gradientMagnitude(sharp, sigma), blurred_magnitude, mask));
  }
  return best;
}

void alignToRegistration(PairCalibrationState& state) {
  warpBlurredShot(state);
  selectKernelTiles(state);
}

void registerShots(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  state.report("register", 0);
  if (state.registered) {
    // registered while finding the orientation
  } else if (options.register_pair) {
    state.register_start = Clock::now();
    result.registration = registerPair(state.sharp, state.blurred, options.registration);
  } else {
    result.registration.method = "none (given as aligned)";
    result.registration.overlap_fraction = 1;
    result.registration.ecc_correlation = 1;
  }
  result.timings["register"] = secondsSince(state.register_start);
  state.report("register", 1, result.registration.summary());

  // I's clipped regions, by its local median (a per-pixel test would select pixels by their noise).
  cv::Mat median;
  cv::medianBlur(state.sharp_g8, median, 3);
  state.sharp_black = median <= state.clip_low;
  state.sharp_clipped = (median >= state.clip_high) | state.sharp_black;

  warpBlurredShot(state);
  checkSameScene(state);
  selectKernelTiles(state);
}

}  // namespace crfcal::detail
