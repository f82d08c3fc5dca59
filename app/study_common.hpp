#pragma once
// What the `crfcal study` subcommands share (cmd_study.cpp registers them; cmd_study_channels.cpp,
// cmd_study_noise.cpp, cmd_study_ratio.cpp, cmd_study_pairs.cpp run them): the arguments, the summary table assumption → misfit → cause →
// extended model → gain, and its writer.
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "crfcal/io/atomic_output.hpp"

namespace crfcal::app::study {

struct StudyArgs {
  std::string data;
  std::string output;
  bool quiet = false;
  bool force = false;  // write into an output directory holding other files (never deletes them)
  int knots = 12;      // channels
  int cases = 16;      // noise benchmark cases
  int images = 2;      // ratio sweep images
};

std::string fmt(double v, int precision = 3);  // fixed-point text
std::string pct(double v);                     // signed percentage text

struct SummaryRow {
  std::string assumption, misfit, cause, extended, gain;
};

struct StudyTable {
  std::string study;
  std::vector<SummaryRow> summary;
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  nlohmann::json extra = nlohmann::json::object();
};

// Prints the table and writes table.csv, details.csv and table.json into `out`.
void emit(const StudyTable& table, io::OutputDirectory& out);
// The shared data root (throws naming it when it or its `sub` folder is missing).
std::filesystem::path requireData(const StudyArgs& args, const std::string& sub);
// The G plane of an image in [0, 1], resized by `scale`.
cv::Mat greenUnit(const std::filesystem::path& path, double scale = 1.0);
double meanOf(const std::vector<double>& v);

int runChannels(const StudyArgs& args);
int runNoise(const StudyArgs& args);
int runRatio(const StudyArgs& args);
int runPairs(const StudyArgs& args);

}  // namespace crfcal::app::study
