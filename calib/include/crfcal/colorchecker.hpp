#pragma once
// The ColorChecker Classic (Macbeth, 24 patches): published reference values, patch layout, robust patch
// sampling of a rectified chart image, and locating the chart in a photo (OpenCV mcc detector or four corners).
//
// Reference values are compiled in (samples/colorchecker/colorchecker_classic_reference.csv, see its PROVENANCE.md):
// BabelColor average of 30 charts (D50 xyY) and the linear sRGB (D65, Bradford) values derived from it.
#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal::chart {

inline constexpr int kColumns = 6;
inline constexpr int kRows = 4;
inline constexpr int kPatches = kColumns * kRows;  // index = row * 6 + column, row 0 = dark skin … bluish green

struct PatchReference {
  std::string_view name;
  double Y;                       // relative luminance (BabelColor, white ≈ 0.913)
  std::array<double, 3> linear;   // linear sRGB (D65) R, G, B derived from BabelColor xyY
  bool neutral;                   // bottom row: white … black
};

// The 24 reference patches in chart order.
const std::array<PatchReference, kPatches>& reference();

// Which published values serve as the linear reference for a camera channel (documented in docs/RESULTS.md#chart).
enum class ReferenceSet {
  Neutral,     // the six grey patches, reference = Y for every channel (camera-independent: a grey reflects
               // the same fraction in every band, so only the per-shot scale is unknown)
  LinearSrgb,  // all 24 patches, reference = the linear sRGB value of the channel (assumes the camera's
               // colour rendering matches sRGB primaries; biased by the camera's colour mixing)
  Luminance,   // all 24 patches, reference = Y
  AllPatches,  // all 24 patches, no published colour needed: the six greys anchor (Y, as Neutral) and each coloured
               // patch is an unknown per-channel irradiance shared by the shots of one scene, which the shots'
               // exposure ratios tie to the curve (the bracket model of bracket_calibration.hpp). Camera-independent:
               // the camera's colour matrix only changes the unknowns. referenceValue gives the greys' Y.
};
ReferenceSet parseReferenceSet(const std::string& name);  // "neutral" | "srgb" | "luminance" | "all"
std::string referenceSetName(ReferenceSet set);
// Reference value of `patch` for channel c (0 = R, 1 = G, 2 = B) or nullopt when the set does not use it.
std::optional<double> referenceValue(ReferenceSet set, int patch, int channel);

// Robust sampling of one patch (inner area, median, rejection of clipped and non-uniform patches).
struct PatchSamplingOptions {
  double inner_fraction = 0.6;      // side of the sampled square as a fraction of the patch pitch (avoids edges,
                                    // gaps between patches and demosaicing/JPEG ringing at the borders)
  double clip_high = 250.0 / 255;   // a pixel ≥ this (any channel, unit scale) counts as clipped
  double clip_low = 0.0;            // a pixel ≤ this counts as clipped (0: only exact 0)
  double max_clipped_fraction = 0.02;  // reject the patch when more of its pixels are clipped
  double max_spread = 0.04;         // reject when robust σ (1.4826·MAD) exceeds max_spread·median + noise_floor
  double noise_floor = 3.0 / 255;
  double max_gradient = 0.04;       // reject when the quadrant medians differ by more than this fraction
                                    // (+ noise_floor): illumination fall-off, glare, misregistration
  void check() const;
};

struct PatchStats {
  int patch = 0;
  std::array<double, 3> median{};   // unit scale, R, G, B
  std::array<double, 3> spread{};   // robust σ
  double clipped_fraction = 0;      // pixels with any channel clipped
  bool clipped = false;
  bool clipped_high = false;        // clipped at the top (the value is a lower bound of the true one)
  bool non_uniform = false;
  int pixels = 0;
  bool usable() const { return !clipped && !non_uniform; }
  std::string rejection() const;    // "" | "clipped" | "non-uniform"
};

// Samples the 24 patches of a rectified chart image (the whole image is the 6×4 patch grid, e.g. the 390×260
// Middlebury crops), BGR or grey, 8 or 16 bit or float in [0,1]. Per-channel values are returned in R,G,B order.
std::vector<PatchStats> sampleRectified(const cv::Mat& chart, const PatchSamplingOptions& options = {});

// Corners of the patch grid in image coordinates, in chart order: outer corner of dark skin (top-left of the chart),
// of bluish green, of black, of white.
using ChartCorners = std::array<cv::Point2f, 4>;
ChartCorners fullImageCorners(cv::Size size);
// Perspective-rectifies the patch grid to kColumns·pitch × kRows·pitch pixels.
cv::Mat rectify(const cv::Mat& image, const ChartCorners& corners, int pitch = 65);

// Detects a ColorChecker Classic with OpenCV's mcc detector; returns the patch-grid corners in chart order, or
// nullopt when nothing is found. `image` is BGR 8-bit.
std::optional<ChartCorners> detect(const cv::Mat& image);

}  // namespace crfcal::chart
