#pragma once
// ColorChecker inputs and outputs: chart photos (rectified crops, detected or user-given corners), the Middlebury
// RAW-vs-JPEG chart dataset, curve tables and the patches-on-curve plot.
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/colorchecker.hpp"

namespace crfcal::io {

// How the chart is found in an image.
enum class ChartLayout {
  Auto,       // --corners if given, else the whole image when it looks like a rectified 6×4 grid (aspect 3:2 and
              // ≤ 1000 px wide), else mcc detection
  Rectified,  // the whole image is the 6×4 patch grid (Middlebury crops)
  Detect,     // OpenCV mcc detector
};
ChartLayout parseChartLayout(const std::string& name);  // "auto" | "rectified" | "detect"

// "x1,y1,x2,y2,x3,y3,x4,y4": outer corners of the patch grid in chart order (dark skin, bluish green, black, white).
chart::ChartCorners parseCorners(const std::string& text);

struct LoadedChart {
  std::filesystem::path path;
  cv::Mat rectified;              // 6·65 × 4·65 px, as read (8/16 bit BGR)
  chart::ChartCorners corners{};  // in the source image
  std::string how;                // "rectified" | "corners" | "mcc"
};

// Reads IMAGE and rectifies its chart. Throws crfcal::Error naming the file when reading fails or no chart is found.
LoadedChart loadChart(const std::filesystem::path& path, ChartLayout layout,
                      const std::optional<chart::ChartCorners>& corners = std::nullopt);

// The Middlebury dataset (../shared/data/middlebury): <Camera>/wb1i{1,2}e{1..4}-{jpg,raw}.png.
struct MiddleburyShot {
  std::string name;  // e.g. "wb1i2e3"
  std::filesystem::path jpg, raw;
  int scene = 0;     // the illumination, "i<k>" of the name (0 when absent): shots of a scene differ in exposure only
};
// Camera folder names (sorted) that contain at least one jpg/raw pair. Throws Error if `root` is not a directory.
std::vector<std::string> listMiddleburyCameras(const std::filesystem::path& root);
// The jpg/raw pairs of one camera folder, sorted by name.
std::vector<MiddleburyShot> listMiddleburyShots(const std::filesystem::path& camera_dir);

// Writes "# comment lines…" then 1024 lines "x,phi" (x = i/1023), atomically. readCurveTable reads it back.
void writeCurveCsv(const std::filesystem::path& path, const std::vector<double>& phi, const std::string& comment);

// Plot of the fitted curve(s) with the patches (x, normalised reference) as markers.
void writeChartPlot(const std::filesystem::path& path, const ChartCalibrationResult& result, const std::string& title,
                    const std::vector<std::pair<std::string, std::vector<double>>>& truth = {});

}  // namespace crfcal::io
