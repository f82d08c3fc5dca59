// crfcal bench raw-truth: the per-pixel RAW→JPEG truth (calib/raw_truth.hpp, `calibrate --raw-truth`) on real data.
//  1. Middlebury (../shared/data/middlebury): every camera's JPEG and linear RAW rendering of the same chart shot,
//     one truth per shot, against the camera's bundled curve samples/camera_curves/<Camera>.csv (fitted by
//     `crfcal curves` from grey-patch medians of all 8 shots: same camera, independent method). Green channel φ
//     RMSE over the range both cover, plain and scale-aligned, and the per-pixel residual with and without the
//     colour-mixing row (raw_truth.hpp step 5). With --channels rgb also R and B, and how far each lies from G in
//     shape over the range both cover (the channels' tone curves: one curve for all three, up to a factor, or not).
//  2. raw_samples (../shared/data/raw_samples): every RAW LibRaw decodes against the preview the camera embedded in
//     the same file (io::readRawThumbnail): what happens, per file.
// Data from --data, $CRFCAL_SHARED_DATA or ../shared/data; parts whose folder is absent are skipped.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>

#include <nlohmann/json.hpp>

#include "bench_command.hpp"
#include "bench_statistics.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/raw_truth.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/chart_io.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/raw_image.hpp"
#include "crfcal/io/response_io.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct RawTruthBenchArgs {
  std::string data;
  std::string curves;  // directory of <Camera>.csv (default samples/camera_curves)
  bool per_shot = false;
  std::string channels = "g";  // g, or rgb: every channel's truth, and R and B against G in shape
  std::string json;
  bool quiet = false;
  bool force = false;  // --json/-o over files crfcal did not write (never deletes them)
};

// One camera's numbers over its shots.
struct CameraRow {
  std::string camera;
  int shots = 0, failed = 0;
  std::vector<double> aligned, covered, pixel, pointwise, explained;
  std::vector<double> red_vs_green, blue_vs_green;  // --channels rgb: shape RMSE against G, each shot
};

double maxOf(const std::vector<double>& v) {
  return v.empty() ? std::nan("") : *std::max_element(v.begin(), v.end());
}

// Every channel's truth into the shot's JSON entry, and R's and B's shape RMSE against G over the range both truths
// cover, after their best common factor (a white balance scales a channel: only the shape compares).
void recordChannelAgreement(const RawTruthResult& truth, nlohmann::json& entry, std::vector<double>& red_vs_green,
                            std::vector<double>& blue_vs_green) {
  const auto curves = truth.inverse();
  const auto covered = truth.covered();
  for (const auto& c : truth.channels)
    entry["channels"][c.channel] = {{"covered", {c.fit.covered_range.first, c.fit.covered_range.second}},
                                    {"inverse_crf", c.fit.inverse}};
  for (const char* name : {"R", "B"}) {
    const ChannelComparison shape =
        compareCurves(curves.at("G"), curves.at(name), covered.at("G"), covered.at(name));
    entry["channels"][name]["shape_rmse_vs_G"] = shape.rmse_covered_aligned;
    (name[0] == 'R' ? red_vs_green : blue_vs_green).push_back(shape.rmse_covered_aligned);
  }
}

void printChannelAgreement(const std::vector<CameraRow>& rows) {
  std::printf("\nper camera (--channels rgb; medians over shots, [max]): R and B against G in shape over the range "
              "both truths cover, after the best common factor\n| camera | R vs G | B vs G |\n|---|---|---|\n");
  std::vector<double> all;
  for (const auto& r : rows) {
    std::printf("| %s | %.4f [%.4f] | %.4f [%.4f] |\n", r.camera.c_str(), median(r.red_vs_green), maxOf(r.red_vs_green),
                median(r.blue_vs_green), maxOf(r.blue_vs_green));
    all.insert(all.end(), r.red_vs_green.begin(), r.red_vs_green.end());
    all.insert(all.end(), r.blue_vs_green.begin(), r.blue_vs_green.end());
  }
  std::printf("all shots, R and B: median %.4f, max %.4f\n", median(all), maxOf(all));
}

nlohmann::json runMiddlebury(const RawTruthBenchArgs& args, const fs::path& root, Progress& progress) {
  const fs::path curves = args.curves.empty() ? io::samplesDirectory() / "camera_curves" : fs::path(args.curves);
  nlohmann::json out = nlohmann::json::array();
  const auto cameras = io::listMiddleburyCameras(root);
  std::printf("\nMiddlebury: per-shot RAW->JPEG truth (G) vs the camera's bundled curve (%s)\n",
              curves.string().c_str());
  if (args.per_shot)
    std::printf("| camera | shot | covered | K | R^2 | pixel rmse (mix / pointwise) | RMSE covered | aligned | s |\n"
                "|---|---|---|---|---|---|---|---|---|\n");
  std::vector<CameraRow> rows;
  int done = 0, total = 0;
  for (const auto& camera : cameras) total += static_cast<int>(io::listMiddleburyShots(root / camera).size());
  for (const auto& camera : cameras) {
    CameraRow row;
    row.camera = camera;
    const fs::path table_path = curves / (camera + ".csv");
    std::vector<double> table;
    std::optional<IntensityRange> table_covered;
    if (fs::exists(table_path)) {
      table = io::readCurveTable(table_path);
      table_covered = io::readCurveTableCoverage(table_path);
    }
    for (const auto& shot : io::listMiddleburyShots(root / camera)) {
      progress.update(double(done++) / std::max(1, total), camera + " " + shot.name);
      ++row.shots;
      nlohmann::json entry = {{"camera", camera}, {"shot", shot.name}};
      try {
        const cv::Mat jpeg = io::readImage(shot.jpg), linear = io::readImage(shot.raw);
        RawTruthOptions options;
        if (args.channels == "rgb") options.channels = {"R", "G", "B"};
        else options.channels = {"G"};
        const auto t0 = Clock::now();
        const RawTruthResult truth = computeRawTruth(jpeg, linear, options);
        const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
        options.channels = {"G"};  // the pointwise comparison is of G alone
        options.colour_matrix = false;
        const RawTruthResult plain = computeRawTruth(jpeg, linear, options);
        const auto green = std::find_if(truth.channels.begin(), truth.channels.end(),
                                         [](const RawTruthChannel& c) { return c.channel == "G"; });
        if (green == truth.channels.end() || plain.channels.empty()) throw Error("no green channel in the RAW truth");
        const RawTruthChannel& g = *green;
        entry.update({{"covered", {g.fit.covered_range.first, g.fit.covered_range.second}},
                      {"terms", g.fit.terms},
                      {"explained", g.explained},
                      {"pixel_rmse", g.pixel_rmse},
                      {"pixel_rmse_pointwise", plain.channels[0].pixel_rmse},
                      {"mix", g.mix},
                      {"pixels", g.pixels},
                      {"seconds", seconds},
                      {"inverse_crf", g.fit.inverse}});
        if (args.channels == "rgb") recordChannelAgreement(truth, entry, row.red_vs_green, row.blue_vs_green);
        row.pixel.push_back(g.pixel_rmse);
        row.pointwise.push_back(plain.channels[0].pixel_rmse);
        row.explained.push_back(g.explained);
        double aligned = std::nan(""), covered = std::nan(""), scale = std::nan("");
        if (!table.empty()) {
          const ChannelComparison cmp = compareCurves(g.fit.inverse, table, g.fit.covered_range, table_covered);
          aligned = cmp.rmse_covered_aligned;
          covered = cmp.rmse_covered;
          scale = cmp.scale_covered;
          entry["vs_table"] = {{"rmse", cmp.rmse},
                               {"rmse_covered", cmp.rmse_covered},
                               {"rmse_covered_aligned", cmp.rmse_covered_aligned},
                               {"scale_covered", cmp.scale_covered},
                               {"covered", {cmp.covered.first, cmp.covered.second}}};
          row.aligned.push_back(aligned);
          row.covered.push_back(covered);
        }
        if (args.per_shot)
          std::printf("| %s | %s | [%.3f, %.3f] | %d | %.4f | %.4f / %.4f | %.4f | %.4f | %.3f |\n", camera.c_str(),
                      shot.name.c_str(), g.fit.covered_range.first, g.fit.covered_range.second, g.fit.terms,
                      g.explained, g.pixel_rmse, plain.channels[0].pixel_rmse, covered, aligned, scale);
      } catch (const Error& e) {
        ++row.failed;
        entry["error"] = e.what();
        if (args.per_shot) std::printf("| %s | %s | error: %s |\n", camera.c_str(), shot.name.c_str(), e.what());
      }
      out.push_back(entry);
    }
    rows.push_back(row);
  }
  std::printf("\nper camera (G; medians over shots, [max]): truth vs bundled table over the range both cover\n");
  std::printf("| camera | shots (failed) | R^2 | pixel rmse, colour mix | pixel rmse, pointwise | RMSE covered | "
              "RMSE covered, scale-aligned |\n|---|---|---|---|---|---|---|\n");
  std::vector<double> all_aligned, all_covered;
  for (const auto& r : rows) {
    std::printf("| %s | %d (%d) | %.4f | %.4f | %.4f | %.4f [%.4f] | %.4f [%.4f] |\n", r.camera.c_str(), r.shots,
                r.failed, median(r.explained), median(r.pixel), median(r.pointwise), median(r.covered),
                maxOf(r.covered), median(r.aligned), maxOf(r.aligned));
    all_aligned.insert(all_aligned.end(), r.aligned.begin(), r.aligned.end());
    all_covered.insert(all_covered.end(), r.covered.begin(), r.covered.end());
  }
  std::printf("all shots: RMSE covered median %.4f, scale-aligned median %.4f (max %.4f)\n", median(all_covered),
              median(all_aligned),
              all_aligned.empty() ? std::nan("") : *std::max_element(all_aligned.begin(), all_aligned.end()));
  if (args.channels == "rgb") printChannelAgreement(rows);
  return out;
}

nlohmann::json runRawSamples(const fs::path& root) {
  nlohmann::json out = nlohmann::json::array();
  std::printf("\nraw_samples: each RAW against the preview embedded in the same file\n");
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(root))
    if (e.is_regular_file() && io::isRawFile(e.path())) files.push_back(e.path());
  std::sort(files.begin(), files.end());
  for (const auto& file : files) {
    nlohmann::json entry = {{"file", file.filename().string()}};
    try {
      io::RawDecodeOptions raw;
      raw.half_size = true;
      const io::RawImage image = io::readRaw(file, raw);
      const cv::Mat preview = io::readRawThumbnail(file);
      entry["raw"] = image.summary();
      entry["preview_size"] = {preview.cols, preview.rows};
      const RawTruthResult truth = computeRawTruth(preview, image.image);
      std::printf("%s: %s; preview %dx%d\n%s", file.filename().string().c_str(), image.summary().c_str(), preview.cols,
                  preview.rows, truth.summary().c_str());
      for (const auto& c : truth.channels)
        entry["channels"][c.channel] = {{"covered", {c.fit.covered_range.first, c.fit.covered_range.second}},
                                        {"terms", c.fit.terms},
                                        {"explained", c.explained},
                                        {"pixel_rmse", c.pixel_rmse},
                                        {"effective_exponent", std::isfinite(c.effective_gamma)
                                                                   ? nlohmann::json(c.effective_gamma)
                                                                   : nlohmann::json(nullptr)},
                                        {"mix", c.mix},
                                        {"inverse_crf", c.fit.inverse}};
    } catch (const Error& e) {
      entry["error"] = e.what();
      std::printf("%s: %s\n", file.filename().string().c_str(), e.what());
    }
    out.push_back(entry);
  }
  if (files.empty()) std::printf("(no file LibRaw recognises)\n");
  return out;
}

int runRawTruthBench(const RawTruthBenchArgs& args) {
  Progress progress(args.quiet);
  const fs::path shared = io::defaultSharedData(args.data);
  const io::OutputPolicy policy{"bench raw-truth", {shared, args.curves}, args.force};
  if (!args.json.empty()) io::checkJsonOutputFile(args.json, policy);  // before the computation
  nlohmann::json json;
  bool any = false;
  if (fs::is_directory(shared / "middlebury")) {
    progress.stage("middlebury");
    json["middlebury"] = runMiddlebury(args, shared / "middlebury", progress);
    progress.done();
    any = true;
  } else {
    std::printf("Middlebury data not found at %s: skipped\n", (shared / "middlebury").string().c_str());
  }
  if (fs::is_directory(shared / "raw_samples")) {
    json["raw_samples"] = runRawSamples(shared / "raw_samples");
    any = true;
  } else {
    std::printf("raw_samples not found at %s: skipped\n", (shared / "raw_samples").string().c_str());
  }
  if (!any) std::printf("(give --data or set CRFCAL_SHARED_DATA)\n");
  if (!args.json.empty()) io::writeJsonOutput(args.json, json, policy.command);
  return kExitOk;
}

const BenchRegistration registration(
    45, "raw-truth",
    "Per-pixel RAW->JPEG truth (calibrate --raw-truth) on real data: Middlebury shots vs the bundled camera curves, "
    "RAW samples vs their embedded previews",
    [](CLI::App& command) {
      auto args = std::make_shared<RawTruthBenchArgs>();
      command.add_option("--data", args->data, "Shared data directory (default $CRFCAL_SHARED_DATA or ../shared/data)");
      command.add_option("--curves", args->curves, "Directory of camera curve tables (default samples/camera_curves)");
      command.add_flag("--per-shot", args->per_shot, "Print one row per shot");
      command.add_option("--channels", args->channels,
                         "Middlebury: g (the green truth only) or rgb (every channel's truth, and R and B against G in "
                         "shape)")
          ->check(CLI::IsMember({"g", "rgb"}));
      command.add_option("--json", args->json, "Write all numbers to this JSON file (atomic)");
      command.add_flag("--force", args->force, kForceHelp);
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runRawTruthBench(*args); };
    });

}  // namespace
}  // namespace crfcal::app
