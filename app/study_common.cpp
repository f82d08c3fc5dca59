// What the `crfcal study` subcommands share (study_common.hpp).
#include "study_common.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "command.hpp"
#include "crfcal/blur_model.hpp"
#include "crfcal/colour_mixing.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/exposure_fit.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_model.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/simulation.hpp"
#include "progress.hpp"

namespace crfcal::app::study {
namespace fs = std::filesystem;

std::string fmt(double v, int precision) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", precision, v);
  return buf;
}
std::string pct(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%+.1f%%", 100 * v);
  return buf;
}

namespace {

std::string csvEscape(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

void printTable(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  std::vector<size_t> width(header.size());
  for (size_t i = 0; i < header.size(); ++i) width[i] = header[i].size();
  for (const auto& r : rows)
    for (size_t i = 0; i < r.size() && i < width.size(); ++i) width[i] = std::max(width[i], r[i].size());
  auto line = [&](const std::vector<std::string>& r) {
    for (size_t i = 0; i < header.size(); ++i)
      std::printf("%-*s%s", static_cast<int>(width[i]), i < r.size() ? r[i].c_str() : "", i + 1 < header.size() ? "  " : "\n");
  };
  line(header);
  for (const auto& r : rows) line(r);
}

}  // namespace

void emit(const StudyTable& table, io::OutputDirectory& out) {
  std::printf("\n== study %s: assumption -> misfit -> cause -> extended model -> gain\n", table.study.c_str());
  for (const auto& s : table.summary) {
    std::printf("  assumption: %s\n  misfit:     %s\n  cause:      %s\n  extended:   %s\n  gain:       %s\n\n",
                s.assumption.c_str(), s.misfit.c_str(), s.cause.c_str(), s.extended.c_str(), s.gain.c_str());
  }
  std::printf("-- details\n");
  printTable(table.header, table.rows);
  std::ostringstream csv;
  csv << "assumption,measured_misfit,named_cause,extended_model,measured_gain\n";
  for (const auto& s : table.summary)
    csv << csvEscape(s.assumption) << ',' << csvEscape(s.misfit) << ',' << csvEscape(s.cause) << ','
        << csvEscape(s.extended) << ',' << csvEscape(s.gain) << '\n';
  io::writeTextFile(out.file("table.csv"), csv.str());
  std::ostringstream det;
  for (size_t i = 0; i < table.header.size(); ++i) det << (i ? "," : "") << csvEscape(table.header[i]);
  det << '\n';
  for (const auto& r : table.rows) {
    for (size_t i = 0; i < r.size(); ++i) det << (i ? "," : "") << csvEscape(r[i]);
    det << '\n';
  }
  io::writeTextFile(out.file("details.csv"), det.str());
  nlohmann::json j;
  j["study"] = table.study;
  j["summary"] = nlohmann::json::array();
  for (const auto& s : table.summary)
    j["summary"].push_back({{"assumption", s.assumption}, {"measured_misfit", s.misfit}, {"named_cause", s.cause},
                            {"extended_model", s.extended}, {"measured_gain", s.gain}});
  j["details"] = {{"header", table.header}, {"rows", table.rows}};
  j["extra"] = table.extra;
  io::writeTextFile(out.file("table.json"), j.dump(2) + "\n");
}

fs::path requireData(const StudyArgs& args, const std::string& sub) {
  const fs::path root = io::defaultSharedData(args.data);
  if (!fs::is_directory(root))
    throw Error("shared data directory not found (give --data DIR or set CRFCAL_SHARED_DATA)", root.string());
  const fs::path dir = root / sub;
  if (!fs::is_directory(dir)) throw Error("dataset folder missing", dir.string());
  return root;
}

cv::Mat greenUnit(const fs::path& path, double scale) {
  const cv::Mat image = io::readColorImage(path);
  cv::Mat g;
  cv::extractChannel(image, g, 1);
  if (scale != 1.0) cv::resize(g, g, cv::Size(), scale, scale, cv::INTER_AREA);
  cv::Mat out;
  g.convertTo(out, CV_64F, 1.0 / 255);
  return out;
}

double meanOf(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / double(v.size());
}

}  // namespace crfcal::app::study
