#include "crfcal/io/chart_io.hpp"

#include <algorithm>
#include <cstdlib>
#include <cmath>
#include <cstdio>
#include <sstream>

#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/plot.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

ChartLayout parseChartLayout(const std::string& name) {
  if (name == "auto") return ChartLayout::Auto;
  if (name == "rectified") return ChartLayout::Rectified;
  if (name == "detect") return ChartLayout::Detect;
  throw InvalidInput("unknown chart layout '" + name + "' (auto | rectified | detect)");
}

chart::ChartCorners parseCorners(const std::string& text) {
  std::vector<float> values;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    try {
      size_t used = 0;
      values.push_back(std::stof(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InvalidInput("--corners: '" + item + "' is not a number");
    }
  }
  if (values.size() != 8) throw InvalidInput("--corners needs 8 numbers x1,y1,…,x4,y4 (got " + std::to_string(values.size()) + ")");
  chart::ChartCorners corners;
  for (size_t i = 0; i < 4; ++i) corners[i] = cv::Point2f(values[2 * i], values[2 * i + 1]);
  return corners;
}

LoadedChart loadChart(const fs::path& path, ChartLayout layout, const std::optional<chart::ChartCorners>& corners) {
  LoadedChart loaded;
  loaded.path = path;
  cv::Mat image = readImage(path);
  if (image.channels() == 1) cv::merge(std::vector<cv::Mat>{image, image, image}, image);
  if (image.channels() == 4) {
    std::vector<cv::Mat> planes;
    cv::split(image, planes);
    planes.resize(3);
    cv::merge(planes, image);
  }
  const double aspect = double(image.cols) / image.rows;
  if (corners) {
    // Corners outside the image would rectify padding into patches (exit 0 with nonsense before this check).
    for (const cv::Point2f& corner : *corners)
      if (!(corner.x >= 0 && corner.y >= 0 && corner.x <= image.cols && corner.y <= image.rows))
      {
        char text[160];
        std::snprintf(text, sizeof text, "--corners: (%g, %g) lies outside the image (%dx%d)", corner.x, corner.y,
                      image.cols, image.rows);
        throw Error(text, path.string());
      }
    loaded.corners = *corners;
    loaded.how = "corners";
  } else if (layout == ChartLayout::Rectified ||
             (layout == ChartLayout::Auto && std::abs(aspect - 1.5) < 0.03 && image.cols <= 1000)) {
    loaded.corners = chart::fullImageCorners(image.size());
    loaded.how = "rectified";
  } else {
    cv::Mat eight = image;
    if (image.depth() == CV_16U) image.convertTo(eight, CV_8U, 1.0 / 257);
    const auto found = chart::detect(eight);
    if (!found) throw Error("no ColorChecker found by the mcc detector (pass --corners)", path.string());
    loaded.corners = *found;
    loaded.how = "mcc";
  }
  if (loaded.how == "rectified" && image.cols == chart::kColumns * 65 && image.rows == chart::kRows * 65)
    loaded.rectified = image;
  else
    loaded.rectified = chart::rectify(image, loaded.corners, 65);
  return loaded;
}

std::vector<std::string> listMiddleburyCameras(const fs::path& root) {
  if (!fs::is_directory(root)) throw Error("not a directory", root.string());
  std::vector<std::string> cameras;
  for (const auto& entry : fs::directory_iterator(root)) {
    if (!entry.is_directory()) continue;
    if (!listMiddleburyShots(entry.path()).empty()) cameras.push_back(entry.path().filename().string());
  }
  std::sort(cameras.begin(), cameras.end());
  return cameras;
}

std::vector<MiddleburyShot> listMiddleburyShots(const fs::path& camera_dir) {
  if (!fs::is_directory(camera_dir)) throw Error("not a directory", camera_dir.string());
  std::vector<MiddleburyShot> shots;
  for (const auto& entry : fs::directory_iterator(camera_dir)) {
    const std::string name = entry.path().filename().string();
    const std::string suffix = "-jpg.png";
    if (name.size() <= suffix.size() || name.compare(name.size() - suffix.size(), suffix.size(), suffix) != 0) continue;
    const std::string stem = name.substr(0, name.size() - suffix.size());
    const fs::path raw = camera_dir / (stem + "-raw.png");
    if (!fs::exists(raw)) continue;
    // "wb1i2e3": illumination 2, exposure 3.
    const auto lit = stem.find('i'), exposure = stem.rfind('e');
    int scene = 0;
    if (lit != std::string::npos && exposure != std::string::npos && exposure > lit + 1)
      scene = std::atoi(stem.substr(lit + 1, exposure - lit - 1).c_str());
    shots.push_back({stem, entry.path(), raw, scene});
  }
  std::sort(shots.begin(), shots.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  return shots;
}

void writeCurveCsv(const fs::path& path, const std::vector<double>& phi, const std::string& comment) {
  if (phi.size() != size_t(kCurveSamples)) throw InvalidInput("curve table must have 1024 samples");
  std::ostringstream out;
  std::istringstream lines(comment);
  std::string line;
  while (std::getline(lines, line)) out << "# " << line << "\n";
  char buffer[64];
  for (size_t i = 0; i < phi.size(); ++i) {
    std::snprintf(buffer, sizeof buffer, "%.8f,%.8f\n", double(i) / double(phi.size() - 1), phi[i]);
    out << buffer;
  }
  writeTextFile(path, out.str());
}

void writeChartPlot(const fs::path& path, const ChartCalibrationResult& result, const std::string& title,
                    const std::vector<std::pair<std::string, std::vector<double>>>& truth) {
  const cv::Scalar colours[3] = {cv::Scalar(40, 40, 220), cv::Scalar(40, 160, 40), cv::Scalar(220, 80, 40)};
  std::vector<PlotSeries> series;
  std::vector<double> grid(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) grid[static_cast<size_t>(i)] = double(i) / (kCurveSamples - 1);
  for (const auto& channel : result.channels) {
    const cv::Scalar colour = colours[channel.channel];
    PlotSeries curve{grid, channel.fit.inverse, colour,
                     channelName(channel.channel) + " EMoR K=" + std::to_string(channel.fit.terms), 2, false, false};
    series.push_back(curve);
    PlotSeries points{{}, {}, colour, "", 2, true, false};
    for (const auto& p : channel.patches) {
      points.x.push_back(p.x);
      points.y.push_back(p.reference);
    }
    series.push_back(points);
  }
  for (const auto& [label, samples] : truth) {
    if (samples.size() != size_t(kCurveSamples)) continue;
    cv::Scalar colour(90, 90, 90);
    for (const auto& channel : result.channels)
      if (label.rfind(channelName(channel.channel), 0) == 0) colour = colours[channel.channel] * 0.6;
    series.push_back({grid, samples, colour, label, 2, false, true});
  }
  PlotOptions options;
  for (const auto& channel : result.channels)
    if (channel.band.lower.size() == grid.size())
      options.bands.push_back({grid, channel.band.lower, channel.band.upper, colours[channel.channel],
                               std::to_string(int(std::lround(100 * channel.band.level))) + " % band " +
                                   channelName(channel.channel) + " (shaded)"});
  options.title = title;
  options.x_label = "intensity x";
  options.y_label = "phi(x)";
  options.x_min = 0;
  options.x_max = 1;
  options.y_min = 0;
  options.y_max = 1.05;
  writePlot(path, series, options);
}

}  // namespace crfcal::io
