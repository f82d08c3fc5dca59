#include "crfcal/io/plot.hpp"

#include <algorithm>
#include <functional>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "crfcal/io/image_io.hpp"

namespace crfcal::io {

cv::Scalar seriesColor(int i) {
  static const cv::Scalar palette[] = {{180, 119, 31}, {14, 127, 255}, {44, 160, 44},  {40, 39, 214},
                                       {189, 103, 148}, {75, 86, 140}, {194, 119, 227}, {127, 127, 127},
                                       {34, 189, 188},  {207, 190, 23}};
  return palette[static_cast<size_t>(i) % std::size(palette)];
}

namespace {

std::string tickLabel(double v, double step) {
  if (std::abs(v) < 1e-9 * step) v = 0;  // no "-0" from accumulated rounding
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.3g", v);
  return buffer;
}

double niceStep(double range) {
  const double raw = range / 5;
  const double magnitude = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 2.5, 5.0, 10.0})
    if (m * magnitude >= raw) return m * magnitude;
  return 10 * magnitude;
}

// A dashed polyline: dashes of `on` pixels separated by `off`, measured along the curve (the points of a sampled
// curve are often less than a pixel apart, so alternating segments would look solid).
void dashedPolyline(cv::Mat& image, const std::vector<cv::Point2d>& points, const cv::Scalar& color, int thickness,
                    double on = 9, double off = 6) {
  double phase = 0;  // position within the current on+off period
  for (size_t i = 0; i + 1 < points.size(); ++i) {
    cv::Point2d a = points[i];
    const cv::Point2d b = points[i + 1];
    double length = cv::norm(b - a);
    while (length > 1e-9) {
      const bool drawing = phase < on;
      const double left = drawing ? on - phase : on + off - phase;
      const double step = std::min(left, length);
      const cv::Point2d c = a + (b - a) * (step / length);
      if (drawing) cv::line(image, cv::Point(cvRound(a.x), cvRound(a.y)), cv::Point(cvRound(c.x), cvRound(c.y)), color,
                            thickness, cv::LINE_AA);
      phase = std::fmod(phase + step, on + off);
      length -= step;
      a = c;
    }
  }
}

// The bands as translucent polygons (lower edge left to right, upper edge back); `at` maps (x, y) to the pixel.
void drawBands(cv::Mat& plot, const std::vector<PlotBand>& bands,
               const std::function<cv::Point(double, double)>& at) {
  for (const auto& b : bands) {
    std::vector<cv::Point> polygon;
    const size_t n = std::min({b.x.size(), b.lower.size(), b.upper.size()});
    for (size_t i = 0; i < n; ++i) polygon.push_back(at(b.x[i], b.lower[i]));
    for (size_t i = n; i-- > 0;) polygon.push_back(at(b.x[i], b.upper[i]));
    if (polygon.size() < 3) continue;
    cv::Mat layer = plot.clone();
    cv::fillPoly(layer, std::vector<std::vector<cv::Point>>{polygon}, b.color, cv::LINE_AA);
    cv::addWeighted(layer, b.opacity, plot, 1 - b.opacity, 0, plot);
  }
}

// One legend line per labelled band (a swatch of its colour); returns the next line's baseline.
int drawBandLegend(cv::Mat& canvas, const std::vector<PlotBand>& bands, int left, int legend_y) {
  for (const auto& b : bands) {
    if (b.label.empty()) continue;
    cv::Mat swatch = canvas(cv::Rect(left + 12, legend_y - 11, 28, 12));
    cv::addWeighted(swatch, 1 - std::max(b.opacity, 0.35), cv::Mat(swatch.size(), swatch.type(), b.color),
                    std::max(b.opacity, 0.35), 0, swatch);
    cv::putText(canvas, b.label, {left + 48, legend_y}, cv::FONT_HERSHEY_SIMPLEX, 0.45, cv::Scalar(0, 0, 0), 1,
                cv::LINE_AA);
    legend_y += 20;
  }
  return legend_y;
}

}  // namespace

cv::Mat renderPlot(const std::vector<PlotSeries>& series, const PlotOptions& options) {
  double x0 = options.x_min, x1 = options.x_max, y0 = options.y_min, y1 = options.y_max;
  auto extend = [](double& lo, double& hi, const std::vector<double>& values, bool fixed_lo, bool fixed_hi) {
    for (double v : values) {
      if (!std::isfinite(v)) continue;
      if (!fixed_lo) lo = std::isnan(lo) ? v : std::min(lo, v);
      if (!fixed_hi) hi = std::isnan(hi) ? v : std::max(hi, v);
    }
  };
  const bool fx0 = !std::isnan(x0), fx1 = !std::isnan(x1), fy0 = !std::isnan(y0), fy1 = !std::isnan(y1);
  for (const auto& s : series) {
    extend(x0, x1, s.x, fx0, fx1);
    extend(y0, y1, s.y, fy0, fy1);
  }
  if (std::isnan(x0) || std::isnan(x1)) x0 = 0, x1 = 1;
  if (std::isnan(y0) || std::isnan(y1)) y0 = 0, y1 = 1;
  if (x1 <= x0) x1 = x0 + 1;
  if (y1 <= y0) y1 = y0 + 1;
  if (!fy0 || !fy1) {  // breathing room
    const double pad = 0.05 * (y1 - y0);
    if (!fy0) y0 -= pad;
    if (!fy1) y1 += pad;
  }

  cv::Mat canvas(options.size, CV_8UC3, cv::Scalar(255, 255, 255));
  const int ranges = static_cast<int>(options.x_ranges.size());
  const int left = 80, right = 20, top = options.title.empty() ? 30 : 58, bottom = 60 + (ranges ? 8 + 12 * ranges : 0);
  const cv::Rect area(left, top, canvas.cols - left - right, canvas.rows - top - bottom);
  auto px = [&](double x) { return area.x + (x - x0) / (x1 - x0) * area.width; };
  auto py = [&](double y) { return area.y + area.height - (y - y0) / (y1 - y0) * area.height; };
  const int font = cv::FONT_HERSHEY_SIMPLEX;
  const cv::Scalar black(0, 0, 0), grid(225, 225, 225);

  for (double step = niceStep(x1 - x0), t = std::ceil(x0 / step) * step; t <= x1 + 1e-9 * step; t += step) {
    const int x = static_cast<int>(std::lround(px(t)));
    cv::line(canvas, {x, area.y}, {x, area.y + area.height}, grid, 1);
    cv::putText(canvas, tickLabel(t, x1 - x0), {x - 15, area.y + area.height + 20}, font, 0.45, black, 1, cv::LINE_AA);
  }
  for (double step = niceStep(y1 - y0), t = std::ceil(y0 / step) * step; t <= y1 + 1e-9 * step; t += step) {
    const int y = static_cast<int>(std::lround(py(t)));
    cv::line(canvas, {area.x, y}, {area.x + area.width, y}, grid, 1);
    cv::putText(canvas, tickLabel(t, y1 - y0), {8, y + 5}, font, 0.45, black, 1, cv::LINE_AA);
  }
  cv::rectangle(canvas, area, black, 1);
  cv::putText(canvas, options.x_label, {area.x + area.width / 2 - 30, canvas.rows - 15}, font, 0.55, black, 1, cv::LINE_AA);
  cv::putText(canvas, options.y_label, {8, top - 16}, font, 0.5, black, 1, cv::LINE_AA);
  if (!options.title.empty()) {
    // A long title (a camera's name, a file) starts further left and then shrinks until it fits the picture.
    double scale = 0.65;
    int baseline = 0, x = left;
    const int width = cv::getTextSize(options.title, font, scale, 1, &baseline).width;
    if (x + width > canvas.cols - 8) x = 8;
    if (x + width > canvas.cols - 8) scale *= double(canvas.cols - 16) / width;
    cv::putText(canvas, options.title, {x, 28}, font, scale, black, 1, cv::LINE_AA);
  }

  cv::Mat plot = canvas(area);
  const cv::Point offset(area.x, area.y);
  drawBands(plot, options.bands, [&](double x, double y) {
    return cv::Point(cvRound(px(x) - offset.x), cvRound(py(y) - offset.y));
  });
  for (const auto& s : series) {
    std::vector<cv::Point2d> points;
    for (size_t i = 0; i < std::min(s.x.size(), s.y.size()); ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      points.emplace_back(px(s.x[i]) - offset.x, py(s.y[i]) - offset.y);
    }
    if (s.markers) {
      for (const auto& p : points)
        cv::circle(plot, cv::Point(cvRound(p.x), cvRound(p.y)), s.thickness + 1, s.color, cv::FILLED, cv::LINE_AA);
    } else if (s.dashed) {
      dashedPolyline(plot, points, s.color, s.thickness);
    } else if (points.size() > 1) {
      std::vector<cv::Point> polyline;
      for (const auto& p : points) polyline.emplace_back(cvRound(p.x), cvRound(p.y));
      cv::polylines(plot, polyline, false, s.color, s.thickness, cv::LINE_AA);
    }
  }
  for (size_t i = 0; i < options.x_ranges.size(); ++i) {
    const PlotRange& r = options.x_ranges[i];
    const int y = area.y + area.height + 34 + 12 * static_cast<int>(i);  // under the tick labels
    const int a = static_cast<int>(std::lround(px(std::max(r.lo, x0)))), b = static_cast<int>(std::lround(px(std::min(r.hi, x1))));
    cv::line(canvas, {a, y}, {b, y}, r.color, 5);
    for (int end : {a, b}) cv::line(canvas, {end, y - 6}, {end, y + 6}, r.color, 2);
  }
  int legend_y = area.y + 20;
  for (const auto& s : series) {
    if (s.label.empty()) continue;
    if (s.markers)
      cv::circle(canvas, {area.x + 26, legend_y - 5}, s.thickness + 1, s.color, cv::FILLED, cv::LINE_AA);
    else if (s.dashed)
      dashedPolyline(canvas, {{area.x + 12.0, legend_y - 5.0}, {area.x + 42.0, legend_y - 5.0}}, s.color,
                     std::max(2, s.thickness), 8, 5);
    else
      cv::line(canvas, {area.x + 12, legend_y - 5}, {area.x + 40, legend_y - 5}, s.color, s.thickness >= 2 ? 3 : 1,
               cv::LINE_AA);
    cv::putText(canvas, s.label, {area.x + 48, legend_y}, font, 0.45, black, 1, cv::LINE_AA);
    legend_y += 20;
  }
  legend_y = drawBandLegend(canvas, options.bands, area.x, legend_y);
  for (const auto& r : options.x_ranges) {
    if (r.label.empty()) continue;
    cv::line(canvas, {area.x + 12, legend_y - 5}, {area.x + 40, legend_y - 5}, r.color, 5);
    for (int end : {area.x + 12, area.x + 40}) cv::line(canvas, {end, legend_y - 11}, {end, legend_y + 1}, r.color, 2);
    cv::putText(canvas, r.label, {area.x + 48, legend_y}, font, 0.45, black, 1, cv::LINE_AA);
    legend_y += 20;
  }
  return canvas;
}

void writePlot(const std::filesystem::path& path, const std::vector<PlotSeries>& series, const PlotOptions& options) {
  writeImage(path, renderPlot(series, options));
}

}  // namespace crfcal::io
