#pragma once
// The band of φ in report.json (curve_band.hpp), kept apart from the report writer so that commands reading a
// report (compare, export) find it in one place:
//   "inverse_crf_band": {"G": {"lower": [1024], "upper": [1024], "shape_half_width": [1024], "level": 0.9,
//                              "replicates": n, "failed_replicates": n, "scale_range": [s_lo, s_hi],
//                              "covered": [x_lo, x_hi], "method": "...",
//                              "above_data": {"kind": "learned_prior", "training_curves": n} or
//                                            {"kind": "exponent_bounds", "exponent": [g_lo, g_hi]}}, …}
// The covered range itself is report.json's "covered_range" (report.hpp); "covered" repeats the range the band
// was built on. Reports without a band (older ones, chart, simulate's truth) read as none; bracket reports have one
// (scaled_fit_band.hpp).
#include <map>
#include <string>

#include <nlohmann/json.hpp>

#include "crfcal/curve_band.hpp"
#include "crfcal/io/report.hpp"

namespace crfcal::io {

// `method`: how the bands were made, for the record (the pair's block bootstrap by default; the bracket says its own).
nlohmann::json curveBandsJson(const std::map<std::string, CurveBand>& bands,
                              const std::string& method = "half-sample block refits (shape) + local-exponent bounds "
                                                          "beyond the covered range (scale); curve_band.hpp");
// The bands of a report (its "inverse_crf_band"); empty when it has none. Throws crfcal::Error naming `source` for
// a malformed band (limits of another length than the channel's curve).
std::map<std::string, CurveBand> readCurveBands(const CalibrationReport& report, const std::string& source = {});

}  // namespace crfcal::io
