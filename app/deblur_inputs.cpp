#include "deblur_inputs.hpp"

#include <algorithm>
#include <cmath>
#include <optional>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"

namespace crfcal::app {
namespace fs = std::filesystem;
namespace {

bool endsWith(const std::string& text, const std::string& suffix) {
  return text.size() >= suffix.size() && text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

}  // namespace

// One φ per image channel (OpenCV order B, G, R; grey: G). A report (or "table:REPORT.json") gives each channel its
// own curve, falling back to G for channels it lacks; any other spec is one curve for all channels.
std::vector<ResponseCurve> curvesFor(const std::string& spec, int channels) {
  std::string path = spec.rfind("table:", 0) == 0 ? spec.substr(6) : spec;
  if (!endsWith(path, ".json")) return {ResponseCurve(io::parseResponseSpec(spec))};
  const io::CalibrationReport report = io::readReport(path);
  const std::vector<std::string> names = channels == 1 ? std::vector<std::string>{"G"}
                                                       : std::vector<std::string>{"B", "G", "R"};
  std::vector<ResponseCurve> curves;
  for (const std::string& name : names) {
    auto found = report.inverse_crf.find(name);
    if (found == report.inverse_crf.end()) found = report.inverse_crf.find("G");
    if (found == report.inverse_crf.end()) throw Error("no inverse_crf for channel " + name + " or G", path);
    try {
      curves.push_back(ResponseCurve::fromSamples(found->second));
    } catch (const InvalidInput& e) {
      throw Error("inverse_crf " + found->first + ": " + e.reason(), path);
    }
  }
  return curves;
}

// The kernel a calibration report points to: "kernel": {"text": "kernel.txt"} beside report.json.
cv::Mat kernelOfReport(const fs::path& report_path) {
  const io::CalibrationReport report = io::readReport(report_path);
  const auto entry = report.extra.find("kernel");
  if (entry == report.extra.end() || !entry->is_object())
    throw Error("the report records no kernel (give --kernel)", report_path.string());
  const std::string text = entry->value("text", std::string("kernel.txt"));
  return io::readKernel(report_path.parent_path() / text);
}

cv::Mat toUnit(const cv::Mat& image) {
  cv::Mat colour = image;
  if (image.channels() == 4) cv::cvtColor(image, colour, cv::COLOR_BGRA2BGR);
  if (colour.channels() != 1 && colour.channels() != 3)
    throw InvalidInput("images to deblur must be grey or colour");
  const double scale = colour.depth() == CV_16U ? 1.0 / 65535 : colour.depth() == CV_8U ? 1.0 / 255 : 1.0;
  cv::Mat unit;
  colour.convertTo(unit, CV_MAKETYPE(CV_64F, colour.channels()), scale);
  return unit;
}

ReportTileKernels tileKernelsOfReport(const fs::path& report_path) {
  const io::CalibrationReport report = io::readReport(report_path);
  ReportTileKernels tiles;
  const auto entry = report.extra.find("kernel");
  if (entry == report.extra.end() || !entry->is_object() || !entry->contains("tile_kernels")) return tiles;
  try {
    for (const auto& tile : entry->at("tile_kernels")) {
      const auto centre = tile.at("centre_in_blurred").get<std::vector<double>>();
      if (centre.size() != 2) throw Error("kernel.tile_kernels: centre_in_blurred needs 2 values", report_path.string());
      tiles.files.push_back(report_path.parent_path() / tile.at("text").get<std::string>());
      tiles.kernels.push_back({{centre[0], centre[1]}, io::readKernel(tiles.files.back())});
    }
    if (entry->contains("tile_disagreement"))
      tiles.varies = entry->at("tile_disagreement").value("varies", false);
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("kernel.tile_kernels: ") + e.what(), report_path.string());
  }
  return tiles;
}

// The sharp shot → blurred shot homography of a calibration report ("registration": {"homography": 9 values}); empty
// when the report has none.
cv::Mat homographyOfReport(const fs::path& report_path) {
  const io::CalibrationReport report = io::readReport(report_path);
  const auto entry = report.extra.find("registration");
  if (entry == report.extra.end() || !entry->is_object() || !entry->contains("homography")) return {};
  const std::vector<double> values = entry->at("homography").get<std::vector<double>>();
  if (values.size() != 9) throw Error("registration.homography must have 9 values", report_path.string());
  return cv::Mat(values, true).reshape(1, 3);
}

// The pair's sharp shot in unit range, checked against the blurred image (same size and channels).
cv::Mat readSharpShot(const std::string& path, const cv::Mat& blurred, const std::string& blurred_path) {
  cv::Mat sharp = io::readImage(path);
  if (sharp.channels() == 4) cv::cvtColor(sharp, sharp, cv::COLOR_BGRA2BGR);
  if (sharp.size() != blurred.size() && sharp.size() != cv::Size(blurred.rows, blurred.cols))
    throw Error("the sharp shot is " + std::to_string(sharp.cols) + "x" + std::to_string(sharp.rows) + " but " +
                    blurred_path + " is " + std::to_string(blurred.cols) + "x" + std::to_string(blurred.rows) +
                    " (the pair's two shots have one size, or are portrait and landscape)", path);
  if (sharp.channels() != blurred.channels())
    throw Error("the sharp shot has " + std::to_string(sharp.channels()) + " channel(s), " + blurred_path + " " +
                    std::to_string(blurred.channels()), path);
  return sharp;
}

// Panels side by side, 8-bit, a caption above each.
cv::Mat sideBySide(const std::vector<std::pair<cv::Mat, std::string>>& items) {
  // captions grow with the panels, so that they stay readable when a photo's panels are shown scaled down
  const int width = items.empty() ? 0 : items.front().first.cols;
  const double font_scale = std::max(0.6, width / 1000.0);
  const int caption = static_cast<int>(std::lround(28 * font_scale / 0.6));
  const int thickness = std::max(1, static_cast<int>(std::lround(font_scale)));
  std::vector<cv::Mat> panels;
  for (const auto& [image_value, label] : items) {
    const cv::Mat* image = &image_value;
    cv::Mat bgr, eight;
    cv::Mat clamped = cv::min(cv::max(*image, 0.0), 1.0);
    clamped.convertTo(eight, CV_MAKETYPE(CV_8U, clamped.channels()), 255.0);
    if (eight.channels() == 1) cv::cvtColor(eight, bgr, cv::COLOR_GRAY2BGR);
    else bgr = eight;
    cv::Mat panel(bgr.rows + caption, bgr.cols, CV_8UC3, cv::Scalar(255, 255, 255));
    bgr.copyTo(panel(cv::Rect(0, caption, bgr.cols, bgr.rows)));
    cv::putText(panel, label.c_str(), {static_cast<int>(6 * font_scale / 0.6), caption - caption * 8 / 28},
                cv::FONT_HERSHEY_SIMPLEX, font_scale, cv::Scalar(0, 0, 0), thickness, cv::LINE_AA);
    panels.push_back(panel);
    panels.push_back(cv::Mat(panel.rows, 4, CV_8UC3, cv::Scalar(255, 255, 255)));
  }
  panels.pop_back();
  cv::Mat joined;
  cv::hconcat(panels, joined);
  return joined;
}

// Registers the sharp shot onto the blurred one; a transposed sharp shot is turned by whichever of ±90° registers
// with a small angle (a handheld pair), into `turned`.
RegistrationResult registerTurning(const cv::Mat& sharp, const cv::Mat& blurred_unit, cv::Mat& turned) {
  cv::Mat blurred;  // registration works on integer images
  blurred_unit.convertTo(blurred, CV_MAKETYPE(CV_16U, blurred_unit.channels()), 65535.0);
  if (sharp.size() == blurred.size()) {
    turned = sharp;
    return registerPair(sharp, blurred);
  }
  std::optional<RegistrationResult> best;
  std::string failure = "neither 90-degree turn of the sharp shot registers";
  for (const int code : {cv::ROTATE_90_CLOCKWISE, cv::ROTATE_90_COUNTERCLOCKWISE}) {
    cv::Mat candidate;
    cv::rotate(sharp, candidate, code);
    try {
      const RegistrationResult r = registerPair(candidate, blurred);
      if (std::abs(r.rotationDegrees()) > 45) continue;
      if (!best || r.ecc_correlation * r.overlap_fraction > best->ecc_correlation * best->overlap_fraction) {
        best = r;
        turned = candidate;
      }
    } catch (const InvalidInput& e) {
      failure = e.reason();
    }
  }
  if (!best) throw InvalidInput(failure, ErrorSubject::pair);
  return *best;
}

}  // namespace crfcal::app
