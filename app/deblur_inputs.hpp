#pragma once
// Inputs of deblurring shared by `crfcal deblur` and `crfcal bench deblur --real`: φ and the kernel of a calibration
// report, its registration, the pair's sharp shot, and the side-by-side figure.
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/deconvolution.hpp"
#include "crfcal/registration.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal::app {

// One φ per image channel (OpenCV order B, G, R; grey: G). A report (or "table:REPORT.json") gives each channel its
// own curve, falling back to G for channels it lacks; any other spec is one curve for all channels.
std::vector<ResponseCurve> curvesFor(const std::string& spec, int channels);

// The kernel a calibration report points to: "kernel": {"text": "kernel.txt"} beside report.json.
cv::Mat kernelOfReport(const std::filesystem::path& report_path);

// The per-tile kernels a calibration report lists ("kernel" → "tile_kernels": kernel_tile_N.txt beside report.json,
// each at its tile's centre in the blurred shot) and whether the calibration found the blur varying across the frame
// ("tile_disagreement" → "varies"). Empty when the report lists none (images up to 1200 px are one tile).
struct ReportTileKernels {
  std::vector<LocalKernel> kernels;
  std::vector<std::filesystem::path> files;  // the kernels' text files (inputs: never overwritten)
  bool varies = false;
};
ReportTileKernels tileKernelsOfReport(const std::filesystem::path& report_path);

// An image as CV_64F in [0,1] (BGRA → BGR); throws InvalidInput unless grey or colour.
cv::Mat toUnit(const cv::Mat& image);

// The sharp shot → blurred shot homography of a calibration report ("registration": {"homography": 9 values}); empty
// when the report has none.
cv::Mat homographyOfReport(const std::filesystem::path& report_path);

// The pair's sharp shot as read, checked against the blurred image (same size, or transposed; same channels).
cv::Mat readSharpShot(const std::string& path, const cv::Mat& blurred, const std::string& blurred_path);

// Panels side by side, 8-bit, a caption above each.
cv::Mat sideBySide(const std::vector<std::pair<cv::Mat, std::string>>& items);

// Registers `sharp` (as read) onto `blurred_unit` (CV_64F, [0,1]); a transposed sharp shot is turned by whichever of
// ±90° registers with a small angle (a handheld pair); the shot as registered goes to `turned`.
RegistrationResult registerTurning(const cv::Mat& sharp, const cv::Mat& blurred_unit, cv::Mat& turned);

}  // namespace crfcal::app
