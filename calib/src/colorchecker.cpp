#include "crfcal/colorchecker.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>
#include <opencv2/mcc.hpp>

#include "crfcal/error.hpp"

namespace crfcal::chart {
namespace {

// samples/colorchecker/colorchecker_classic_reference.csv: name, Y_babel, R_lin, G_lin, B_lin (linear sRGB, D65,
// Bradford-adapted from the BabelColor D50 xyY average of 30 charts).
const std::array<PatchReference, kPatches> kReference{{
    {"dark skin", 0.1034, {0.17751, 0.08430, 0.05723}, false},
    {"light skin", 0.3525, {0.57017, 0.29613, 0.22013}, false},
    {"blue sky", 0.1847, {0.10560, 0.19646, 0.33597}, false},
    {"foliage", 0.1335, {0.10188, 0.15018, 0.05233}, false},
    {"blue flower", 0.2324, {0.22612, 0.21762, 0.43026}, false},
    {"bluish green", 0.4174, {0.11117, 0.51293, 0.41167}, false},
    {"orange", 0.3117, {0.74051, 0.20276, 0.02591}, false},
    {"purplish blue", 0.1140, {0.06053, 0.10707, 0.39226}, false},
    {"moderate red", 0.1979, {0.57309, 0.08804, 0.11987}, false},
    {"purple", 0.0644, {0.10758, 0.04485, 0.13714}, false},
    {"yellow green", 0.4435, {0.34807, 0.50636, 0.05027}, false},
    {"orange yellow", 0.4358, {0.79631, 0.35908, 0.01973}, false},
    {"blue", 0.0579, {0.01971, 0.04993, 0.29238}, false},
    {"green", 0.2307, {0.05854, 0.29795, 0.06730}, false},
    {"red", 0.1268, {0.46410, 0.02941, 0.04043}, false},
    {"yellow", 0.6081, {0.87094, 0.57726, 0.00784}, false},
    {"magenta", 0.2007, {0.53348, 0.08886, 0.30179}, false},
    {"cyan", 0.1903, {-0.03325, 0.24280, 0.38999}, false},
    {"white 9.5 (.05 D)", 0.9129, {0.91835, 0.91448, 0.87425}, true},
    {"neutral 8 (.23 D)", 0.5885, {0.58123, 0.59103, 0.58524}, true},
    {"neutral 6.5 (.44 D)", 0.3595, {0.35451, 0.36103, 0.35976}, true},
    {"neutral 5 (.70 D)", 0.1912, {0.18712, 0.19240, 0.19204}, true},
    {"neutral 3.5 (1.05 D)", 0.0893, {0.08672, 0.08995, 0.09105}, true},
    {"black 2 (1.5 D)", 0.0320, {0.03180, 0.03200, 0.03270}, true},
}};

double median(std::vector<double>& v) {
  if (v.empty()) return 0;
  const size_t h = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(h), v.end());
  double m = v[h];
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(h)));
  return m;
}

// Image as CV_64F, three channels in R,G,B order, unit scale.
cv::Mat toUnitRgb(const cv::Mat& image) {
  if (image.empty()) throw InvalidInput("chart image is empty");
  double scale = 1;
  switch (image.depth()) {
    case CV_8U: scale = 1.0 / 255; break;
    case CV_16U: scale = 1.0 / 65535; break;
    case CV_32F:
    case CV_64F: break;
    default: throw InvalidInput("chart image must be 8/16-bit or floating point");
  }
  cv::Mat unit;
  image.convertTo(unit, CV_64F, scale);
  cv::Mat rgb;
  std::vector<cv::Mat> planes;
  cv::split(unit, planes);
  if (planes.size() == 1) cv::merge(std::vector<cv::Mat>{unit, unit, unit}, rgb);
  else if (planes.size() == 3 || planes.size() == 4) cv::merge(std::vector<cv::Mat>{planes[2], planes[1], planes[0]}, rgb);
  else throw InvalidInput("chart image must have 1, 3 or 4 channels");
  return rgb;
}

}  // namespace

const std::array<PatchReference, kPatches>& reference() { return kReference; }

ReferenceSet parseReferenceSet(const std::string& name) {
  if (name == "neutral") return ReferenceSet::Neutral;
  if (name == "srgb") return ReferenceSet::LinearSrgb;
  if (name == "luminance") return ReferenceSet::Luminance;
  if (name == "all") return ReferenceSet::AllPatches;
  throw InvalidInput("unknown chart reference '" + name + "' (neutral | srgb | luminance | all)");
}

std::string referenceSetName(ReferenceSet set) {
  switch (set) {
    case ReferenceSet::Neutral: return "neutral";
    case ReferenceSet::LinearSrgb: return "srgb";
    case ReferenceSet::Luminance: return "luminance";
    case ReferenceSet::AllPatches: return "all";
  }
  return "?";
}

std::optional<double> referenceValue(ReferenceSet set, int patch, int channel) {
  if (patch < 0 || patch >= kPatches || channel < 0 || channel > 2) throw InvalidInput("patch/channel out of range");
  const PatchReference& p = kReference[static_cast<size_t>(patch)];
  double value = 0;
  switch (set) {
    case ReferenceSet::Neutral:
    case ReferenceSet::AllPatches:
      if (!p.neutral) return std::nullopt;
      value = p.Y;
      break;
    case ReferenceSet::Luminance: value = p.Y; break;
    case ReferenceSet::LinearSrgb: value = p.linear[static_cast<size_t>(channel)]; break;
  }
  if (!(value > 0.005)) return std::nullopt;  // out-of-gamut (cyan R < 0) or too dark to be a usable reference
  return value;
}

void PatchSamplingOptions::check() const {
  if (!(inner_fraction > 0.05 && inner_fraction <= 1)) throw InvalidInput("patch inner_fraction must be in (0.05, 1]");
  if (!(clip_high > clip_low)) throw InvalidInput("patch clip_high must exceed clip_low");
  if (!(max_clipped_fraction >= 0 && max_clipped_fraction < 1)) throw InvalidInput("max_clipped_fraction must be in [0,1)");
  if (!(max_spread >= 0) || !(noise_floor >= 0) || !(max_gradient >= 0))
    throw InvalidInput("patch spread/gradient thresholds must be ≥ 0");
}

std::string PatchStats::rejection() const {
  if (clipped) return "clipped";
  if (non_uniform) return "non-uniform";
  return {};
}

std::vector<PatchStats> sampleRectified(const cv::Mat& chart_image, const PatchSamplingOptions& options) {
  options.check();
  const cv::Mat rgb = toUnitRgb(chart_image);
  const double pitch_x = double(rgb.cols) / kColumns, pitch_y = double(rgb.rows) / kRows;
  if (pitch_x < 4 || pitch_y < 4) throw InvalidInput("chart image too small to sample 6×4 patches");
  std::vector<PatchStats> result(kPatches);
  cv::parallel_for_(cv::Range(0, kPatches), [&](const cv::Range& range) {
    for (int p = range.start; p < range.end; ++p) {
      const int row = p / kColumns, column = p % kColumns;
      const double cx = (column + 0.5) * pitch_x, cy = (row + 0.5) * pitch_y;
      const int half_w = std::max(1, int(std::lround(0.5 * options.inner_fraction * pitch_x)));
      const int half_h = std::max(1, int(std::lround(0.5 * options.inner_fraction * pitch_y)));
      const int x0 = std::clamp(int(std::lround(cx)) - half_w, 0, rgb.cols - 1);
      const int x1 = std::clamp(int(std::lround(cx)) + half_w, x0 + 1, rgb.cols);
      const int y0 = std::clamp(int(std::lround(cy)) - half_h, 0, rgb.rows - 1);
      const int y1 = std::clamp(int(std::lround(cy)) + half_h, y0 + 1, rgb.rows);
      const int mx = (x0 + x1) / 2, my = (y0 + y1) / 2;
      PatchStats& stats = result[static_cast<size_t>(p)];
      stats.patch = p;
      std::array<std::vector<double>, 3> values;
      std::array<std::array<std::vector<double>, 4>, 3> quadrants;
      int high = 0, low = 0;
      for (int y = y0; y < y1; ++y) {
        const auto* row_ptr = rgb.ptr<cv::Vec3d>(y);
        for (int x = x0; x < x1; ++x) {
          const cv::Vec3d& v = row_ptr[x];
          bool is_high = false, is_low = false;
          const int q = (y >= my ? 2 : 0) + (x >= mx ? 1 : 0);
          for (int c = 0; c < 3; ++c) {
            values[static_cast<size_t>(c)].push_back(v[c]);
            quadrants[static_cast<size_t>(c)][static_cast<size_t>(q)].push_back(v[c]);
            is_high = is_high || v[c] >= options.clip_high;
            is_low = is_low || v[c] <= options.clip_low;
          }
          high += is_high;
          low += is_low;
        }
      }
      const int n = (x1 - x0) * (y1 - y0);
      stats.pixels = n;
      stats.clipped_fraction = double(high + low) / n;
      // Clipping at the top biases the median at once; at zero (dark noisy RAW) only when a large share is zero.
      stats.clipped_high = double(high) / n > options.max_clipped_fraction;
      stats.clipped = stats.clipped_high || double(low) / n > 0.25;
      for (size_t c = 0; c < 3; ++c) {
        std::vector<double>& v = values[c];
        const double m = median(v);
        for (double& e : v) e = std::abs(e - m);
        const double sigma = 1.4826 * median(v);
        stats.median[c] = m;
        stats.spread[c] = sigma;
        const double allowed = options.max_spread * m + options.noise_floor;
        if (sigma > allowed) stats.non_uniform = true;
        double qmin = 1e300, qmax = -1e300;
        for (auto& quadrant : quadrants[c]) {
          if (quadrant.empty()) continue;
          const double qm = median(quadrant);
          qmin = std::min(qmin, qm);
          qmax = std::max(qmax, qm);
        }
        if (qmax - qmin > options.max_gradient * m + options.noise_floor) stats.non_uniform = true;
      }
    }
  });
  return result;
}

ChartCorners fullImageCorners(cv::Size size) {
  const float w = float(size.width), h = float(size.height);
  return {cv::Point2f(0, 0), cv::Point2f(w, 0), cv::Point2f(w, h), cv::Point2f(0, h)};
}

cv::Mat rectify(const cv::Mat& image, const ChartCorners& corners, int pitch) {
  if (image.empty()) throw InvalidInput("chart image is empty");
  if (pitch < 4) throw InvalidInput("rectification pitch must be ≥ 4 px");
  const float w = float(kColumns * pitch), h = float(kRows * pitch);
  const std::array<cv::Point2f, 4> target{cv::Point2f(0, 0), cv::Point2f(w, 0), cv::Point2f(w, h), cv::Point2f(0, h)};
  const cv::Mat homography = cv::getPerspectiveTransform(corners.data(), target.data());
  cv::Mat out;
  cv::warpPerspective(image, out, homography, cv::Size(int(w), int(h)), cv::INTER_AREA, cv::BORDER_REPLICATE);
  return out;
}

namespace {

// mcc on `image` scaled by `factor`; the box corners in full-resolution coordinates.
std::optional<std::vector<cv::Point2f>> detectBox(const cv::Mat& image, double factor) {
  cv::Mat small = image;
  if (factor < 1) cv::resize(image, small, cv::Size(), factor, factor, cv::INTER_AREA);
  cv::Ptr<cv::mcc::CCheckerDetector> detector = cv::mcc::CCheckerDetector::create();
  if (!detector->process(small, cv::mcc::MCC24, 1)) return std::nullopt;
  cv::Ptr<cv::mcc::CChecker> checker = detector->getBestColorChecker();
  if (!checker) return std::nullopt;
  std::vector<cv::Point2f> box = checker->getBox();
  if (box.size() != 4) return std::nullopt;
  for (auto& p : box) p *= float(1 / factor);
  return box;
}

}  // namespace

std::optional<ChartCorners> detect(const cv::Mat& image) {
  if (image.empty() || image.depth() != CV_8U || image.channels() != 3)
    throw InvalidInput("chart detection needs an 8-bit BGR image");
  // mcc is slow on large photos (≈ 10 s at 2448×2048): detect on a copy at most 1280 px wide and scale back; only
  // when that finds nothing (a chart too small at that scale) try the full resolution.
  const double factor = std::min(1.0, 1280.0 / std::max(image.cols, image.rows));
  std::optional<std::vector<cv::Point2f>> box = detectBox(image, factor);
  if (!box && factor < 1) box = detectBox(image, 1.0);
  if (!box) return std::nullopt;
  // mcc's Classic model (opencv_contrib mcc/src/charts.cpp): box 16.75 × 11.25 units, 2.5-unit cells on a
  // 2.75 pitch starting at 0.25; box[0] is the corner at the first cell (dark skin). The patch grid as crfcal
  // defines it (pitch-sized cells centred on the patches) spans [0.125, 16.625] × [0.125, 11.125].
  const std::array<cv::Point2f, 4> model{cv::Point2f(0, 0), cv::Point2f(16.75f, 0), cv::Point2f(16.75f, 11.25f),
                                         cv::Point2f(0, 11.25f)};
  const std::array<cv::Point2f, 4> image_box{(*box)[0], (*box)[1], (*box)[2], (*box)[3]};
  const cv::Mat h = cv::getPerspectiveTransform(model.data(), image_box.data());
  std::vector<cv::Point2f> grid{cv::Point2f(0.125f, 0.125f), cv::Point2f(16.625f, 0.125f),
                                cv::Point2f(16.625f, 11.125f), cv::Point2f(0.125f, 11.125f)};
  std::vector<cv::Point2f> mapped;
  cv::perspectiveTransform(grid, mapped, h);
  return ChartCorners{mapped[0], mapped[1], mapped[2], mapped[3]};
}

}  // namespace crfcal::chart
