// crfcal curves middlebury: the real cameras' inverse responses (RAW → JPEG) bundled for the synthetic benchmark.
#include <cstdio>
#include <sstream>

#include <nlohmann/json.hpp>

#include "command.hpp"
#include "crfcal/chart_calibration.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/chart_io.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/plot.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

struct CurvesArgs {
  std::string data;
  std::string output;
  std::string channel = "G";
  int terms = 0;
  int max_terms = 7;
  bool per_shot_scale = false;
  std::string patches = "neutral";
  double smoothness = 0.01;
  // The bundled samples/camera_curves tables (used by the synthetic benchmark) were fitted without the
  // local-exponent penalty; 0 keeps this command reproducing them. `crfcal chart` uses 1e-4 (see
  // ScaledFitOptions::exponent_smoothness and docs/RESULTS.md#chart for the difference).
  double exponent_smoothness = 0;
  bool quiet = false;
  bool force = false;  // write into an output directory holding other files (never deletes them)
};

int runCurvesMiddlebury(const CurvesArgs& args) {
  const int channel = args.channel == "R" ? 0 : args.channel == "B" ? 2 : 1;
  const auto cameras = io::listMiddleburyCameras(args.data);
  if (cameras.empty()) throw Error("no camera folders with *-jpg.png / *-raw.png pairs", args.data);
  Progress progress(args.quiet);
  io::OutputDirectory out(args.output, {"curves middlebury", {args.data}, args.force});
  nlohmann::json summary = nlohmann::json::object();
  std::vector<io::PlotSeries> series;
  std::vector<double> grid(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) grid[static_cast<size_t>(i)] = double(i) / (kCurveSamples - 1);
  std::printf("%-20s %2s %5s %9s %9s %9s %15s %5s\n", "camera", "K", "n", "rmse", "max", "cv_rmse", "covered x", "rej");
  int index = 0;
  for (const auto& camera : cameras) {
    progress.stage("fit " + camera);
    std::vector<ChartShot> shots;
    for (const auto& shot : io::listMiddleburyShots(std::filesystem::path(args.data) / camera)) {
      ChartShot s;
      s.name = shot.name;
      s.measured = chart::sampleRectified(io::loadChart(shot.jpg, io::ChartLayout::Rectified).rectified);
      s.raw = chart::sampleRectified(io::loadChart(shot.raw, io::ChartLayout::Rectified).rectified);
      shots.push_back(std::move(s));
    }
    ChartCalibrationOptions options;
    options.use_raw = true;
    options.raw_common_scale = !args.per_shot_scale;
    options.channels = {channel};
    options.fit.terms = args.terms;
    options.fit.max_terms = args.max_terms;
    options.fit.smoothness = args.smoothness;
    options.fit.exponent_smoothness = args.exponent_smoothness;
    options.raw_neutral_only = args.patches == "neutral";
    const ChartCalibrationResult result = calibrateChart(shots, options);
    const ChartChannelResult& fit = result.channels.front();
    const ModelValidity validity = checkValidity(TableModel{fit.fit.inverse}, 4096, 1e-9);
    if (!validity) throw Error(camera + ": fitted curve is not a valid inverse response: " + validity.reason);
    double cv_best = 0;
    for (const auto& [k, e] : fit.fit.cv_rmse)
      if (k == fit.fit.terms) cv_best = e;
    std::ostringstream comment;
    comment << "x,phi  inverse response phi (" << args.channel << " channel) of the " << camera
            << ": x = camera JPEG value / 255, phi = linear RAW value / RAW value at x = 1 (phi(0)=0, phi(1)=1)\n"
            << "fitted by `crfcal curves middlebury` from the Middlebury RAW-vs-JPEG ColorChecker shots (Chakrabarti et "
               "al. 2009, via Zhao et al. 2022): medians of the "
            << (args.patches == "neutral" ? "6 grey patches" : "24 patches") << " of " << shots.size()
            << " shots, EMoR K="
            << fit.fit.terms << " (leave-one-shot-out CV), monotone, joint RAW scale, smoothness " << args.smoothness
            << ", exponent smoothness " << args.exponent_smoothness << "\n"
            << "fit rmse " << fit.fit.rmse << " over " << fit.fit.observations << " patch samples; data cover x in ["
            << fit.fit.covered_range.first << ", " << fit.fit.covered_range.second
            << "], outside that the curve is the EMoR model's extrapolation; see PROVENANCE.md";
    io::writeCurveCsv(out.file(camera + ".csv"), fit.fit.inverse, comment.str());
    nlohmann::json entry;
    entry["terms"] = fit.fit.terms;
    entry["emor"] = fit.fit.model.coefficients;
    entry["rmse"] = fit.fit.rmse;
    entry["max_error"] = fit.fit.max_error;
    entry["cv_rmse"] = nlohmann::json::object();
    for (const auto& [k, e] : fit.fit.cv_rmse) entry["cv_rmse"][std::to_string(k)] = e;
    entry["covered_range"] = {fit.fit.covered_range.first, fit.fit.covered_range.second};
    entry["observations"] = fit.fit.observations;
    entry["rejected"] = fit.rejected;
    entry["scales"] = fit.fit.scales;
    entry["shots"] = shots.size();
    summary[camera] = entry;
    std::printf("%-20s %2d %5d %9.5f %9.5f %9.5f  [%.3f, %.3f] %5d\n", camera.c_str(), fit.fit.terms,
                fit.fit.observations, fit.fit.rmse, fit.fit.max_error, cv_best, fit.fit.covered_range.first,
                fit.fit.covered_range.second, fit.rejected);
    series.push_back({grid, fit.fit.inverse, io::seriesColor(index++), camera, 2, false, false});
    io::writeChartPlot(out.file(camera + "_fit.png"), result,
                       camera + ": patches (JPEG, RAW / s) and fitted phi, " + args.channel);
    progress.done();
  }
  io::PlotOptions plot;
  plot.title = "Middlebury cameras: inverse response (" + args.channel + ", RAW vs JPEG)";
  plot.x_label = "JPEG value / 255";
  plot.y_label = "normalised RAW";
  plot.x_min = 0;
  plot.x_max = 1;
  plot.y_min = 0;
  plot.y_max = 1;
  plot.size = cv::Size(900, 700);
  io::writePlot(out.file("curves.png"), series, plot);
  io::writeTextFile(out.file("fit_summary.json"), summary.dump(2) + "\n");
  out.commit();
  std::printf("wrote %s/{<Camera>.csv, <Camera>_fit.png, curves.png, fit_summary.json}\n", args.output.c_str());
  return kExitOk;
}

const CommandRegistration registration(
    45, "curves", "Fit real cameras' inverse responses from RAW-vs-JPEG chart shots (benchmark curves)",
    [](CLI::App& command) {
      auto args = std::make_shared<CurvesArgs>();
      command.require_subcommand(1);
      CLI::App* middlebury = command.add_subcommand(
          "middlebury", "Middlebury RAW/JPEG ColorChecker dataset: one <Camera>.csv per camera folder of DIR");
      middlebury->add_option("--data", args->data, "Dataset root (folders <Camera>/wb1i*e*-{jpg,raw}.png)")
          ->required()
          ->check(CLI::ExistingDirectory);
      middlebury->add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")
          ->required();
      middlebury->add_flag("--force", args->force, kForceHelp);
      middlebury->add_option("--channel", args->channel, "Colour channel")->check(CLI::IsMember({"R", "G", "B"}));
      middlebury->add_option("--terms", args->terms, "EMoR terms K (0 = leave-one-shot-out cross-validation)")
          ->check(CLI::Range(0, 25));
      middlebury->add_option("--max-terms", args->max_terms, "Largest K tried by cross-validation")
          ->check(CLI::Range(1, 25));
      middlebury->add_option("--patches", args->patches,
                             "Patches used: all 24, or the 6 neutral ones (no colour-matrix crosstalk)")
          ->check(CLI::IsMember({"all", "neutral"}));
      middlebury->add_option("--smoothness", args->smoothness,
                             "Roughness penalty weight (ScaledFitOptions::smoothness)")
          ->check(CLI::NonNegativeNumber);
      middlebury->add_option("--exponent-smoothness", args->exponent_smoothness,
                             "Local-exponent penalty weight (ScaledFitOptions::exponent_smoothness; 0 reproduces the "
                             "bundled samples/camera_curves, crfcal chart uses 1e-4)")
          ->check(CLI::NonNegativeNumber);
      middlebury->add_flag("--per-shot-scale", args->per_shot_scale,
                           "One free RAW scale per shot instead of one per camera");
      middlebury->add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runCurvesMiddlebury(*args); };
    });

}  // namespace
}  // namespace crfcal::app
