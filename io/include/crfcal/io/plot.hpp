#pragma once
// Line plots rendered with OpenCV's drawing functions (curve plots, Γ profiles, benchmark figures).
#include <cmath>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal::io {

struct PlotSeries {
  std::vector<double> x;
  std::vector<double> y;
  cv::Scalar color{200, 80, 0};  // BGR
  std::string label;
  int thickness = 2;
  bool markers = false;  // draw points instead of a polyline
  bool dashed = false;
};

// An interval of x (e.g. the intensities a channel's data cover): a bar along the bottom of the plot, in the legend.
struct PlotRange {
  double lo = 0, hi = 1;
  cv::Scalar color{0, 0, 0};  // BGR
  std::string label;
};

// A shaded region between two curves sampled at the same x (e.g. a pointwise band of φ), drawn translucent under
// the series, with a swatch in the legend when labelled.
struct PlotBand {
  std::vector<double> x, lower, upper;
  cv::Scalar color{0, 0, 0};  // BGR
  std::string label;
  double opacity = 0.18;
};

struct PlotOptions {
  std::string title;
  std::string x_label = "x";
  std::string y_label = "y";
  double x_min = std::numeric_limits<double>::quiet_NaN();  // NaN: from the data
  double x_max = std::numeric_limits<double>::quiet_NaN();
  double y_min = std::numeric_limits<double>::quiet_NaN();
  double y_max = std::numeric_limits<double>::quiet_NaN();
  cv::Size size{720, 540};
  std::vector<PlotRange> x_ranges;  // drawn as bars stacked from the bottom of the plot area
  std::vector<PlotBand> bands;      // shaded under the series
};

// A distinct colour for series i (a small qualitative palette).
cv::Scalar seriesColor(int i);

cv::Mat renderPlot(const std::vector<PlotSeries>& series, const PlotOptions& options);
void writePlot(const std::filesystem::path& path, const std::vector<PlotSeries>& series, const PlotOptions& options);

}  // namespace crfcal::io
