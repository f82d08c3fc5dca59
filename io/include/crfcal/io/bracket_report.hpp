#pragma once
// The output of `crfcal bracket` (bracket_calibration.hpp): report.json in the common schema of report.hpp (so that
// `compare` and `export` read it like every other report) and its pictures:
//   curve.png   φ per channel (thick where the data support it, thin where extrapolated; bars: covered ranges; the
//               90 % band shaded)
//   points.png  the scene points drawn, over a dimmed copy of the reference frame
// Bracket's keys beyond report.hpp's common ones: "bracket" {"frames": [{"image", "exif", "nominal_exposure",
// "start_exposure", "fitted_exposure", "reference", "registration"}], "exposure_source", "points", "channels":
// {"R": {"emor", "terms", "cv_rmse", "rmse", "points", "ggcm_rmse_vs_emor", "ggcm_valid"}}, "inverse_crf_model"};
// "inverse_crf_band" per channel as band_report.hpp writes it (scaled_fit_band.hpp's band).
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/bracket_calibration.hpp"
#include "crfcal/exposure_ratio.hpp"
#include "crfcal/io/report.hpp"

namespace crfcal::io {

// The report of one bracket calibration; `exif`: each frame's EXIF as read (input order), for the record.
CalibrationReport bracketReport(const BracketCalibrationResult& result, const std::vector<ExifExposure>& exif);

// Writes the curve picture and the points picture (atomically, one by one). `reference_image`: the reference frame.
void writeBracketFigures(const std::filesystem::path& curve_png, const std::filesystem::path& points_png,
                         const BracketCalibrationResult& result, const cv::Mat& reference_image,
                         const std::string& camera);

}  // namespace crfcal::io
