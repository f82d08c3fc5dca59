// crfcal calibrate SHARP BLURRED -o DIR: a real handheld JPEG or RAW pair in, the camera's response out (Sec. 4).
#include <chrono>
#include <cstdio>
#include <memory>
#include <sstream>

#include <opencv2/core.hpp>
#include <nlohmann/json.hpp>

#include "command.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/pair_calibration.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

struct CalibrateArgs {
  std::string first, second, output;
  std::string channels = "rgb";
  std::string model = "auto";
  double ratio = 0;  // 0: from EXIF
  int kernel_size = 35;
  std::string kernel_file;
  int threads = 0;
  int rounds = 2;
  std::string blurred = "auto";
  bool no_white_balance = false;
  bool no_register = false;
  bool quiet = false;
};

int runCalibrate(const CalibrateArgs& args) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  if (args.threads > 0) cv::setNumThreads(args.threads);
  Progress progress(args.quiet);
  io::CalibrationReport report;
  report.command = "calibrate";

  progress.stage("decode");
  auto t = Clock::now();
  io::RawDecodeOptions raw;
  raw.camera_white_balance = !args.no_white_balance;
  const io::BlurredChoice choice = args.blurred == "first"    ? io::BlurredChoice::first
                                   : args.blurred == "second" ? io::BlurredChoice::second
                                                              : io::BlurredChoice::automatic;
  const io::LoadedPair pair = io::loadPair(args.first, args.second, choice, raw);
  report.timings["decode"] = std::chrono::duration<double>(Clock::now() - t).count();
  progress.done(pair.sharp.format + " pair " + std::to_string(pair.blurred.image.cols) + "x" +
                std::to_string(pair.blurred.image.rows) + "; blurred = " + pair.blurred.path.filename().string() +
                " (" + pair.blurred_reason + ")");

  // Exposure ratio (footnote 4).
  double ratio = args.ratio;
  if (pair.exif_ratio) {
    report.ratio_exif = pair.exif_ratio->ratio();
    std::fprintf(stderr, "  exif: sharp %s; blurred %s\n  exif: %s\n", pair.sharp.exposure.summary().c_str(),
                 pair.blurred.exposure.summary().c_str(), pair.exif_ratio->summary().c_str());
  }
  if (ratio <= 0) {
    if (!pair.exif_ratio)
      throw Error("no exposure ratio: " + pair.exif_problem, pair.exif_problem.find("sharp") != std::string::npos
                                                                  ? pair.sharp.path.string()
                                                                  : pair.blurred.path.string());
    ratio = pair.exif_ratio->ratio();
  }

  PairCalibrationOptions options;
  options.kernel.kernel_size = args.kernel_size;
  options.rgb = args.channels == "rgb";
  options.rounds = args.rounds;
  options.register_pair = !args.no_register;
  options.fit.initial_ratio = ratio;
  options.fit.model = args.model == "ggcm" ? CrfModelChoice::ggcm
                      : args.model == "emor" ? CrfModelChoice::emor
                                             : CrfModelChoice::automatic;
  options.fit.threads = args.threads;
  if (!args.kernel_file.empty()) options.given_kernel = io::readKernel(args.kernel_file);
  std::string current;
  options.progress = [&](const std::string& stage, double fraction, const std::string& detail) {
    std::string name = stage.rfind("fit", 0) == 0 ? "fit" : stage;
    if (name != current) {
      if (!current.empty()) progress.done();
      progress.stage(name);
      current = name;
    }
    progress.update(fraction, detail);
  };
  const PairCalibrationResult result = calibratePair(pair.sharp.image, pair.blurred.image, options);
  if (!current.empty()) progress.done();

  progress.stage("write");
  t = Clock::now();
  for (const auto& [stage, seconds] : result.timings) report.timings[stage] = seconds;
  for (const auto& [name, fit] : result.fits) {
    report.inverse_crf[name] = fit.inverse_crf;
    report.models[name] = fit.model;
    report.pixels_used[name] = fit.pixels.used;
  }
  report.ratio_fitted = result.fits.at("G").ratio;
  report.warnings = result.warnings;
  report.effects = nlohmann::json::array();
  for (const auto& e : result.effects.entries)
    report.effects.push_back({{"name", e.name}, {"detected", e.detected}, {"tested", e.tested},
                              {"statistic", e.statistic}, {"threshold", e.threshold}, {"gain", e.gain},
                              {"gain_threshold", e.gain_threshold}, {"parameters", e.parameters}, {"detail", e.detail}});
  for (const auto& name : result.effects.detected()) report.warnings.push_back("effect detected: " + name);
  if (!result.base_fits.empty()) {
    report.extra["phi_base_model"] = nlohmann::json::object();
    for (const auto& [name, fit] : result.base_fits) report.extra["phi_base_model"][name] = fit.inverse_crf;
  }
  if (pair.swapped) report.warnings.push_back("the first image is the blurred one (" + pair.blurred_reason + "); swapped");
  if (pair.sharp.linear)
    report.warnings.push_back("RAW pair: the data are linear (phi should be the identity; the fit checks it)");
  nlohmann::json& extra = report.extra;
  extra["input"] = {{"sharp", pair.sharp.path.string()},
                    {"blurred", pair.blurred.path.string()},
                    {"format", pair.sharp.format},
                    {"linear", pair.sharp.linear},
                    {"blurred_reason", pair.blurred_reason},
                    {"camera", pair.sharp.exposure.camera()},
                    {"size", {pair.blurred.image.cols, pair.blurred.image.rows}}};
  if (pair.sharp.linear)
    extra["input"]["raw_levels"] = {{"black", pair.sharp.black_level}, {"white", pair.sharp.white_level}};
  if (pair.exif_ratio)
    extra["exposure_ratio_factors"] = {{"iso", pair.exif_ratio->iso},
                                       {"time", pair.exif_ratio->time},
                                       {"aperture", pair.exif_ratio->aperture},
                                       {"aperture_known", pair.exif_ratio->aperture_known},
                                       {"sharp", pair.sharp.exposure.summary()},
                                       {"blurred", pair.blurred.exposure.summary()}};
  extra["exposure_ratio_used_as_seed"] = ratio;
  extra["exposure_ratio_per_channel"] = nlohmann::json::object();
  for (const auto& [name, fit] : result.fits) extra["exposure_ratio_per_channel"][name] = fit.ratio;
  const cv::Mat& K = result.kernel.kernel;
  extra["kernel"] = {{"size", {K.cols, K.rows}},
                     {"file", "kernel.png"},
                     {"text", "kernel.txt"},
                     {"estimated", result.kernel_estimated}};
  if (result.kernel_estimated) {
    extra["kernel"]["centroid"] = {result.kernel.centroid.x, result.kernel.centroid.y};
    extra["kernel"]["border_mass"] = result.kernel.border_mass;
    extra["kernel"]["relative_residual"] = result.kernel.relative_residual;
    extra["kernel"]["tiles"] = result.tiles.size();
    if (result.tile_kernels.size() > 1)
      extra["kernel"]["tile_disagreement"] = {{"mean_relative", result.disagreement.mean_relative},
                                              {"max_relative", result.disagreement.max_relative},
                                              {"centroid_spread_px", result.disagreement.centroid_spread}};
  }
  extra["registration"] = {{"method", result.registration.method},
                           {"homography", std::vector<double>(result.registration.homography.begin<double>(),
                                                              result.registration.homography.end<double>())},
                           {"ecc_correlation", result.registration.ecc_correlation},
                           {"overlap", result.registration.overlap_fraction},
                           {"inliers", result.registration.inliers},
                           {"shift_px", {result.registration.shift().x, result.registration.shift().y}},
                           {"rotation_deg", result.registration.rotationDegrees()}};
  extra["rounds"] = nlohmann::json::array();
  for (const auto& r : result.rounds)
    extra["rounds"].push_back({{"round", r.round},
                               {"kernel_change", r.kernel_change},
                               {"phi_change_rmse", r.phi_change},
                               {"ratio", r.ratio},
                               {"kernel_residual", r.kernel_residual}});
  extra["fit_window"] = {result.fit_window.x, result.fit_window.y, result.fit_window.width, result.fit_window.height};
  extra["fit"] = nlohmann::json::object();
  for (const auto& [name, fit] : result.fits)
    extra["fit"][name] = {{"model", describe(fit.model)}, {"chosen", fit.chosen}, {"reason", fit.choice_reason},
                          {"energy", fit.energy}, {"iterations", fit.iterations}, {"noise_sigma", fit.noise_sigma}};

  io::OutputDirectory out(args.output);
  // inverse_crf.csv
  {
    std::ostringstream csv;
    csv << "x";
    const auto channels = report.channels();
    for (const auto& c : channels) csv << "," << c;
    csv << "\n";
    for (int i = 0; i < kCurveSamples; ++i) {
      csv << static_cast<double>(i) / (kCurveSamples - 1);
      for (const auto& c : channels) csv << "," << report.inverse_crf.at(c)[i];
      csv << "\n";
    }
    io::writeTextFile(out.file("inverse_crf.csv"), csv.str());
  }
  io::writeKernelPng(out.file("kernel.png"), K);
  io::writeKernelText(out.file("kernel.txt"), K);
  {
    std::vector<io::PlotSeries> series;
    std::vector<double> x(kCurveSamples);
    for (int i = 0; i < kCurveSamples; ++i) x[i] = static_cast<double>(i) / (kCurveSamples - 1);
    io::PlotSeries identity{x, x, cv::Scalar(150, 150, 150), "identity", 1, false, true};
    series.push_back(identity);
    for (const auto& c : report.channels()) {
      const cv::Scalar colour = c == "R" ? cv::Scalar(40, 40, 220) : c == "G" ? cv::Scalar(40, 160, 40) : cv::Scalar(220, 80, 40);
      series.push_back({x, report.inverse_crf.at(c), colour, "phi " + c});
    }
    io::PlotOptions plot;
    plot.title = "inverse response phi (" + pair.sharp.exposure.camera() + ")";
    plot.x_label = "intensity x";
    plot.y_label = "irradiance phi(x)";
    plot.x_min = plot.y_min = 0;
    plot.x_max = plot.y_max = 1;
    io::writePlot(out.file("curve.png"), series, plot);
  }
  io::writeSignedMap(out.file("gamma_map.png"), result.gamma_map);
  io::writeImage(out.file("weights.png"), result.weights.empty() ? cv::Mat::zeros(1, 1, CV_8U) : result.weights);
  report.timings["write"] = std::chrono::duration<double>(Clock::now() - t).count();
  report.timings["total"] = std::chrono::duration<double>(Clock::now() - start).count();
  io::writeReport(out.file("report.json"), report);
  out.commit();
  progress.done();

  std::printf("%s\n", result.summary().c_str());
  if (report.ratio_exif) std::printf("exposure ratio: EXIF %.4g, fitted %.4g\n", *report.ratio_exif, *report.ratio_fitted);
  else std::printf("exposure ratio: given %.4g, fitted %.4g\n", ratio, *report.ratio_fitted);
  for (const auto& w : report.warnings) std::printf("warning: %s\n", w.c_str());
  std::printf("wrote %s/{report.json, inverse_crf.csv, kernel.png, kernel.txt, curve.png, gamma_map.png, weights.png}\n",
              args.output.c_str());
  return kExitOk;
}

const CommandRegistration registration(
    30, "calibrate", "Measure the camera response from a real handheld sharp/blurred pair (JPEG, PNG, TIFF or RAW; Sec. 4)",
    [](CLI::App& command) {
      auto args = std::make_shared<CalibrateArgs>();
      command.add_option("SHARP", args->first, "The short-exposure (sharp, noisy) shot")->required();
      command.add_option("BLURRED", args->second, "The long-exposure (blurred) shot")->required();
      command.add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")->required();
      command.add_option("--channels", args->channels, "Channels to fit: g (green only) or rgb")
          ->check(CLI::IsMember({"g", "rgb"}));
      command.add_option("--model", args->model, "Model of phi: ggcm (Eq. 19), emor (PCA), auto (cross-validated)")
          ->check(CLI::IsMember({"ggcm", "emor", "auto"}));
      command.add_option("--ratio", args->ratio, "Exposure ratio r = dt_B/dt_I (default: from EXIF, footnote 4)")
          ->check(CLI::PositiveNumber);
      command.add_option("--kernel-size", args->kernel_size, "Largest kernel extent, odd (blur + residual shift)")
          ->check(CLI::Range(3, 151));
      command.add_option("--kernel", args->kernel_file, "Use this kernel (text matrix or image) instead of estimating")
          ->check(CLI::ExistingFile);
      command.add_option("--rounds", args->rounds, "Kernel <-> phi rounds after the first fit")->check(CLI::Range(0, 10));
      command.add_option("--blurred", args->blurred, "Which argument is the blurred shot: auto, first, second")
          ->check(CLI::IsMember({"auto", "first", "second"}));
      command.add_option("--threads", args->threads, "Worker threads (0: all cores)")->check(CLI::NonNegativeNumber);
      command.add_flag("--no-white-balance", args->no_white_balance, "RAW: no white balance (sensor RGB)");
      command.add_flag("--no-register", args->no_register, "The pair is already aligned (skip registration)");
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] {
        if (args->kernel_size % 2 == 0) throw InvalidInput("--kernel-size must be odd");
        return runCalibrate(*args);
      };
    });

}  // namespace
}  // namespace crfcal::app
