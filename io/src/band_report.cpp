#include "crfcal/io/band_report.hpp"

#include "crfcal/error.hpp"

namespace crfcal::io {

nlohmann::json curveBandsJson(const std::map<std::string, CurveBand>& bands, const std::string& method) {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& [name, band] : bands) {
    if (band.empty()) continue;
    out[name] = {{"lower", band.lower},
                 {"upper", band.upper},
                 {"shape_half_width", band.shape_half_width},
                 {"level", band.level},
                 {"replicates", band.replicates},
                 {"failed_replicates", band.failed_replicates},
                 {"scale_range", {band.scale_range.first, band.scale_range.second}},
                 {"covered", {band.covered.first, band.covered.second}},
                 {"method", method}};
    // What set the band above the covered range: the exponent bounds, or the learned prior's quantiles.
    if (band.above_data == CurveBand::AboveData::learned_prior)
      out[name]["above_data"] = {{"kind", "learned_prior"}, {"training_curves", band.above_data_curves}};
    else
      out[name]["above_data"] = {{"kind", "exponent_bounds"},
                                 {"exponent", {band.exponent_above.first, band.exponent_above.second}}};
  }
  return out;
}

std::map<std::string, CurveBand> readCurveBands(const CalibrationReport& report, const std::string& source) {
  std::map<std::string, CurveBand> bands;
  const auto it = report.extra.find("inverse_crf_band");
  if (it == report.extra.end() || !it->is_object()) return bands;
  try {
    for (const auto& [name, value] : it->items()) {
      CurveBand band;
      band.lower = value.at("lower").get<std::vector<double>>();
      band.upper = value.at("upper").get<std::vector<double>>();
      band.shape_half_width = value.value("shape_half_width", std::vector<double>(band.lower.size(), 0.0));
      band.level = value.value("level", 0.9);
      band.replicates = value.value("replicates", 0);
      if (value.contains("covered")) band.covered = {value["covered"].at(0).get<double>(), value["covered"].at(1).get<double>()};
      if (value.contains("scale_range"))
        band.scale_range = {value["scale_range"].at(0).get<double>(), value["scale_range"].at(1).get<double>()};
      const auto curve = report.inverse_crf.find(name);
      if (curve == report.inverse_crf.end() || band.lower.size() != curve->second.size() ||
          band.upper.size() != curve->second.size() || band.shape_half_width.size() != curve->second.size())
        throw Error("inverse_crf_band." + name + ": limits of another length than inverse_crf." + name, source);
      bands[name] = std::move(band);
    }
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("inverse_crf_band: ") + e.what(), source);
  }
  return bands;
}

}  // namespace crfcal::io
