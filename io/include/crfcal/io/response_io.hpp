#pragma once
// Response curves on disk and in JSON.
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal::io {

// Like crfcal::parseResponseSpec, plus "table:FILE": FILE holds φ samples at x = i/(n−1), one per line, or two
// columns x,φ (resampled to 1024 points), or columns under a header "x,R,G,B" (`crfcal export`'s csv: the green
// column, or `channel`'s), or a crfcal JSON report/truth file ("inverse_crf": samples, or per channel {"G": …} —
// the green channel, or `channel`).
ResponseModel parseResponseSpec(const std::string& spec, const std::string& channel = "G");

// Reads an inverse curve table (as described above) resampled to `samples` points.
std::vector<double> readCurveTable(const std::filesystem::path& path, const std::string& channel = "G",
                                   int samples = kCurveSamples);

// The intensity range a curve table's header says its data cover ("# ... data cover x in [lo, hi] ...", written by
// `crfcal curves`), or nullopt when no header line says so.
std::optional<std::pair<double, double>> readCurveTableCoverage(const std::filesystem::path& path);

// {"kind": "ggcm", "parameters": [...], "spec": "ggcm:..."} (tables: kind and sample count only).
nlohmann::json modelToJson(const ResponseModel& model);

}  // namespace crfcal::io
