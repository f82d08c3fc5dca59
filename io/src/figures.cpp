#include "crfcal/io/figures.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "crfcal/io/image_io.hpp"

namespace crfcal::io {
namespace {

const int kFont = cv::FONT_HERSHEY_SIMPLEX;
const cv::Scalar kBlack(0, 0, 0), kNoData(150, 150, 150);
constexpr double kTitleScale = 0.6, kTextScale = 0.45;
constexpr int kMargin = 12;

std::string number(const char* format, double v) {
  char buffer[48];
  std::snprintf(buffer, sizeof buffer, format, v);
  return buffer;
}

std::string offsetLabel(int d) { return d > 0 ? "+" + std::to_string(d) : std::to_string(d); }

int textWidth(const std::string& s, double scale) {
  int baseline = 0;
  return cv::getTextSize(s, kFont, scale, 1, &baseline).width;
}

// Greedy word wrap to `width` pixels.
std::vector<std::string> wrap(const std::string& text, double scale, int width) {
  std::vector<std::string> lines;
  std::string line, word;
  auto flush = [&] {
    if (!line.empty()) lines.push_back(line);
    line.clear();
  };
  for (size_t i = 0; i <= text.size(); ++i) {
    if (i < text.size() && text[i] != ' ') {
      word += text[i];
      continue;
    }
    if (word.empty()) continue;
    const std::string candidate = line.empty() ? word : line + " " + word;
    if (!line.empty() && textWidth(candidate, scale) > width) {
      flush();
      line = word;
    } else {
      line = candidate;
    }
    word.clear();
  }
  flush();
  return lines;
}

// The picture: `body` at the left under the title and notes, `side` (legend / colour bar) at its right.
cv::Mat compose(const cv::Mat& body, const cv::Mat& side, const FigureText& text) {
  const int width = std::max(body.cols + side.cols + 3 * kMargin, 560);
  std::vector<std::pair<std::string, double>> lines;
  for (const auto& l : wrap(text.title, kTitleScale, width - 2 * kMargin)) lines.emplace_back(l, kTitleScale);
  for (const auto& note : text.notes)
    for (const auto& l : wrap(note, kTextScale, width - 2 * kMargin)) lines.emplace_back(l, kTextScale);
  int header = kMargin;
  for (const auto& [_, scale] : lines) header += scale == kTitleScale ? 26 : 19;
  const int height = header + kMargin + std::max(body.rows, side.rows) + kMargin;
  cv::Mat canvas(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  int y = kMargin;
  for (const auto& [line, scale] : lines) {
    y += scale == kTitleScale ? 26 : 19;
    cv::putText(canvas, line, {kMargin, y - 6}, kFont, scale, kBlack, scale == kTitleScale ? 2 : 1, cv::LINE_AA);
  }
  body.copyTo(canvas(cv::Rect(kMargin, header + kMargin, body.cols, body.rows)));
  side.copyTo(canvas(cv::Rect(kMargin * 2 + body.cols, header + kMargin, side.cols, side.rows)));
  return canvas;
}

// Display scale of a map: small maps enlarged (nearest) to ≥ 480 px, large ones reduced to ≤ 1000 px.
double displayScale(cv::Size size) {
  const int side = std::max(size.width, size.height);
  if (side < 480) return std::ceil(480.0 / side);
  if (side > 1000) return 1000.0 / side;
  return 1;
}

// A vertical colour bar for the colour map `lut` (256×1 BGR, index 0 at the bottom), ticks at `ticks` (values
// between lo and hi), a caption above.
cv::Mat colourBar(const cv::Mat& lut, double lo, double hi, const std::vector<double>& ticks,
                  const std::vector<std::string>& labels, const std::vector<std::string>& caption, int height) {
  const int bar_w = 22, top = 8 + 18 * static_cast<int>(caption.size()), bar_h = std::max(200, height - top - 10);
  cv::Mat side(top + bar_h + 10, 200, CV_8UC3, cv::Scalar(255, 255, 255));
  for (size_t i = 0; i < caption.size(); ++i)
    cv::putText(side, caption[i], {0, 18 + 18 * static_cast<int>(i) - 4}, kFont, kTextScale, kBlack, 1, cv::LINE_AA);
  for (int y = 0; y < bar_h; ++y) {
    const int index = static_cast<int>(std::lround(255.0 * (bar_h - 1 - y) / (bar_h - 1)));
    cv::line(side, {0, top + y}, {bar_w - 1, top + y}, cv::Scalar(lut.at<cv::Vec3b>(index)), 1);
  }
  cv::rectangle(side, cv::Rect(0, top, bar_w, bar_h), kBlack, 1);
  for (size_t i = 0; i < ticks.size(); ++i) {
    const int y = top + static_cast<int>(std::lround((hi - ticks[i]) / (hi - lo) * (bar_h - 1)));
    cv::line(side, {bar_w, y}, {bar_w + 5, y}, kBlack, 1);
    cv::putText(side, labels[i], {bar_w + 8, y + 5}, kFont, kTextScale, kBlack, 1, cv::LINE_AA);
  }
  return side;
}

// Diverging blue–white–red (ColorBrewer RdBu, reversed), 256 entries, BGR.
cv::Mat divergingLut() {
  static const std::array<cv::Vec3d, 11> rgb = {{{5, 48, 97},     {33, 102, 172}, {67, 147, 195}, {146, 197, 222},
                                                 {209, 229, 240}, {247, 247, 247}, {253, 219, 199}, {244, 165, 130},
                                                 {214, 96, 77},   {178, 24, 43},   {103, 0, 31}}};
  cv::Mat lut(256, 1, CV_8UC3);
  for (int i = 0; i < 256; ++i) {
    const double t = i / 255.0 * 10;
    const int k = std::min(9, static_cast<int>(t));
    const cv::Vec3d c = rgb[k] + (rgb[k + 1] - rgb[k]) * (t - k);
    lut.at<cv::Vec3b>(i) = cv::Vec3b(cv::saturate_cast<uchar>(c[2]), cv::saturate_cast<uchar>(c[1]),
                                     cv::saturate_cast<uchar>(c[0]));
  }
  return lut;
}

cv::Mat builtinLut(int colormap) {
  cv::Mat ramp(256, 1, CV_8U), lut;
  for (int i = 0; i < 256; ++i) ramp.at<uchar>(i) = static_cast<uchar>(i);
  cv::applyColorMap(ramp, lut, colormap);
  return lut;
}

// A legend entry: a swatch and its text (wrapped to the legend's width).
int legendEntry(cv::Mat& side, int y, const cv::Scalar& colour, const std::string& text) {
  cv::rectangle(side, cv::Rect(0, y, 18, 18), colour, cv::FILLED);
  cv::rectangle(side, cv::Rect(0, y, 18, 18), kBlack, 1);
  for (const auto& line : wrap(text, kTextScale, side.cols - 26)) {
    cv::putText(side, line, {26, y + 14}, kFont, kTextScale, kBlack, 1, cv::LINE_AA);
    y += 18;
  }
  return y + 12;
}

double percentileOf(std::vector<double> values, double p) {
  if (values.empty()) return 0;
  const size_t k = std::min(values.size() - 1, static_cast<size_t>(p / 100 * (values.size() - 1) + 0.5));
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(k), values.end());
  return values[k];
}

}  // namespace

void writeSignedMapFigure(const std::filesystem::path& path, const cv::Mat& map, const FigureText& text,
                          const std::vector<std::string>& units, double percentile) {
  cv::Mat m;
  map.convertTo(m, CV_64F);
  std::vector<double> magnitudes, values;
  for (auto it = m.begin<double>(); it != m.end<double>(); ++it)
    if (*it != 0 && std::isfinite(*it)) {
      magnitudes.push_back(std::abs(*it));
      values.push_back(*it);
    }
  const double limit = std::max(percentileOf(magnitudes, percentile), 1e-12);
  const double median = percentileOf(values, 50);
  const double positive = values.empty() ? 0
                                         : 100.0 * std::count_if(values.begin(), values.end(), [](double v) {
                                             return v > 0;
                                           }) / values.size();
  const double scale = displayScale(m.size());
  cv::Mat shown, index, coloured;
  cv::resize(m, shown, cv::Size(), scale, scale, scale >= 1 ? cv::INTER_NEAREST : cv::INTER_AREA);
  shown.convertTo(index, CV_8U, 127.5 / limit, 127.5);  // −limit → 0, 0 → 128, +limit → 255 (saturating)
  const cv::Mat lut = divergingLut();
  cv::applyColorMap(index, coloured, lut);
  coloured.setTo(kNoData, shown == 0);

  FigureText full = text;
  full.notes.push_back("colour scale: +/- " + number("%.3g", limit) + " = the " + number("%g", percentile) +
                       "th percentile of |value| (larger values saturate); grey: no data (0)");
  full.notes.push_back("median " + number("%+.3g", median) + "; " + number("%.0f", positive) + " % of pixels > 0");
  const std::vector<double> ticks{-limit, -limit / 2, 0, limit / 2, limit};
  std::vector<std::string> labels;
  for (double t : ticks) labels.push_back(t == 0 ? "0" : number("%+.3g", t));
  labels.front() = "<=" + labels.front();
  labels.back() = ">=" + labels.back();
  const cv::Mat side = colourBar(lut, -limit, limit, ticks, labels, units, coloured.rows);
  writeImage(path, compose(coloured, side, full));
}

void writeKernelFigure(const std::filesystem::path& path, const cv::Mat& kernel, const FigureText& text) {
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  double peak = 0;
  cv::minMaxLoc(k, nullptr, &peak);
  const int scale = std::max(1, static_cast<int>(std::ceil(300.0 / std::max(k.cols, k.rows))));
  cv::Mat index, coloured;
  k.convertTo(index, CV_8U, peak > 0 ? 255.0 / peak : 0);
  cv::resize(index, index, cv::Size(), scale, scale, cv::INTER_NEAREST);
  const cv::Mat lut = builtinLut(cv::COLORMAP_INFERNO);
  cv::applyColorMap(index, coloured, lut);

  // Ticks in pixels from the centre (the kernel's origin), on a frame around the enlarged kernel.
  const int pad_left = 44, pad_bottom = 40, pad_top = 8;
  cv::Mat body(coloured.rows + pad_top + pad_bottom, coloured.cols + pad_left + 10, CV_8UC3, cv::Scalar(255, 255, 255));
  const cv::Rect area(pad_left, pad_top, coloured.cols, coloured.rows);
  coloured.copyTo(body(area));
  cv::rectangle(body, area, kBlack, 1);
  const int cx = k.cols / 2, cy = k.rows / 2, extent = std::max(cx, cy);
  const int step = extent <= 6 ? 1 : extent <= 12 ? 2 : extent <= 30 ? 5 : 10;
  for (int d = -(extent / step) * step; d <= extent; d += step) {
    if (cx + d >= 0 && cx + d < k.cols) {
      const int x = area.x + (cx + d) * scale + scale / 2;
      cv::line(body, {x, area.br().y}, {x, area.br().y + 5}, kBlack, 1);
      const std::string label = offsetLabel(d);
      cv::putText(body, label, {x - textWidth(label, 0.4) / 2, area.br().y + 18}, kFont, 0.4, kBlack, 1, cv::LINE_AA);
    }
    if (cy + d >= 0 && cy + d < k.rows) {
      const int y = area.y + (cy + d) * scale + scale / 2;
      cv::line(body, {area.x - 5, y}, {area.x, y}, kBlack, 1);
      const std::string label = offsetLabel(d);
      cv::putText(body, label, {area.x - 8 - textWidth(label, 0.4), y + 4}, kFont, 0.4, kBlack, 1, cv::LINE_AA);
    }
  }
  cv::putText(body, "pixels from the centre", {area.x, area.br().y + 34}, kFont, kTextScale, kBlack, 1, cv::LINE_AA);

  FigureText full = text;
  full.title += " (" + std::to_string(k.cols) + " x " + std::to_string(k.rows) + " px, shown " +
                std::to_string(scale) + "x)";
  full.notes.push_back("a picture, not data: the exact kernel is kernel.txt (use that with --kernel)");
  const std::vector<double> ticks{0, 0.25, 0.5, 0.75, 1};
  const std::vector<std::string> labels{"0", "0.25", "0.5", "0.75", "1 = " + number("%.3g", peak)};
  const cv::Mat side = colourBar(lut, 0, 1, ticks, labels, {"weight / peak", "(weights sum to 1)"}, body.rows);
  writeImage(path, compose(body, side, full));
}

void writeMaskFigure(const std::filesystem::path& path, const cv::Mat& mask, const cv::Mat& image,
                     const FigureText& text, const std::string& in_mask, const std::string& not_in_mask) {
  // Grey backdrop stretched to its 1st–99th percentile (the sharp shot is dark), dimmed.
  cv::Mat grey(mask.size(), CV_64F, cv::Scalar(0));
  if (!image.empty() && image.size() == mask.size()) {
    cv::Mat g = image;
    if (image.channels() == 3) cv::cvtColor(image, g, cv::COLOR_BGR2GRAY);
    if (image.channels() == 4) cv::cvtColor(image, g, cv::COLOR_BGRA2GRAY);
    g.convertTo(grey, CV_64F);
    std::vector<double> values(grey.begin<double>(), grey.end<double>());
    const double lo = percentileOf(values, 1), hi = percentileOf(values, 99);
    grey = (grey - lo) / std::max(hi - lo, 1e-12);
    cv::max(cv::min(grey, 1.0), 0.0, grey);
  }
  const double scale = displayScale(mask.size());
  const int interpolation = scale >= 1 ? cv::INTER_NEAREST : cv::INTER_AREA;
  cv::Mat used, backdrop;
  mask.convertTo(used, CV_64F, 1.0 / 255);
  cv::resize(used, used, cv::Size(), scale, scale, interpolation);
  cv::resize(grey, backdrop, cv::Size(), scale, scale, interpolation);
  const cv::Vec3d highlight(40, 220, 255);  // BGR: yellow
  const double dim = 0.35;
  cv::Mat out(used.size(), CV_8UC3);
  for (int y = 0; y < out.rows; ++y)
    for (int x = 0; x < out.cols; ++x) {
      const double a = used.at<double>(y, x), g = dim * 255 * backdrop.at<double>(y, x);
      const cv::Vec3d c = cv::Vec3d(g, g, g) * (1 - 0.75 * a) + highlight * (0.75 * a);
      out.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]),
                                          cv::saturate_cast<uchar>(c[2]));
    }
  cv::Mat side(std::max(out.rows, 160), 220, CV_8UC3, cv::Scalar(255, 255, 255));
  int y = legendEntry(side, 0, cv::Scalar(highlight * 0.75 + cv::Vec3d(30, 30, 30) * 0.25), in_mask);
  legendEntry(side, y, cv::Scalar(45, 45, 45), not_in_mask);
  writeImage(path, compose(out, side, text));
}

}  // namespace crfcal::io
