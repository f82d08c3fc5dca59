// crfcal calibrate SHARP BLURRED -o DIR: a real handheld JPEG or RAW pair in, the camera's response out (Sec. 4).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
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
#include "crfcal/curve_comparison.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/raw_truth.hpp"
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
  bool fix_ratio = false;
  bool always_fit_ratio = false;
  bool no_effects = false;
  double irradiance_kernel_lambda = PairCalibrationOptions{}.irradiance_kernel_lambda;
  bool unweighted_irradiance_kernel = false;
  std::string shoulder = PairCalibrationOptions{}.fit.shoulder_follows_emor_mean ? "mean-camera" : "rising-free";
  double ratio_prior = PairCalibrationOptions{}.fit.ratio_prior_sigma;  // σ of log r around EXIF/--ratio
  std::string noise_handling = toString(PairCalibrationOptions{}.fit.noise);
  bool quiet = false;
  std::string raw_truth;            // RAW (or linear image) of one of the two shots
  std::string raw_truth_of = "auto";  // which shot it is: auto (EXIF), sharp, blurred
};

// Which shot of the pair the --raw-truth file belongs to: given, else the one with the same exposure time (and ISO,
// when both say) in EXIF, else the sharp one.
struct TruthShot {
  bool blurred = false;
  std::string reason;
};

TruthShot chooseTruthShot(const std::string& given, const io::LoadedImage& truth, const io::LoadedPair& pair) {
  if (given == "sharp") return {false, "given on the command line"};
  if (given == "blurred") return {true, "given on the command line"};
  auto same = [](const std::optional<double>& a, const std::optional<double>& b) {
    return a && b && *a > 0 && *b > 0 && std::abs(std::log(*a / *b)) < std::log(1.05);
  };
  auto unknownOrSame = [&](const std::optional<double>& a, const std::optional<double>& b) {
    return !a || !b || same(a, b);
  };
  const ExifExposure& t = truth.exposure;
  const ExifExposure &s = pair.sharp.exposure, &b = pair.blurred.exposure;
  if (!t.exposure_time || !s.exposure_time || !b.exposure_time)
    return {false, "the sharp shot (default: no EXIF exposure times to decide)"};
  const bool is_sharp = same(t.exposure_time, s.exposure_time) && unknownOrSame(t.iso, s.iso);
  const bool is_blurred = same(t.exposure_time, b.exposure_time) && unknownOrSame(t.iso, b.iso);
  if (is_sharp && !is_blurred) return {false, "EXIF: same exposure as the sharp shot (" + t.summary() + ")"};
  if (is_blurred && !is_sharp) return {true, "EXIF: same exposure as the blurred shot (" + t.summary() + ")"};
  if (is_sharp && is_blurred)
    return {false, "EXIF: both shots have its exposure; the sharp one assumed (--raw-truth-of decides)"};
  throw InvalidInput("its exposure (" + t.summary() + ") matches neither shot (sharp: " + s.summary() + "; blurred: " +
                         b.summary() + "): not a RAW of this pair? (--raw-truth-of sharp|blurred overrides)",
                     truth.path.string());
}

struct RawTruthRun {
  io::LoadedImage file;
  TruthShot shot;
  std::string shot_file;
  RawTruthResult result;
};

// Loads the --raw-truth file and measures the camera's response from it and the JPEG of its shot (calib/raw_truth).
RawTruthRun computeTruth(const CalibrateArgs& args, const io::LoadedPair& pair, const io::RawDecodeOptions& raw) {
  if (pair.sharp.linear)
    throw InvalidInput("--raw-truth needs a rendered (JPEG, PNG, TIFF) pair: this pair is already linear camera RAW",
                       pair.sharp.path.string() + ", " + pair.blurred.path.string());
  RawTruthRun run;
  // A 2x2-binned decode (LibRaw half_size): no demosaicing artefacts, and the truth works on ≤ 1024 px copies anyway.
  io::RawDecodeOptions truth_raw = raw;
  truth_raw.half_size = true;
  run.file = io::loadImage(args.raw_truth, truth_raw);
  if (run.file.format == "jpeg")
    throw InvalidInput("is a JPEG, not linear data: give the camera RAW or a linear (PNG/TIFF) rendering of it",
                       args.raw_truth);
  run.shot = chooseTruthShot(args.raw_truth_of, run.file, pair);
  const io::LoadedImage& shot = run.shot.blurred ? pair.blurred : pair.sharp;
  run.shot_file = shot.path.string();
  RawTruthOptions options;
  options.channels = args.channels == "rgb" && shot.image.channels() >= 3 ? std::vector<std::string>{"R", "G", "B"}
                                                                           : std::vector<std::string>{"G"};
  try {
    run.result = computeRawTruth(shot.image, run.file.image, options);
  } catch (const InvalidInput& e) {
    throw InvalidInput(e.reason(), args.raw_truth);
  }
  if (!run.file.linear)
    run.result.warnings.push_back("not a camera RAW: taken as linear data as given (the response's exponent "
                                  "checks it)");
  return run;
}

nlohmann::json comparisonJson(const CurveComparison& comparison) {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& c : comparison.channels)
    out[c.channel] = {{"rmse", c.rmse},
                      {"max_error", c.max_error},
                      {"covered", {c.covered.first, c.covered.second}},
                      {"covered_source", c.covered_source},
                      {"rmse_covered", c.rmse_covered},
                      {"max_error_covered", c.max_error_covered},
                      {"scale_covered", c.scale_covered},
                      {"rmse_covered_aligned", c.rmse_covered_aligned}};
  out["worst_rmse"] = comparison.worst_rmse;
  out["worst_rmse_covered"] = comparison.worst_rmse_covered;
  out["worst_rmse_covered_aligned"] = comparison.worst_rmse_covered_aligned;
  return out;
}

nlohmann::json truthJson(const RawTruthRun& run, const std::optional<CurveComparison>& comparison) {
  const RawTruthResult& r = run.result;
  nlohmann::json out = {{"file", run.file.path.string()},
                        {"format", run.file.format},
                        {"camera_raw", run.file.linear},
                        {"shot", run.shot.blurred ? "blurred" : "sharp"},
                        {"shot_file", run.shot_file},
                        {"shot_reason", run.shot.reason},
                        {"inverse_crf", r.inverse()},
                        {"covered_range", nlohmann::json::object()},
                        {"channels", nlohmann::json::object()},
                        {"overlap_pixels", r.overlap_pixels},
                        {"flat_pixels", r.flat_pixels},
                        {"warnings", r.warnings}};
  if (run.file.linear) out["raw_levels"] = {{"black", run.file.black_level}, {"white", run.file.white_level}};
  for (const auto& [name, range] : r.covered()) out["covered_range"][name] = {range.first, range.second};
  for (const auto& c : r.channels) {
    nlohmann::json cv = nlohmann::json::array();
    for (const auto& [k, e] : c.fit.cv_rmse) cv.push_back({k, e});
    out["channels"][c.channel] = {{"model", describe(c.fit.model)},
                                  {"terms", c.fit.terms},
                                  {"cv_rmse", cv},
                                  {"colour_mix", c.mix},
                                  {"bin_rmse", c.fit.rmse},
                                  {"pixel_rmse", c.pixel_rmse},
                                  {"explained_variance", c.explained},
                                  {"effective_exponent", std::isfinite(c.effective_gamma)
                                                             ? nlohmann::json(c.effective_gamma)
                                                             : nlohmann::json(nullptr)},
                                  {"pixels", c.pixels},
                                  {"censored_pixels", c.censored_pixels},
                                  {"bins", c.bins}};
  }
  const cv::Mat& H = r.registration.homography;
  out["registration"] = {{"method", r.registration.method},
                         {"rotation_deg", r.rotation_degrees},
                         {"linear_scale", r.linear_scale},
                         {"ecc_correlation", r.registration.ecc_correlation},
                         {"working_size", {r.working_size.width, r.working_size.height}},
                         {"matrix", std::vector<double>(H.begin<double>(), H.end<double>())}};
  if (comparison) out["comparison"] = comparisonJson(*comparison);
  return out;
}

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

  // The RAW of one shot: the camera's real response, measured before the (longer) pair calibration so that a bad
  // file fails fast.
  std::optional<RawTruthRun> truth;
  if (!args.raw_truth.empty()) {
    progress.stage("raw truth");
    t = Clock::now();
    truth = computeTruth(args, pair, raw);
    report.timings["raw_truth"] = std::chrono::duration<double>(Clock::now() - t).count();
    progress.done(truth->file.format + " " + truth->file.path.filename().string() + " = the " +
                  (truth->shot.blurred ? "blurred" : "sharp") + " shot (" + truth->shot.reason + ")");
  }

  PairCalibrationOptions options;
  options.kernel.kernel_size = args.kernel_size;
  options.rgb = args.channels == "rgb";
  options.rounds = args.rounds;
  options.register_pair = !args.no_register;
  options.fit.initial_ratio = ratio;
  options.fit.fit_ratio = !args.fix_ratio;
  options.fix_ratio_when_blur_is_small = !args.always_fit_ratio;
  options.effects.enabled = !args.no_effects;
  options.irradiance_kernel_lambda = args.irradiance_kernel_lambda;
  options.weight_irradiance_kernel = !args.unweighted_irradiance_kernel;
  options.fit.shoulder_follows_emor_mean = args.shoulder == "mean-camera";
  options.fit.ratio_prior_sigma = args.ratio_prior;
  options.fit.noise = noiseHandlingFromString(args.noise_handling);
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
  // Problems found by the computation name the pair's file(s), like the decoding errors do.
  const PairCalibrationResult result = [&] {
    try {
      return calibratePair(pair.sharp.image, pair.blurred.image, options);
    } catch (const InvalidInput& e) {
      if (!e.file().empty()) throw;
      const std::string file = e.subject() == ErrorSubject::blurred_image ? pair.blurred.path.string()
                               : e.subject() == ErrorSubject::sharp_image
                                   ? pair.sharp.path.string()
                                   : pair.sharp.path.string() + ", " + pair.blurred.path.string();
      throw InvalidInput(e.reason(), e.subject(), file);
    }
  }();
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
  report.covered_range = result.covered_range;
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
  {
    // One warning naming every chroma-subsampled shot (only when R and B are fitted: G is carried by luma).
    std::vector<std::string> subsampled;
    for (const auto* shot : {&pair.sharp, &pair.blurred})
      if (shot->chroma_subsampled)
        subsampled.push_back(shot->path.string() + " (" + shot->chroma_subsampling + ")");
    if (!subsampled.empty() && result.fits.size() > 1) {
      std::string files = subsampled.front();
      if (subsampled.size() > 1) files += " and " + subsampled.back();
      report.warnings.push_back(files + ": JPEG chroma subsampled: R and B are rebuilt from chroma averaged across "
                                "edges after the tone curve, so their curves are less reliable than G's (see "
                                "docs/RESULTS.md#calibrate)");
    }
  }
  nlohmann::json& extra = report.extra;
  extra["input"] = {{"sharp", pair.sharp.path.string()},
                    {"blurred", pair.blurred.path.string()},
                    {"format", pair.sharp.format},
                    {"chroma_subsampling", {{"sharp", pair.sharp.chroma_subsampling},
                                            {"blurred", pair.blurred.chroma_subsampling}}},
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
  extra["exposure_ratio_mode"] = args.fix_ratio                     ? "fixed (--fix-ratio)"
                                : result.ratio_fixed_by_small_blur ? "fixed (blur too small to determine r)"
                                                                   : "fitted";
  extra["exposure_ratio_per_channel"] = nlohmann::json::object();
  extra["ambiguity_rise"] = nlohmann::json::object();  // CrfFitResult::ambiguity_rise per channel
  for (const auto& [name, fit] : result.fits) {
    extra["exposure_ratio_per_channel"][name] = fit.ratio;
    extra["ambiguity_rise"][name] = fit.ambiguity_rise;
  }
  // the EXIF prior on log r (CrfFitOptions::ratio_prior_sigma) and what the images alone say, per channel
  if (options.fit.fit_ratio && options.fit.ratio_prior_sigma > 0) {
    extra["exposure_ratio_prior"] = {{"centre", ratio},
                                     {"log_sigma", options.fit.ratio_prior_sigma},
                                     {"images_only", nlohmann::json::object()}};
    for (const auto& [name, fit] : result.fits)
      if (fit.ratio_images_only > 0) extra["exposure_ratio_prior"]["images_only"][name] = fit.ratio_images_only;
  }
  const cv::Mat& K = result.kernel.kernel;
  extra["kernel"] = {{"size", {K.cols, K.rows}},
                     {"file", "kernel.png"},
                     {"text", "kernel.txt"},
                     {"estimated", result.kernel_estimated}};
  if (result.kernel_estimated) {
    extra["kernel"]["centroid"] = {result.kernel.centroid.x, result.kernel.centroid.y};
    extra["kernel"]["blur_rms_radius_px"] = result.blur_radius;
    extra["kernel"]["equations"] = result.kernel.equations;
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
  std::optional<CurveComparison> truth_comparison;
  if (truth) {
    // The pair's φ against the RAW truth, per channel, over [0,1] and over the range both are supported by data.
    try {
      truth_comparison = compareChannels(report.inverse_crf, truth->result.inverse(), report.covered_range,
                                         truth->result.covered());
    } catch (const InvalidInput&) {
      // The two are supported by data on disjoint intensity ranges: only the [0,1] comparison is meaningful.
      truth_comparison = compareChannels(report.inverse_crf, truth->result.inverse());
      report.warnings.push_back("raw truth: the pair and the RAW truth cover disjoint intensity ranges; compared over "
                                "[0,1] only");
    }
    extra["raw_truth"] = truthJson(*truth, truth_comparison);
    for (const auto& w : truth->result.warnings) report.warnings.push_back("raw truth: " + w);
  }

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
      if (truth && truth->result.inverse().count(c))
        series.push_back({x, truth->result.inverse().at(c), colour, "RAW truth " + c, 1, false, true});
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
  if (report.ratio_exif) {
    std::printf("exposure ratio: EXIF %.4g, fitted %.4g", *report.ratio_exif, *report.ratio_fitted);
    const CrfFitResult& g = result.fits.count("G") ? result.fits.at("G") : result.fits.begin()->second;
    if (g.ratio_images_only > 0)
      std::printf(" (images alone %.4g; prior sigma %.2g on log r)", g.ratio_images_only, options.fit.ratio_prior_sigma);
    std::printf("\n");
  }
  else std::printf("exposure ratio: given %.4g, fitted %.4g\n", ratio, *report.ratio_fitted);
  if (truth) {
    std::printf("RAW truth (%s, the %s shot):\n%s", truth->file.path.string().c_str(),
                truth->shot.blurred ? "blurred" : "sharp", truth->result.summary().c_str());
    std::printf("pair phi vs RAW truth:\n%s", truth_comparison->summary().c_str());
  }
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
      command.add_flag("--fix-ratio", args->fix_ratio,
                       "Keep r at the EXIF/--ratio value instead of fitting it (weak blur leaves r and the curve's "
                       "exponent ambiguous: phi^g, r^g fit equally)");
      command.add_flag("--always-fit-ratio", args->always_fit_ratio,
                       "Fit r even when the blur is too small to determine it (by default, with a kernel RMS radius "
                       "< 1 px and the images' r more than 10 % from the EXIF/--ratio value, r is held at that value)")
          ->excludes("--fix-ratio");
      command.add_option("--shoulder", args->shoulder,
                         "Extrapolation of phi above the data: rising-free (the local exponent may rise freely) or "
                         "mean-camera (it rises like the EMoR mean curve's)")
          ->capture_default_str()
          ->check(CLI::IsMember({"rising-free", "mean-camera"}));
      command.add_option("--irradiance-kernel-lambda", args->irradiance_kernel_lambda,
                         "Sparsity weight of the irradiance-domain kernel rounds (the first estimate keeps 0.03)")
          ->capture_default_str()
          ->check(CLI::NonNegativeNumber);
      command.add_flag("--unweighted-irradiance-kernel", args->unweighted_irradiance_kernel,
                       "Irradiance-domain kernel rounds without the 1/phi'(B) weights (ablation)");
      command.add_flag("--no-effects", args->no_effects,
                       "Skip the effect diagnostics (effects.hpp): faster; phi is the base fit of Eq. 4");
      command.add_option("--noise-handling", args->noise_handling,
                         "The sharp shot's noise in the fit: jensen (second-order correction of Jensen's bias), none, "
                         "debias (deconvolution), denoise (bilateral)")
          ->capture_default_str()
          ->check(CLI::IsMember({"jensen", "none", "debias", "denoise"}));
      command.add_option("--ratio-prior", args->ratio_prior,
                         "Fitted r: sigma of the prior on log r around the EXIF/--ratio value, weighed against what the "
                         "blur determines (0: r from the images alone)")
          ->capture_default_str()
          ->check(CLI::NonNegativeNumber);
      auto* raw_truth = command.add_option("--raw-truth", args->raw_truth,
                         "Camera RAW (or a linear PNG/TIFF) of one of the two shots: its RAW->JPEG relation, the "
                         "camera's real response, is written to report.json (raw_truth) and compared with the result");
      command.add_option("--raw-truth-of", args->raw_truth_of,
                         "Which shot the --raw-truth file is: auto (same exposure in EXIF, else sharp), sharp, blurred")
          ->check(CLI::IsMember({"auto", "sharp", "blurred"}))
          ->needs(raw_truth);
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] {
        if (args->kernel_size % 2 == 0) throw InvalidInput("--kernel-size must be odd");
        return runCalibrate(*args);
      };
    });

}  // namespace
}  // namespace crfcal::app
