#pragma once
// The calibration report (report.json) shared by `calibrate`, `chart`, `compare` and `export`.
//
// Layout (keys not listed are free-form additions of the producing command, kept in `extra`):
// {
//   "crfcal_version": "0.1.0", "command": "calibrate" | "chart" | ...,
//   "inverse_crf": {"R": [1024 samples of φ at x = i/1023], "G": [...], "B": [...]}   (only "G" for grey input),
//   "models": {"G": {"kind": "ggcm", "parameters": [...], "spec": "ggcm:..."}, ...},
//   "exposure_ratio": {"nominal": r, "nominal_source": "exif" | "--ratio", "exif": r (only when nominal_source is
//                      "exif"), "fitted": r or null}   (r = Δt_B/Δt_I, footnote 4; "nominal" absent when unknown;
//                      reports before 0.2 wrote {"exif": r or null, "fitted": r}: read as nominal from EXIF),
//   "kernel": {"size": [w, h], "file": "kernel.png"} (optional),
//   "pixels_used": {"G": n, ...}, "timings": {"stage": seconds, ...},
//   "effects": [ {"name", "detected", "statistic", "gain", ...} ], "warnings": ["..."],
//   "covered_range": {"G": [x_lo, x_hi]}   (intensity range actually supported by data; optional)
// }
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal::io {

struct CalibrationReport {
  std::string command;
  std::map<std::string, std::vector<double>> inverse_crf;   // channel → 1024 samples
  std::map<std::string, ResponseModel> models;              // channel → model (optional per channel)
  std::map<std::string, std::pair<double, double>> covered_range;
  std::optional<double> nominal_ratio;   // the exposure ratio given to the fit: from EXIF or --ratio
  std::string nominal_ratio_source;      // "exif" or "--ratio" (empty: unknown)
  std::optional<double> fitted_ratio;
  std::map<std::string, double> timings;
  std::map<std::string, long long> pixels_used;
  nlohmann::json effects = nlohmann::json::array();
  std::vector<std::string> warnings;
  nlohmann::json extra = nlohmann::json::object();  // command-specific fields, merged at top level

  // Channels present, in R, G, B order.
  std::vector<std::string> channels() const;
  nlohmann::json toJson() const;
  static CalibrationReport fromJson(const nlohmann::json& json, const std::string& source = {});
};

// One channel of a static calibration (chart, bracket: the scaled-exposure fitter of chart_calibration.hpp) into a
// report: φ, its GGCM form, the covered range and the observations used.
void addScaledFitChannel(CalibrationReport& report, const std::string& channel, const ScaledFitResult& fit,
                         const GgcmModel& ggcm);

// Reads report.json (or a simulate truth.json, whose "inverse_crf" is a plain list: channel "G").
// Throws crfcal::Error naming the file.
CalibrationReport readReport(const std::filesystem::path& path);
// Writes atomically, pretty-printed.
void writeReport(const std::filesystem::path& path, const CalibrationReport& report);

}  // namespace crfcal::io
