#include "crfcal/chroma_subsampling.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"

namespace crfcal {
namespace {

// JFIF chroma weights on (B, G, R) and the channel's coefficients on Cb and Cr in its reconstruction from YCbCr.
const cv::Matx13f kCb(0.5f, -0.331264f, -0.168736f), kCr(-0.081312f, -0.418688f, 0.5f);

std::pair<float, float> reconstructionCoefficients(const std::string& channel) {
  if (channel == "R") return {0.0f, 1.402f};
  if (channel == "B") return {1.772f, 0.0f};
  if (channel == "G") return {0.344136f, 0.714136f};
  throw InvalidInput("chroma error bound: unknown channel '" + channel + "' (R, G or B)");
}

// The range of a block plane over (2·reach + 1)² blocks.
cv::Mat localRange(const cv::Mat& plane, int reach) {
  const cv::Mat window = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * reach + 1, 2 * reach + 1));
  cv::Mat hi, lo;
  cv::dilate(plane, hi, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
  cv::erode(plane, lo, window, cv::Point(-1, -1), 1, cv::BORDER_REPLICATE);
  return hi - lo;
}

float median(const cv::Mat& plane) {
  std::vector<float> values(plane.begin<float>(), plane.end<float>());
  std::nth_element(values.begin(), values.begin() + values.size() / 2, values.end());
  return values[values.size() / 2];
}

}  // namespace

std::string ChromaSubsampling::name() const {
  if (h == 1 && v == 1) return "4:4:4";
  if (h == 2 && v == 2) return "4:2:0";
  if (h == 2 && v == 1) return "4:2:2";
  if (h == 1 && v == 2) return "4:4:0";
  return std::to_string(h) + "x" + std::to_string(v);
}

void ChromaDetailOptions::check() const {
  if (reach_blocks < 1 || reach_blocks > 8) throw InvalidInput("chroma detail reach must be 1..8 blocks");
}

cv::Mat chromaErrorBound(const cv::Mat& bgr, ChromaSubsampling sampling, const std::string& channel,
                         const ChromaDetailOptions& options) {
  options.check();
  if (bgr.channels() != 3) throw InvalidInput("chroma error bound needs a colour image", ErrorSubject::sharp_image);
  if (sampling.h < 1 || sampling.v < 1) throw InvalidInput("chroma sampling factors must be at least 1");
  const auto [coefficient_cb, coefficient_cr] = reconstructionCoefficients(channel);
  cv::Mat bound = cv::Mat::zeros(bgr.size(), CV_32F);
  if (!sampling.subsampled()) return bound;
  cv::Mat unit;
  bgr.convertTo(unit, CV_32F, bgr.depth() == CV_16U ? 1.0 / 65535 : 1.0 / 255);
  // The stored planes: block averages of the image padded by replication to whole blocks, as libjpeg does.
  const int pw = (bgr.cols + sampling.h - 1) / sampling.h * sampling.h;
  const int ph = (bgr.rows + sampling.v - 1) / sampling.v * sampling.v;
  cv::Mat padded;
  cv::copyMakeBorder(unit, padded, 0, ph - bgr.rows, 0, pw - bgr.cols, cv::BORDER_REPLICATE);
  const cv::Size blocks(pw / sampling.h, ph / sampling.v);
  cv::Mat range = cv::Mat::zeros(blocks, CV_32F);
  for (const auto& [weights, coefficient] : {std::make_pair(kCb, coefficient_cb), std::make_pair(kCr, coefficient_cr)}) {
    if (coefficient == 0) continue;
    cv::Mat plane, stored;
    cv::transform(padded, plane, weights);
    cv::resize(plane, stored, blocks, 0, 0, cv::INTER_AREA);  // integer factors: the exact block average
    range += coefficient * localRange(stored, options.reach_blocks);
  }
  range = cv::max(range - median(range), 0.0f);
  cv::Mat full;
  cv::resize(range, full, cv::Size(pw, ph), 0, 0, cv::INTER_NEAREST);
  full(cv::Rect(0, 0, bgr.cols, bgr.rows)).copyTo(bound);
  return bound;
}

cv::Mat excludedByErrorBound(const cv::Mat& weighted_bound, const cv::Mat& level, const cv::Mat& candidates,
                             double max_error, const LevelFloor& floor) {
  if (weighted_bound.type() != CV_64F || level.type() != CV_64F || candidates.type() != CV_8U ||
      level.size() != weighted_bound.size() || candidates.size() != weighted_bound.size())
    throw InvalidInput("error bound exclusion: bound and level CV_64F, candidates CV_8U, all of one size");
  floor.check();
  const int bins = floor.bins;
  const auto binOf = [&](int y, int x) { return std::clamp(static_cast<int>(level.at<double>(y, x) * bins), 0, bins - 1); };
  std::vector<std::vector<double>> bounds(bins);
  for (int y = 0; y < level.rows; ++y)
    for (int x = 0; x < level.cols; ++x)
      if (candidates.at<std::uint8_t>(y, x)) bounds[binOf(y, x)].push_back(weighted_bound.at<double>(y, x));
  std::vector<double> threshold(bins, max_error);
  for (int b = 0; b < bins; ++b) {
    std::vector<double>& v = bounds[b];
    const auto kept = std::count_if(v.begin(), v.end(), [&](double e) { return e <= max_error; });
    const auto keep = static_cast<std::size_t>(std::ceil(floor.refilled_fraction * v.size()));
    if (v.empty() || kept >= floor.emptied_fraction * v.size() || keep == 0) continue;
    std::nth_element(v.begin(), v.begin() + (keep - 1), v.end());
    threshold[b] = std::max(max_error, v[keep - 1]);
  }
  cv::Mat excluded = cv::Mat::zeros(level.size(), CV_8U);
  for (int y = 0; y < level.rows; ++y)
    for (int x = 0; x < level.cols; ++x)
      if (candidates.at<std::uint8_t>(y, x) && weighted_bound.at<double>(y, x) > threshold[binOf(y, x)])
        excluded.at<std::uint8_t>(y, x) = 255;
  return excluded;
}

void ChromaModelChoice::check() const {
  if (!(min_relative_scale > 0 && min_relative_scale < 10))
    throw InvalidInput("chroma model choice: min_relative_scale must be in (0, 10)");
}

double relativeCurveScale(const std::vector<double>& modelled, std::pair<int, int> covered_modelled,
                          const std::vector<double>& pointwise, std::pair<int, int> covered_pointwise) {
  if (modelled.empty() || modelled.size() != pointwise.size())
    throw InvalidInput("relative curve scale: both curves need the same, non-zero number of samples");
  const int last = static_cast<int>(modelled.size()) - 1;
  const int lo = std::clamp(std::max(covered_modelled.first, covered_pointwise.first), 0, last);
  const int hi = std::clamp(std::min(covered_modelled.second, covered_pointwise.second), 0, last);
  double cross = 0, square = 0;
  for (int i = lo; i <= hi; ++i) {
    cross += modelled[i] * pointwise[i];
    square += pointwise[i] * pointwise[i];
  }
  if (hi < lo || !(square > 0)) throw InvalidInput("relative curve scale: the curves cover no common non-zero range");
  return cross / square;
}

void LevelFloor::check() const {
  if (bins < 1 || bins > 1024 || !(emptied_fraction >= 0 && emptied_fraction <= 1) ||
      !(refilled_fraction >= 0 && refilled_fraction <= 1))
    throw InvalidInput("error bound level floor: bins 1..1024, fractions in [0, 1]");
}

}  // namespace crfcal
