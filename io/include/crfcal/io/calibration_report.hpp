#pragma once
// The report of `crfcal calibrate` (report.json): the schema of report.hpp filled from a pair calibration, its
// inputs and (optionally) the RAW truth of one shot. One home for the keys; the command only parses, calls, prints.
//
// Calibrate's keys beyond report.hpp's common ones: "input", "exposure_ratio_factors" (EXIF), "exposure_ratio_mode",
// "exposure_ratio_per_channel", "exposure_ratio_prior", "ambiguity_rise", "kernel", "registration", "rounds",
// "fit_window", "fit", "phi_base_model" (the fits before an effect's model replaced them), "raw_truth".
#include <map>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "crfcal/curve_comparison.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/raw_truth.hpp"

namespace crfcal::io {

// calibrate --raw-truth: the RAW (or linear) file of one shot and the camera response measured from it.
struct RawTruthReport {
  const LoadedImage& file;
  bool blurred_shot = false;        // the file is the blurred shot's (else the sharp one's)
  std::string shot_file;            // that shot's rendered file
  std::string shot_reason;          // why that shot (given, or EXIF)
  const RawTruthResult& result;
  std::optional<CurveComparison> comparison;  // the pair's φ against the truth's
  bool compared_on_full_range_only = false;   // the two cover disjoint intensity ranges: [0,1] comparison only
};

// What the report needs besides the result: the inputs and the choices the command made.
struct CalibrationReportContext {
  const LoadedPair& pair;
  double nominal_ratio = 0;           // r handed to the fit (footnote 4): the EXIF ratio or --ratio
  std::string nominal_ratio_source;   // "exif" or "--ratio"
  bool ratio_fixed_by_option = false; // --fix-ratio
  double ratio_prior_sigma = 0;       // σ of the prior on log r around nominal_ratio (0 or fixed r: no prior)
  const RawTruthReport* raw_truth = nullptr;
};

// A `calibrate` report's curves: per channel φ, its model and the pixels used (single pair and joint fits alike).
CalibrationReport curveFitsReport(const std::map<std::string, CrfFitResult>& fits);

// The report of one calibration (timings: the result's stages; the command adds its own before writing).
CalibrationReport calibrationReport(const PairCalibrationResult& result, const CalibrationReportContext& context);

// The per-tile kernels of a calibration (PairCalibrationResult::tile_kernels, when more than one) as text matrices in
// `directory`, named as the report's "kernel" → "tile_kernels" entries name them (kernel_tile_<tile>.txt).
void writeTileKernels(const std::filesystem::path& directory, const PairCalibrationResult& result);

// The comparison of two sets of curves (CurveComparison) as JSON: per channel RMSE / max error / covered range.
nlohmann::json curveComparisonJson(const CurveComparison& comparison);

}  // namespace crfcal::io
