// crfcal bench references: the static references of issue 21 side by side on real cameras — OpenCV's
// CalibrateDebevec / CalibrateRobertson (calib/opencv_calibrators.hpp, as `bench bracket` calls them), `crfcal chart`
// (calibrateChart, as `bench chart`), `crfcal chart` with the exposures given, and `crfcal bracket` (calibrateBracket)
// — on the same 4 JPEG shots of each Middlebury camera and scene, scored against the camera's RAW→JPEG truth
// (`crfcal chart JPEG… --raw RAW…` on all its shots, as `bench chart`). The exposure times OpenCV's calibrators need
// (and the "exposures given" rows) come from the linear RAW shots' grey patches.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <map>
#include <memory>

#include <nlohmann/json.hpp>

#include "bench_command.hpp"
#include "bench_statistics.hpp"
#include "crfcal/bracket_calibration.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/chart_calibration.hpp"
#include "crfcal/colorchecker.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/opencv_calibrators.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/chart_io.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/output_guard.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

namespace fs = std::filesystem;

struct ReferencesBenchArgs {
  std::string data;  // shared data root holding middlebury/; default $CRFCAL_SHARED_DATA or ../shared/data
  std::string json;
  bool force = false;
  bool quiet = false;
  bool curves = false;
  // The RAW truth's scale: one per camera and scene (the light changes the RAW-to-JPEG gain of R and B) or one per
  // camera (before issue 21's second round).
  std::string truth_scale = "scene";
  // The shots' relative exposures from the RAW: neighbours' ratios over all patches, or each shot's greys against
  // their published reflectances (before issue 21's second round).
  std::string raw_exposures = "patches";  // the JSON also holds every method's curves and the truth's samples (for analysis)
};

// One scene of one camera: its 4 exposures (JPEG frames, their sampled patches) and the RAW-derived exposures.
struct SceneShots {
  std::string camera;
  int scene = 0;
  std::vector<cv::Mat> frames;       // BGR 8-bit JPEG renderings (the rectified chart)
  std::vector<ChartShot> shots;      // measured = JPEG patches, raw = RAW patches
  std::vector<double> exposures;     // relative, from the RAW greys
};

// Relative exposure of each shot from its linear RAW greys: per channel the median over usable greys of
// log(raw / Y), averaged over the channels (each channel's white-balance factor is the same in every shot).
std::vector<double> rawExposures(const std::vector<ChartShot>& shots) {
  std::vector<double> exposures;
  for (const auto& shot : shots) {
    double sum = 0;
    int channels = 0;
    for (size_t c = 0; c < 3; ++c) {
      std::vector<double> logs;
      for (int p = 0; p < chart::kPatches; ++p) {
        const auto& ref = chart::reference()[static_cast<size_t>(p)];
        const chart::PatchStats& raw = shot.raw[static_cast<size_t>(p)];
        if (ref.neutral && raw.usable() && raw.median[c] > 0.01) logs.push_back(std::log(raw.median[c] / ref.Y));
      }
      if (logs.empty()) continue;
      std::sort(logs.begin(), logs.end());
      sum += logs[logs.size() / 2];
      ++channels;
    }
    if (channels == 0) throw InvalidInput("no usable grey patch in the RAW shot", shot.name);
    exposures.push_back(std::exp(sum / channels));
  }
  return exposures;
}

// Relative exposure of each shot from its linear RAW patches alone: shots in order of the grey-based estimate
// (rawExposures), each neighbour's ratio the median over the patches and channels usable and above the noise floor
// in both of log(raw_next / raw), chained. Unlike rawExposures this needs no published reflectance: a patch whose
// real reflectance differs from the published Y biases the greys' estimate of the shots in which it is usable
// (the set of usable greys changes with the exposure), and that bias changes the exposure span, i.e. the exponent
// every calibrator given these exposures recovers.
std::vector<double> rawExposureRatios(const std::vector<ChartShot>& shots) {
  const std::vector<double> by_greys = rawExposures(shots);
  std::vector<size_t> order(shots.size());
  for (size_t j = 0; j < order.size(); ++j) order[j] = j;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return by_greys[a] < by_greys[b]; });
  std::vector<double> exposures(shots.size(), 1.0);
  constexpr double kFloor = 0.02;  // RAW values below this (unit scale) are left to the noise floor
  for (size_t k = 1; k < order.size(); ++k) {
    const ChartShot& dark = shots[order[k - 1]];
    const ChartShot& bright = shots[order[k]];
    std::vector<double> logs;
    for (int p = 0; p < chart::kPatches; ++p) {
      const chart::PatchStats& a = dark.raw[static_cast<size_t>(p)];
      const chart::PatchStats& b = bright.raw[static_cast<size_t>(p)];
      if (!a.usable() || !b.usable()) continue;
      for (size_t c = 0; c < 3; ++c)
        if (a.median[c] > kFloor && b.median[c] > kFloor) logs.push_back(std::log(b.median[c] / a.median[c]));
    }
    const double ratio = by_greys[order[k]] / by_greys[order[k - 1]];
    if (logs.size() < 3) {  // too few patches in common: the greys' ratio
      exposures[order[k]] = exposures[order[k - 1]] * ratio;
      continue;
    }
    std::nth_element(logs.begin(), logs.begin() + long(logs.size() / 2), logs.end());
    exposures[order[k]] = exposures[order[k - 1]] * std::exp(logs[logs.size() / 2]);
  }
  return exposures;
}

struct Method {
  std::string name;
  std::vector<double> error[3];   // shape error per case and channel
  std::vector<double> cpu_seconds, wall_seconds;
  int failed = 0;
  // RGB mean shape error per case that has all three channels, split as `bench chart` splits the cameras: cameras
  // 1, 3, 5, … in name order are where choices are made, 2, 4, 6, … where they are reported.
  std::vector<double> rgb_choose, rgb_report;
  // Methods with a band (crfcal's, scaled_fit_band.hpp): shape-band samples of the scored range and how many hold the
  // truth (after its best common scale), and the band's median shape width there, per case and channel.
  int band_samples = 0, band_hits = 0;
  std::vector<double> band_width;
};

// The band's shape coverage of the truth over the scored range only (the RAW truth is itself a fit, valid where its
// shots have grey patches): the band's covered range replaced by that range, then curve_band.hpp's scoreBand.
void scoreBandOnRange(Method& method, const CurveBand& band, const std::vector<double>& phi,
                      const std::vector<double>& truth, IntensityRange range) {
  if (band.empty() || !(range.second > range.first)) return;
  CurveBand on_range = band;
  on_range.covered = range;
  const BandScore score = scoreBand(on_range, phi, truth);
  method.band_samples += score.inside;
  method.band_hits += score.shape_hits;
  method.band_width.push_back(score.median_shape_width_inside);
}

// The range every method is scored on, per channel: the truth's covered range ∩ the range of the usable patch values
// of the 4 JPEG shots (what any method could have seen).
IntensityRange scoredRange(const SceneShots& scene, int c, IntensityRange truth_covered) {
  double lo = 1, hi = 0;
  for (const auto& shot : scene.shots)
    for (const auto& p : shot.measured)
      if (p.usable()) lo = std::min(lo, p.median[static_cast<size_t>(c)]), hi = std::max(hi, p.median[static_cast<size_t>(c)]);
  return {std::max(lo, truth_covered.first), std::min(hi, truth_covered.second)};
}

// Runs one method on one scene (timed) and records its three channels' shape errors.
// `bands`: filled by `calibrate` for the methods that have bands (one per channel), else null.
template <typename Calibrate>
void runMethod(Method& method, const Calibrate& calibrate, const ChartCalibrationResult& truth, const SceneShots& scene,
               bool choose_camera, nlohmann::json& row, bool with_curves, const std::vector<CurveBand>* bands = nullptr) {
  const auto wall = std::chrono::steady_clock::now();
  const std::clock_t cpu = std::clock();
  std::vector<std::vector<double>> curves;
  try {
    curves = calibrate();
  } catch (const InvalidInput& e) {
    ++method.failed;
    row[method.name] = {{"error", e.what()}};
    return;
  }
  method.cpu_seconds.push_back(double(std::clock() - cpu) / CLOCKS_PER_SEC);
  method.wall_seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - wall).count());
  bool finite = true;
  double sum = 0;
  for (int c = 0; c < 3; ++c) {
    const auto& t = truth.channels[static_cast<size_t>(c)].fit;
    const IntensityRange range = scoredRange(scene, c, t.covered_range);
    const double e = shapeError(t.inverse, curves[static_cast<size_t>(c)], range);
    if (bands && static_cast<size_t>(c) < bands->size())
      scoreBandOnRange(method, (*bands)[static_cast<size_t>(c)], curves[static_cast<size_t>(c)], t.inverse, range);
    if (std::isfinite(e)) method.error[c].push_back(e);
    finite = finite && std::isfinite(e);
    sum += e;
    row[method.name][channelName(c)] = std::isfinite(e) ? nlohmann::json(e) : nlohmann::json(nullptr);
  }
  method.failed += !finite;
  if (finite) (choose_camera ? method.rgb_choose : method.rgb_report).push_back(sum / 3);
  if (with_curves) row["curves"][method.name] = curves;
}

// `crfcal chart` (its default --reference all) on the scene's JPEG shots (patch sampling included in the time), with or without exposures.
std::vector<std::vector<double>> chartCurves(const SceneShots& scene, bool exposures_given,
                                             std::vector<CurveBand>& bands) {
  std::vector<ChartShot> shots;
  for (size_t j = 0; j < scene.frames.size(); ++j) {
    ChartShot shot;
    shot.name = scene.shots[j].name;
    shot.scene = scene.scene;
    shot.measured = chart::sampleRectified(scene.frames[j]);
    if (exposures_given) shot.exposure = scene.exposures[j];
    shots.push_back(std::move(shot));
  }
  ChartCalibrationOptions options;
  options.reference = chart::ReferenceSet::AllPatches;  // `crfcal chart`'s default
  const ChartCalibrationResult result = calibrateChart(shots, options);
  std::vector<std::vector<double>> curves;
  bands.clear();
  for (const auto& c : result.channels) curves.push_back(c.fit.inverse), bands.push_back(c.band);
  return curves;
}

std::vector<SceneShots> loadScenes(const fs::path& root, bool truth_scale_per_scene, bool exposures_from_patches,
                                   std::vector<ChartCalibrationResult>& truths, std::vector<size_t>& truth_of,
                                   Progress& progress) {
  std::vector<SceneShots> scenes;
  const std::vector<std::string> cameras = io::listMiddleburyCameras(root);
  for (size_t i = 0; i < cameras.size(); ++i) {
    std::map<int, SceneShots> by_scene;
    std::vector<ChartShot> all;
    for (const auto& shot : io::listMiddleburyShots(root / cameras[i])) {
      SceneShots& scene = by_scene[shot.scene];
      scene.camera = cameras[i];
      scene.scene = shot.scene;
      const cv::Mat jpg = io::loadChart(shot.jpg, io::ChartLayout::Rectified).rectified;
      ChartShot s;
      s.name = shot.name;
      s.scene = shot.scene;
      s.measured = chart::sampleRectified(jpg);
      s.raw = chart::sampleRectified(io::loadChart(shot.raw, io::ChartLayout::Rectified).rectified);
      scene.frames.push_back(jpg);
      scene.shots.push_back(s);
      all.push_back(s);
    }
    // The truth: `crfcal chart JPEG… --raw RAW…` on all the camera's shots (grey patches, one RAW scale).
    ChartCalibrationOptions truth_options;
    truth_options.use_raw = true;
    truth_options.raw_neutral_only = true;
    truth_options.raw_scale_per_scene = truth_scale_per_scene;
    truths.push_back(calibrateChart(all, truth_options));
    for (auto& [id, scene] : by_scene) {
      scene.exposures = exposures_from_patches ? rawExposureRatios(scene.shots) : rawExposures(scene.shots);
      scenes.push_back(std::move(scene));
      truth_of.push_back(i);
    }
    progress.update(double(i + 1) / double(cameras.size()), cameras[i]);
  }
  return scenes;
}

// The table and the targets' verdicts.
nlohmann::json printTable(const std::vector<Method>& methods, size_t scenes, const fs::path& root) {
  std::printf("\nStatic references on the Middlebury ColorChecker shots (%s): %zu camera scenes x 4 exposures, JPEG vs "
              "the camera's RAW->JPEG truth; exposure times for OpenCV (and 'exposures given') from the RAW greys\n",
              root.string().c_str(), scenes);
  std::printf("shape RMSE over the covered range (truth's ∩ the shots' patch values) after the best common factor\n");
  std::printf("| method | R | G | B | RGB mean | RGB choose | RGB report | R/G | B/G | failed | CPU s median | CPU s max | "
              "wall s median |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  nlohmann::json json = nlohmann::json::object();
  std::map<std::string, double> rgb;
  for (const Method& m : methods) {
    std::vector<double> all;
    for (int c = 0; c < 3; ++c) all.insert(all.end(), m.error[c].begin(), m.error[c].end());
    const double R = mean(m.error[0]), G = mean(m.error[1]), B = mean(m.error[2]);
    rgb[m.name] = mean(all);
    const double cpu_max = m.cpu_seconds.empty() ? std::nan("") : *std::max_element(m.cpu_seconds.begin(), m.cpu_seconds.end());
    std::printf("| %s | %.4f | %.4f | %.4f | %.4f | %.4f | %.4f | %.2f | %.2f | %d | %.3f | %.3f | %.3f |\n",
                m.name.c_str(), R, G, B, mean(all), mean(m.rgb_choose), mean(m.rgb_report), R / G, B / G, m.failed,
                median(m.cpu_seconds), cpu_max, median(m.wall_seconds));
    json[m.name] = {{"R", R}, {"G", G}, {"B", B}, {"rgb_mean", mean(all)},
                    {"rgb_choose", mean(m.rgb_choose)}, {"rgb_report", mean(m.rgb_report)}, {"failed", m.failed},
                    {"cpu_seconds_median", median(m.cpu_seconds)}, {"cpu_seconds_max", cpu_max},
                    {"wall_seconds_median", median(m.wall_seconds)}};
  }
  std::printf("\ncrfcal's 90 %% bands (scaled_fit_band.hpp) against the RAW truth over the scored range, pooled over "
              "scenes and channels (target 85-95 %%; median shape width <= 0.02):\n");
  std::printf("| method | shape band holds the truth | samples | median shape width |\n|---|---|---|---|\n");
  for (const Method& m : methods) {
    if (m.band_samples == 0) continue;
    const double coverage = 100.0 * m.band_hits / m.band_samples;
    std::printf("| %s | %.1f %% | %d | %.4f |\n", m.name.c_str(), coverage, m.band_samples, median(m.band_width));
    json[m.name]["band_shape_coverage"] = coverage;
    json[m.name]["band_median_shape_width"] = median(m.band_width);
  }
  const double debevec = rgb["OpenCV Debevec"];
  std::printf("\n");
  for (const Method& m : methods) {
    if (m.name.rfind("crfcal", 0) != 0) continue;
    const double R = mean(m.error[0]), G = mean(m.error[1]), B = mean(m.error[2]);
    const bool shape = rgb[m.name] <= 0.5 * debevec, balance = R <= 1.5 * G && B <= 1.5 * G;
    const bool fast = median(m.cpu_seconds) <= 0.4;
    std::printf("%s: RGB <= 1/2 Debevec's (%.4f vs %.4f, ratio %.2f): %s; R and B within 1.5x of G: %s; "
                "<= 0.4 s per call (median CPU %.3f s): %s\n",
                m.name.c_str(), rgb[m.name], debevec, rgb[m.name] / debevec, shape ? "met" : "not met",
                balance ? "met" : "not met", median(m.cpu_seconds), fast ? "met" : "not met");
  }
  return json;
}

int runReferencesBench(const ReferencesBenchArgs& args) {
  const fs::path root = io::defaultSharedData(args.data) / "middlebury";
  const io::OutputPolicy policy{"bench references", {io::defaultSharedData(args.data)}, args.force};
  if (!args.json.empty()) io::checkJsonOutputFile(args.json, policy);
  if (!fs::is_directory(root)) {
    std::printf("Middlebury data not found at %s (give --data or set CRFCAL_SHARED_DATA): skipped\n",
                root.string().c_str());
    return kExitOk;
  }
  Progress progress(args.quiet);
  progress.stage("load and truth");
  std::vector<ChartCalibrationResult> truths;
  std::vector<size_t> truth_of;
  const std::vector<SceneShots> scenes = loadScenes(root, args.truth_scale == "scene", args.raw_exposures == "patches", truths, truth_of, progress);
  progress.done();
  std::vector<Method> methods;
  for (const char* name : {"OpenCV Debevec", "OpenCV Robertson", "crfcal chart", "crfcal chart, exposures given",
                           "crfcal bracket"}) {
    methods.emplace_back();
    methods.back().name = name;
  }
  nlohmann::json cases = nlohmann::json::array();
  progress.stage("calibrate");
  for (size_t i = 0; i < scenes.size(); ++i) {
    const SceneShots& scene = scenes[i];
    const ChartCalibrationResult& truth = truths[truth_of[i]];
    const bool choose = truth_of[i] % 2 == 0;  // cameras 1, 3, 5, … in name order
    nlohmann::json row{{"camera", scene.camera}, {"scene", scene.scene}, {"exposures", scene.exposures}};
    for (const auto calibrator : {OpenCvCalibrator::Debevec, OpenCvCalibrator::Robertson})
      runMethod(methods[calibrator == OpenCvCalibrator::Debevec ? 0 : 1],
                [&] { return opencvInverseResponse(scene.frames, scene.exposures, calibrator); }, truth, scene, choose, row, args.curves);
    std::vector<CurveBand> bands;
    runMethod(methods[2], [&] { return chartCurves(scene, false, bands); }, truth, scene, choose, row, args.curves, &bands);
    runMethod(methods[3], [&] { return chartCurves(scene, true, bands); }, truth, scene, choose, row, args.curves, &bands);
    nlohmann::json bracket_fit = nlohmann::json::object();  // per channel: the data's covered range, points, K
    runMethod(methods[4], [&] {
      std::vector<BracketFrame> frames;
      for (size_t j = 0; j < scene.frames.size(); ++j)
        frames.push_back({scene.shots[j].name, scene.frames[j], scene.exposures[j]});
      const BracketCalibrationResult result = calibrateBracket(frames);
      std::vector<std::vector<double>> curves;
      bands.clear();
      for (const auto& c : result.channels) {
        curves.push_back(c.fit.inverse);
        bands.push_back(c.band);
        bracket_fit[channelName(c.channel)] = {{"covered_range", {c.fit.covered_range.first, c.fit.covered_range.second}},
                                               {"points", c.points}, {"terms", c.fit.terms}};
      }
      return curves;
    }, truth, scene, choose, row, args.curves, &bands);
    if (!bracket_fit.empty()) row["crfcal bracket"]["fit"] = bracket_fit;
    if (args.curves)
      for (int c = 0; c < 3; ++c) {
        const ChartChannelResult& t = truth.channels[static_cast<size_t>(c)];
        nlohmann::json samples = nlohmann::json::array();
        for (const auto& p : t.patches) samples.push_back({p.shot, p.patch, p.x, p.reference});
        const IntensityRange range = scoredRange(scene, c, t.fit.covered_range);
        row["truth"][channelName(c)] = {{"inverse", t.fit.inverse}, {"samples", samples}, {"terms", t.fit.terms},
                                        {"scored_range", {range.first, range.second}}};
      }
    cases.push_back(row);
    progress.update(double(i + 1) / double(scenes.size()), scene.camera);
  }
  progress.done();
  const nlohmann::json summary = printTable(methods, scenes.size(), root);
  if (!args.json.empty()) io::writeJsonOutput(args.json, {{"summary", summary}, {"cases", cases}}, policy.command);
  return kExitOk;
}

const BenchRegistration registration(
    47, "references",
    "The static references side by side on the Middlebury cameras' 4-exposure chart shots: OpenCV Debevec / "
    "Robertson, crfcal chart (with and without exposures), crfcal bracket; shape error vs RAW->JPEG truth, time",
    [](CLI::App& command) {
      auto args = std::make_shared<ReferencesBenchArgs>();
      command.add_option("--data", args->data,
                         "Shared data directory holding middlebury/ (default $CRFCAL_SHARED_DATA or ../shared/data)");
      command.add_option("--json", args->json, "Write all numbers to this JSON file (atomic)");
      command.add_flag("--curves", args->curves,
                       "With --json: also write each method's curves and the RAW truth's curve and samples per case");
      command.add_option("--truth-scale", args->truth_scale,
                         "The RAW truth's unknown scale: one per camera and scene (the light changes the RAW-to-JPEG "
                         "gain) or one per camera")
          ->check(CLI::IsMember({"scene", "camera"}));
      command.add_option("--raw-exposures", args->raw_exposures,
                         "The shots' exposures (for OpenCV, 'exposures given' and the bracket) from the RAW: "
                         "neighbouring shots' ratios over all patches, or each shot's greys against their published "
                         "reflectances")
          ->check(CLI::IsMember({"patches", "greys"}));
      command.add_flag("--force", args->force, kForceHelp);
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runReferencesBench(*args); };
    });

}  // namespace
}  // namespace crfcal::app
