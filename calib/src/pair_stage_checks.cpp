// Stage "checks" of calibratePair: the pair's shapes, then saturated frames and an edgeless sharp shot — each
// refused with the reason before the registration would call it a non-overlapping pair.
#include <algorithm>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "image_units.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

const cv::Mat& channelPlane(const std::vector<cv::Mat>& planes, const std::string& name) {
  if (planes.size() == 1) return planes[0];
  return planes[name == "B" ? 0 : name == "G" ? 1 : 2];
}

bool checkPairShapes(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options) {
  if (sharp.empty() || blurred.empty()) throw InvalidInput("empty image", ErrorSubject::pair);
  const bool transposed = sharp.size() != blurred.size() && sharp.size() == cv::Size(blurred.rows, blurred.cols);
  if (transposed && !options.register_pair)
    throw InvalidInput("the images differ in orientation (portrait vs landscape): registration is needed",
                       ErrorSubject::pair);
  if (sharp.size() != blurred.size() && !transposed)
    throw InvalidInput("the images differ in size (" + std::to_string(sharp.cols) + "x" + std::to_string(sharp.rows) +
                           " vs " + std::to_string(blurred.cols) + "x" + std::to_string(blurred.rows) + ")",
                       ErrorSubject::pair);
  if (sharp.type() != blurred.type())
    throw InvalidInput("the images differ in bit depth or channel count", ErrorSubject::pair);
  if (sharp.depth() != CV_8U && sharp.depth() != CV_16U)
    throw InvalidInput("8- or 16-bit images expected", ErrorSubject::pair);
  return transposed;
}

void splitPlanes(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  const bool colour = state.sharp.channels() == 3;
  state.result.channels = colour && options.rgb ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"G"};
  cv::split(state.sharp, state.sharp_planes);  // BGR order
  cv::split(state.blurred, state.blurred_planes);
  state.sharp_g8 = channelPlane(state.sharp_planes, "G");
  state.blurred_own_g8 = channelPlane(state.blurred_planes, "G");
  const double top = fullScale(state.sharp);
  state.clip_high = options.fit.saturation_high * top;
  state.clip_low = options.fit.saturation_low * top;
}

namespace {

// More than `saturated_frame_limit` of either G plane at the clip level: nothing left to fit.
void checkSaturation(const PairCalibrationState& state) {
  const std::pair<const char*, const cv::Mat*> images[] = {{"blurred", &state.blurred_own_g8},
                                                           {"sharp", &state.sharp_g8}};
  for (const auto& [name, image] : images) {
    const double f = cv::countNonZero(*image >= state.clip_high) / static_cast<double>(image->total());
    if (f > state.options.saturated_frame_limit) {
      char buffer[200];
      std::snprintf(buffer, sizeof buffer, "saturated frame: %.0f%% of the %s image is clipped (over-exposed)", 100 * f,
                    name);
      throw InvalidInput(buffer, image == &state.sharp_g8 ? ErrorSubject::sharp_image : ErrorSubject::blurred_image);
    }
  }
}

// No edges at all (a flat frame). An edge pixel: a step between neighbours (on a noise-smoothed ≤ 1024 px copy)
// of more than 5 % of the image's own range (1st–99th percentile; a dark, underexposed frame still has edges) and
// more than 1.5 levels of 8 bits.
void checkEdges(const PairCalibrationState& state) {
  cv::Mat small = unit(state.sharp_g8);
  const double s = std::min(1.0, 1024.0 / std::max(small.cols, small.rows));
  if (s < 1) cv::resize(small, small, cv::Size(), s, s, cv::INTER_AREA);
  cv::GaussianBlur(small, small, cv::Size(3, 3), 0);
  std::vector<double> values(small.begin<double>(), small.end<double>());
  std::sort(values.begin(), values.end());
  const double range = values[values.size() * 99 / 100] - values[values.size() / 100];
  cv::Mat gx, gy, magnitude;
  cv::Sobel(small, gx, CV_64F, 1, 0, 3, 1.0 / 8);
  cv::Sobel(small, gy, CV_64F, 0, 1, 3, 1.0 / 8);
  cv::magnitude(gx, gy, magnitude);
  const double step = std::max(0.05 * range, 1.5 / 255.0);
  if (cv::countNonZero(magnitude > step) < 0.001 * magnitude.total())
    throw InvalidInput("no edges: the sharp image is nearly uniform (nothing to measure the blur or the response on)",
                       ErrorSubject::sharp_image);
}

}  // namespace

void checkExposureAndEdges(const PairCalibrationState& state) {
  checkSaturation(state);
  checkEdges(state);
}

}  // namespace crfcal::detail
