#include "crfcal/io/response_io.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "crfcal/error.hpp"
#include "crfcal/response_curve.hpp"
#include "json_error.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {

std::vector<double> resample(const std::vector<double>& x, const std::vector<double>& y, int samples) {
  std::vector<double> out(static_cast<size_t>(samples));
  for (int i = 0; i < samples; ++i) {
    const double t = double(i) / (samples - 1);
    auto it = std::lower_bound(x.begin(), x.end(), t);
    if (it == x.begin()) out[static_cast<size_t>(i)] = y.front();
    else if (it == x.end()) out[static_cast<size_t>(i)] = y.back();
    else {
      const size_t j = static_cast<size_t>(it - x.begin());
      const double w = (t - x[j - 1]) / std::max(1e-300, x[j] - x[j - 1]);
      out[static_cast<size_t>(i)] = y[j - 1] + w * (y[j] - y[j - 1]);
    }
  }
  return out;
}

std::vector<double> evenSamples(const std::vector<double>& y, int samples) {
  std::vector<double> x(y.size());
  for (size_t i = 0; i < y.size(); ++i) x[i] = double(i) / double(y.size() - 1);
  return resample(x, y, samples);
}

}  // namespace

namespace {

std::vector<double> readCurveSamples(const fs::path& path, const std::string& channel, int samples) {
  std::error_code ec;
  if (fs::is_directory(path, ec)) throw Error("is a directory, not a curve table", path.string());
  std::ifstream in(path);
  if (!in) throw Error(fs::exists(path) ? "cannot open" : "file not found", path.string());
  std::stringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  const auto first = text.find_first_not_of(" \t\r\n");
  if (first != std::string::npos && text[first] == '{') {
    nlohmann::json json;
    try {
      json = nlohmann::json::parse(text);
    } catch (const nlohmann::json::exception& e) {
      throw Error(describeJsonError(e), path.string());
    }
    if (!json.is_object() || !json.contains("inverse_crf")) throw Error("JSON has no \"inverse_crf\"", path.string());
    auto curve = json["inverse_crf"];
    if (curve.is_object()) {
      if (!curve.contains(channel)) throw Error("\"inverse_crf\" has no channel " + channel, path.string());
      curve = curve[channel];
    }
    if (!curve.is_array() || curve.size() < 2) throw Error("\"inverse_crf\" is not a list of samples", path.string());
    for (const auto& value : curve)
      if (!value.is_number()) throw Error("\"inverse_crf\" holds a value that is not a number", path.string());
    return evenSamples(curve.get<std::vector<double>>(), samples);
  }
  std::vector<double> xs, ys;
  std::istringstream lines(text);
  std::string line;
  int number = 0, columns = -1;
  // A header naming the columns "x,R,G,B" (what `crfcal export` writes as csv) selects `channel`'s column.
  std::vector<std::string> header;
  int channel_column = -1;
  while (std::getline(lines, line)) {
    ++number;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream fields(line);
    std::vector<double> row;
    std::vector<std::string> tokens;
    std::string token;
    bool numeric = true;
    while (fields >> token) {
      char* end = nullptr;
      const double v = std::strtod(token.c_str(), &end);
      if (end == token.c_str() || *end) numeric = false;
      row.push_back(v);
      tokens.push_back(token);
    }
    if (row.empty()) continue;  // blank line
    if (!numeric && xs.empty() && ys.empty()) {  // a header
      if (header.empty()) header = tokens;
      continue;
    }
    if (!numeric) throw Error("line " + std::to_string(number) + " is not numeric", path.string());
    if (columns < 0) {
      columns = static_cast<int>(row.size());
      if (columns > 2) {
        const auto named = std::find(header.begin(), header.end(), channel);
        if (header.size() != row.size() || header.front() != "x" || named == header.end())
          throw Error("line " + std::to_string(number) + ": expected 1 (phi) or 2 (x,phi) columns, or a header "
                      "x," + channel + ",… naming the channel's column", path.string());
        channel_column = static_cast<int>(named - header.begin());
      }
    }
    if (static_cast<int>(row.size()) != columns)
      throw Error("line " + std::to_string(number) + ": " + std::to_string(row.size()) + " columns, the first row has " +
                  std::to_string(columns), path.string());
    if (columns >= 2) xs.push_back(row[0]);
    ys.push_back(channel_column >= 0 ? row[static_cast<std::size_t>(channel_column)] : row.back());
  }
  if (ys.size() < 2) throw Error("a curve table needs at least 2 samples", path.string());
  if (columns >= 2) {
    for (size_t i = 0; i < xs.size(); ++i)
      if (!std::isfinite(xs[i]) || (i > 0 && !(xs[i] > xs[i - 1])))
        throw Error("x column must be finite and increase", path.string());
    return resample(xs, ys, samples);
  }
  return evenSamples(ys, samples);
}

}  // namespace

std::vector<double> readCurveTable(const fs::path& path, const std::string& channel, int samples) {
  if (samples < 2) throw InvalidInput("a curve table is resampled to at least 2 points");
  std::vector<double> phi = readCurveSamples(path, channel, samples);
  // The one validation of curves (response_curve.hpp): chart --truth, table: specs and simulate agree.
  if (const ModelValidity validity = checkInverseSamples(phi); !validity)
    throw Error("not a valid inverse response: " + validity.reason, path.string());
  return phi;
}

ResponseModel parseResponseSpec(const std::string& spec, const std::string& channel) {
  if (spec.rfind("table:", 0) == 0) {
    const fs::path path = spec.substr(6);
    return TableModel{readCurveTable(path, channel)};
  }
  return crfcal::parseResponseSpec(spec);
}

std::optional<std::pair<double, double>> readCurveTableCoverage(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line) && !line.empty() && line[0] == '#') {
    const auto at = line.find("cover x in [");
    if (at == std::string::npos) continue;
    double lo = 0, hi = 0;
    if (std::sscanf(line.c_str() + at, "cover x in [%lf, %lf]", &lo, &hi) == 2) return std::make_pair(lo, hi);
  }
  return std::nullopt;
}

nlohmann::json modelToJson(const ResponseModel& model) {
  nlohmann::json json;
  json["kind"] = modelKind(model);
  std::visit(
      [&](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, GammaModel>) json["parameters"] = {m.gamma};
        if constexpr (std::is_same_v<T, GgcmModel>) json["parameters"] = m.alpha;
        if constexpr (std::is_same_v<T, EmorModel>) json["parameters"] = m.coefficients;
        if constexpr (std::is_same_v<T, TableModel>) json["samples"] = m.samples.size();
      },
      model);
  if (!std::holds_alternative<TableModel>(model)) json["spec"] = describe(model);
  return json;
}

}  // namespace crfcal::io
