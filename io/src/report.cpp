#include "crfcal/io/report.hpp"

#include <fstream>
#include <sstream>

#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/response_curve.hpp"
#include "json_error.hpp"

#ifndef CRFCAL_VERSION
#define CRFCAL_VERSION "0.1.0"
#endif

namespace crfcal::io {
namespace {

ResponseModel modelFromJson(const nlohmann::json& json) {
  const std::string kind = json.value("kind", "");
  std::vector<double> parameters;
  if (json.contains("parameters")) parameters = json["parameters"].get<std::vector<double>>();
  if (kind == "gamma" && parameters.size() == 1) return GammaModel{parameters[0]};
  if (kind == "ggcm") return GgcmModel{parameters};
  if (kind == "emor") return EmorModel{parameters};
  throw InvalidInput("model of kind '" + kind + "' cannot be rebuilt from its parameters");
}

}  // namespace

std::vector<std::string> CalibrationReport::channels() const {
  std::vector<std::string> names;
  for (const char* c : {"R", "G", "B"})
    if (inverse_crf.count(c)) names.emplace_back(c);
  for (const auto& [name, _] : inverse_crf)
    if (name != "R" && name != "G" && name != "B") names.push_back(name);
  return names;
}

nlohmann::json CalibrationReport::toJson() const {
  nlohmann::json json = extra.is_object() ? extra : nlohmann::json::object();
  json["crfcal_version"] = CRFCAL_VERSION;
  json["command"] = command;
  json["inverse_crf_x"] = "x = i/1023, i = 0..1023";
  json["inverse_crf"] = nlohmann::json::object();
  for (const auto& [channel, samples] : inverse_crf) json["inverse_crf"][channel] = samples;
  if (!models.empty()) {
    json["models"] = nlohmann::json::object();
    for (const auto& [channel, model] : models) json["models"][channel] = modelToJson(model);
  }
  if (!covered_range.empty()) {
    json["covered_range"] = nlohmann::json::object();
    for (const auto& [channel, range] : covered_range) json["covered_range"][channel] = {range.first, range.second};
  }
  nlohmann::json& ratio = json["exposure_ratio"];
  ratio = {{"fitted", fitted_ratio ? nlohmann::json(*fitted_ratio) : nlohmann::json(nullptr)}};
  if (nominal_ratio) {
    ratio["nominal"] = *nominal_ratio;
    if (!nominal_ratio_source.empty()) ratio["nominal_source"] = nominal_ratio_source;
    if (nominal_ratio_source == "exif") ratio["exif"] = *nominal_ratio;  // the key older readers know
  }
  json["timings"] = timings;
  json["pixels_used"] = pixels_used;
  json["effects"] = effects;
  json["warnings"] = warnings;
  return json;
}

CalibrationReport CalibrationReport::fromJson(const nlohmann::json& json, const std::string& source) {
  CalibrationReport report;
  try {
    if (!json.is_object() || !json.contains("inverse_crf")) throw Error("no \"inverse_crf\" in report", source);
    report.command = json.value("command", "");
    const auto& curves = json["inverse_crf"];
    if (curves.is_array()) {
      report.inverse_crf["G"] = curves.get<std::vector<double>>();
    } else if (curves.is_object()) {
      for (const auto& [channel, samples] : curves.items()) report.inverse_crf[channel] = samples.get<std::vector<double>>();
    } else {
      throw Error("\"inverse_crf\" must be a list or an object of channels", source);
    }
    // The same validation as every other reader of curves (response_curve.hpp): what compare accepts, export accepts.
    for (const auto& [channel, samples] : report.inverse_crf)
      if (const ModelValidity validity = checkInverseSamples(samples); !validity)
        throw Error("\"inverse_crf\"." + channel + " is not a valid inverse response: " + validity.reason, source);
    if (json.contains("models") && json["models"].is_object()) {
      for (const auto& [channel, model] : json["models"].items()) {
        try {
          report.models[channel] = modelFromJson(model);
        } catch (const InvalidInput&) {
          // tables and unknown kinds: the samples are authoritative
        }
      }
    } else if (json.contains("model") && json["model"].is_object()) {
      try {
        report.models["G"] = modelFromJson(json["model"]);
      } catch (const InvalidInput&) {
      }
    }
    if (json.contains("covered_range") && json["covered_range"].is_object())
      for (const auto& [channel, range] : json["covered_range"].items())
        report.covered_range[channel] = {range.at(0).get<double>(), range.at(1).get<double>()};
    if (json.contains("exposure_ratio")) {
      const auto& ratio = json["exposure_ratio"];
      if (ratio.is_number()) report.fitted_ratio = ratio.get<double>();  // simulate's truth.json
      if (ratio.is_object()) {
        if (ratio.contains("nominal") && ratio["nominal"].is_number()) {
          report.nominal_ratio = ratio["nominal"].get<double>();
          report.nominal_ratio_source = ratio.value("nominal_source", "");
        } else if (ratio.contains("exif") && ratio["exif"].is_number()) {  // reports before "nominal"
          report.nominal_ratio = ratio["exif"].get<double>();
          report.nominal_ratio_source = "exif";
        }
        if (ratio.contains("fitted") && ratio["fitted"].is_number()) report.fitted_ratio = ratio["fitted"].get<double>();
      }
    }
    if (json.contains("timings") && json["timings"].is_object()) report.timings = json["timings"].get<std::map<std::string, double>>();
    if (json.contains("pixels_used") && json["pixels_used"].is_object())
      report.pixels_used = json["pixels_used"].get<std::map<std::string, long long>>();
    if (json.contains("effects")) report.effects = json["effects"];
    if (json.contains("warnings") && json["warnings"].is_array()) report.warnings = json["warnings"].get<std::vector<std::string>>();
    report.extra = json;
    for (const char* key : {"inverse_crf", "models", "covered_range", "exposure_ratio", "timings", "pixels_used",
                            "effects", "warnings", "crfcal_version", "command", "inverse_crf_x"})
      report.extra.erase(key);
  } catch (const nlohmann::json::exception& e) {
    throw Error("malformed report: " + describeJsonError(e), source);
  }
  return report;
}

CalibrationReport readReport(const std::filesystem::path& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) throw Error("is a directory, not a report", path.string());
  std::ifstream in(path);
  if (!in) throw Error(std::filesystem::exists(path, ec) ? "cannot open" : "file not found", path.string());
  nlohmann::json json;
  try {
    in >> json;
  } catch (const nlohmann::json::exception& e) {
    throw Error(describeJsonError(e), path.string());
  }
  return CalibrationReport::fromJson(json, path.string());
}

void writeReport(const std::filesystem::path& path, const CalibrationReport& report) {
  writeTextFile(path, report.toJson().dump(2) + "\n");
}

void addScaledFitChannel(CalibrationReport& report, const std::string& channel, const ScaledFitResult& fit,
                         const GgcmModel& ggcm) {
  report.inverse_crf[channel] = fit.inverse;
  report.models[channel] = ggcm;
  report.covered_range[channel] = fit.covered_range;
  report.pixels_used[channel] = fit.observations;
}

}  // namespace crfcal::io
