// crfcal calibrate SHARP BLURRED -o DIR: a real handheld JPEG or RAW pair in, the camera's response out (Sec. 4).
#include <chrono>
#include <cmath>
#include <filesystem>
#include <cstdio>
#include <memory>
#include <optional>
#include <sstream>

#include <opencv2/core.hpp>
#include <nlohmann/json.hpp>

#include "command.hpp"
#include "option_checks.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/curve_prior_io.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/calibration_figures.hpp"
#include "crfcal/io/calibration_report.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/joint_calibration_report.hpp"
#include "crfcal/io/pair_manifest.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/joint_calibration.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/pair_checks.hpp"
#include "crfcal/raw_truth.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

struct CalibrateArgs {
  std::string first, second, output;
  std::string channels = "rgb";
  // check (default), auto or off: applyChromaModel (option_checks.hpp); issue 20
  std::string chroma_model = "check";
  std::string model = "auto";
  int emor_terms = PairCalibrationOptions{}.fit.emor_terms;  // EMoR basis curves of the fit
  double ratio = 0;  // 0: from EXIF
  int kernel_size = 35;
  int max_kernel_size = PairCalibrationOptions{}.max_kernel_size;  // 0: automatic (PairCalibrationOptions)
  std::string kernel_file;
  int threads = 0;
  int rounds = 2;
  int band_replicates = PairCalibrationOptions{}.band.replicates;  // the band of φ (curve_band.hpp); 0: none
  std::string blurred = "auto";
  bool no_white_balance = false;
  bool no_register = false;
  bool fix_ratio = false;
  bool always_fit_ratio = false;
  std::string ratio_evidence = PairCalibrationOptions{}.ratio_evidence.enabled ? "on" : "off";
  bool ratio_noise_bias = PairCalibrationOptions{}.ratio_evidence.measure_noise_bias;
  bool no_effects = false;
  double irradiance_kernel_lambda = PairCalibrationOptions{}.irradiance_kernel_lambda;
  bool unweighted_irradiance_kernel = false;
  std::string shoulder = PairCalibrationOptions{}.fit.experimental.shoulder_follows_emor_mean ? "mean-camera" : "rising-free";
  std::string band_above = "learned";  // the band above the data: the learned prior's quantiles or exponent bounds
  double ratio_prior = PairCalibrationOptions{}.fit.ratio_prior_sigma;  // σ of log r around EXIF/--ratio
  double censored_weight = PairCalibrationOptions{}.fit.censored_weight;  // B's clipped pixels, censored
  std::string noise_handling = toString(PairCalibrationOptions{}.fit.experimental.noise);
  bool quiet = false;
  bool strict = false;              // exit kExitUnreliable when a channel's verdict is "unreliable"
  std::string raw_truth;            // RAW (or linear image) of one of the two shots
  std::string raw_truth_of = "auto";  // which shot it is: auto (EXIF), sharp, blurred
  bool force = false;               // write into an output directory holding other files (never deletes them)
  // A joint calibration of several pairs of one camera (joint_calibration.hpp): --pair SHARP BLURRED (repeated)
  // and/or a manifest --pairs FILE; then SHARP BLURRED are not given.
  std::vector<std::pair<std::string, std::string>> pairs;
  std::string pairs_file;
  int joint_ratio_rounds = -1;  // rounds moving each pair's r to its r at the joint φ (−1: not given, the default)
  bool joint() const { return !pairs.empty() || !pairs_file.empty(); }
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

// The pair's φ against the RAW truth, per channel, over [0,1] and over the range both are supported by data (over
// [0,1] only when the two cover disjoint ranges).
void compareWithTruth(const PairCalibrationResult& result, io::RawTruthReport& truth) {
  std::map<std::string, std::vector<double>> curves;
  for (const auto& [name, fit] : result.fits) curves[name] = fit.inverse_crf;
  try {
    truth.comparison = compareChannels(curves, truth.result.inverse(), result.covered_range, truth.result.covered());
  } catch (const InvalidInput&) {
    truth.comparison = compareChannels(curves, truth.result.inverse());
    truth.compared_on_full_range_only = true;
  }
}

// Pure image checks (pair_checks.hpp) before any fitting, with the file(s) they concern.
void requireUsablePair(const io::LoadedPair& pair) {
  try {
    requireDistinctImages(pair.sharp.image, pair.blurred.image);
  } catch (const InvalidInput& e) {
    throw Error(e.reason(), pair.sharp.path.string() + ", " + pair.blurred.path.string());
  }
  PairCheckOptions checks;
  if (pair.sharp.linear) checks.black_level = 0.002;  // linear RAW: 2/255 of a gamma-encoded scale is far darker
  for (const io::LoadedImage* shot : {&pair.sharp, &pair.blurred}) {
    try {
      requireUsableExposure(shot->image, shot == &pair.sharp ? "sharp" : "blurred", 0, 0, checks);
    } catch (const InvalidInput& e) {
      throw Error(e.reason(), shot->path.string());
    }
  }
}

double secondsSince(std::chrono::steady_clock::time_point from) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - from).count();
}

io::LoadedPair decodePair(const CalibrateArgs& args, const io::RawDecodeOptions& raw) {
  const io::BlurredChoice choice = args.blurred == "first"    ? io::BlurredChoice::first
                                   : args.blurred == "second" ? io::BlurredChoice::second
                                                              : io::BlurredChoice::automatic;
  io::LoadedPair pair = io::loadPair(args.first, args.second, choice, raw);
  requireUsablePair(pair);

  return pair;
}

// Exposure ratio (footnote 4): --ratio, else the EXIF's (printed unless -q); neither is an error naming the file.
double nominalRatio(const CalibrateArgs& args, const io::LoadedPair& pair) {
  double nominal_ratio = args.ratio;
  if (pair.exif_ratio) {
    if (!args.quiet)
      std::fprintf(stderr, "  exif: sharp %s; blurred %s\n  exif: %s\n", pair.sharp.exposure.summary().c_str(),
                   pair.blurred.exposure.summary().c_str(), pair.exif_ratio->summary().c_str());
  }
  if (nominal_ratio <= 0) {
    if (!pair.exif_ratio)
      throw Error("no exposure ratio: " + pair.exif_problem, pair.exif_problem.find("sharp") != std::string::npos
                                                                  ? pair.sharp.path.string()
                                                                  : pair.blurred.path.string());
    nominal_ratio = pair.exif_ratio->ratio();
  }
  return nominal_ratio;
}

PairCalibrationOptions calibrationOptions(const CalibrateArgs& args, double nominal_ratio) {
  checkKernelSizes(args.kernel_size, args.max_kernel_size);
  PairCalibrationOptions options;
  options.kernel.kernel_size = args.kernel_size;
  options.max_kernel_size = args.max_kernel_size;
  options.rgb = args.channels == "rgb";
  options.rounds = args.rounds;
  options.band.replicates = args.band_replicates;
  options.register_pair = !args.no_register;
  options.fit.nominal_ratio = nominal_ratio;
  options.nominal_ratio_name = args.ratio > 0 ? "--ratio" : "EXIF";
  options.fit.fit_ratio = !args.fix_ratio;
  options.fix_ratio_when_blur_is_small = !args.always_fit_ratio;
  options.ratio_evidence.enabled = args.ratio_evidence == "on";
  options.ratio_evidence.measure_noise_bias = args.ratio_noise_bias;
  options.effects.enabled = !args.no_effects;
  options.irradiance_kernel_lambda = args.irradiance_kernel_lambda;
  options.weight_irradiance_kernel = !args.unweighted_irradiance_kernel;
  options.fit.experimental.shoulder_follows_emor_mean = args.shoulder == "mean-camera";
  if (args.shoulder == "learned") options.fit.learned_prior = io::learnPriorFromCameraCurves();
  if (args.band_above == "learned") options.band.above_data_prior = io::learnPriorFromCameraCurves();
  options.fit.ratio_prior_sigma = args.ratio_prior;
  options.fit.censored_weight = args.censored_weight;
  options.fit.experimental.noise = noiseHandlingFromString(args.noise_handling);
  options.fit.model = crfModelFromName(args.model);
  options.fit.emor_terms = args.emor_terms;
  options.fit.threads = args.threads;
  if (!args.kernel_file.empty()) options.given_kernel = io::readKernel(args.kernel_file);
  return options;
}

// The calibration's stages on the progress line ("fit …" stages shown as one).
struct StageProgress {
  Progress& progress;
  std::string current;

  void report(const std::string& stage, double fraction, const std::string& detail) {
    std::string name = stage.rfind("fit", 0) == 0 ? "fit" : stage;
    if (name != current) {
      if (!current.empty()) progress.done();
      progress.stage(name);
      current = name;
    }
    progress.update(fraction, detail);
  }
  void finish() {
    if (!current.empty()) progress.done();
  }
};

// Problems found by the computation name the pair's file(s), like the decoding errors do.
PairCalibrationResult calibrateNamingFiles(const io::LoadedPair& pair, const PairCalibrationOptions& options) {
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
}

void writeInverseCrfCsv(io::OutputDirectory& out, const io::CalibrationReport& report) {
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

void printCalibration(const CalibrateArgs& args, double nominal_ratio, const PairCalibrationOptions& options,
                      const PairCalibrationResult& result, const io::CalibrationReport& report,
                      const std::optional<RawTruthRun>& truth, const std::optional<io::RawTruthReport>& truth_report) {
  std::printf("%s\n", result.summary().c_str());
  std::printf("exposure ratio: %s %.4g, fitted %.4g", args.ratio > 0 ? "given" : "EXIF", nominal_ratio,
              *report.fitted_ratio);
  const CrfFitResult& g = result.fits.count("G") ? result.fits.at("G") : result.fits.begin()->second;
  if (g.ratio_images_only > 0)
    std::printf(" (images alone %.4g; prior sigma %.2g on log r)", g.ratio_images_only, options.fit.ratio_prior_sigma);
  std::printf("\n");
  if (result.ratio_evidence.combined) std::printf("exposure ratio evidence: %s\n", result.ratio_evidence.summary().c_str());
  if (truth) {
    std::printf("RAW truth (%s, the %s shot):\n%s", truth->file.path.string().c_str(),
                truth->shot.blurred ? "blurred" : "sharp", truth->result.summary().c_str());
    std::printf("pair phi vs RAW truth:\n%s", truth_report->comparison->summary().c_str());
  }
  for (const auto& w : report.warnings) std::printf("warning: %s\n", w.c_str());
  std::printf("wrote %s/{report.json, inverse_crf.csv, kernel.png, kernel.txt, curve.png, gamma_map.png, weights.png}%s\n",
              args.output.c_str(),
              result.tile_kernels.size() > 1 ? " and the tiles' kernels kernel_tile_N.txt (deblur --from --kernels)" : "");
}

// The verdict per channel, last (channel_verdict.hpp): one line each, R, G, B order.
void printVerdicts(const PairCalibrationResult& result) {
  for (const char* c : {"R", "G", "B"})
    if (result.verdicts.count(c)) std::printf("verdict %s: %s\n", c, result.verdicts.at(c).summary().c_str());
}

// --strict: kExitUnreliable when a channel is unreliable (the outputs are written; the message says which and why).
int strictExitCode(const CalibrateArgs& args, const PairCalibrationResult& result) {
  if (!args.strict || worstLevel(result.verdicts) != VerdictLevel::unreliable) return kExitOk;
  std::string channels;
  for (const auto& [name, verdict] : result.verdicts)
    if (verdict.level == VerdictLevel::unreliable) channels += (channels.empty() ? "" : ", ") + name;
  std::fflush(stdout);  // the verdict lines first
  std::fprintf(stderr, "crfcal: --strict: channel %s unreliable (see the verdict above and report.json "
               "verdict_reasons); outputs written to %s; exit %d\n",
               channels.c_str(), args.output.c_str(), kExitUnreliable);
  return kExitUnreliable;
}

int runCalibrate(const CalibrateArgs& args) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  if (args.joint_ratio_rounds >= 0)
    throw Error("--joint-ratio-rounds applies to a joint calibration (--pair/--pairs)", ErrorSubject::options);
  if (args.threads > 0) cv::setNumThreads(args.threads);
  Progress progress(args.quiet);
  std::map<std::string, double> timings;  // the command's stages (the calibration's own are in its result)
  // Decided before the computation: a refused or unwritable output directory fails at once.
  io::OutputDirectory out(args.output, {"calibrate", {args.first, args.second, args.kernel_file, args.raw_truth}, args.force});

  progress.stage("decode");
  auto t = Clock::now();
  io::RawDecodeOptions raw;
  raw.camera_white_balance = !args.no_white_balance;
  const io::LoadedPair pair = decodePair(args, raw);
  timings["decode"] = secondsSince(t);
  progress.done(pair.sharp.format + " pair " + std::to_string(pair.blurred.image.cols) + "x" +
                std::to_string(pair.blurred.image.rows) + "; blurred = " + pair.blurred.path.filename().string() +
                " (" + pair.blurred_reason + ")");
  const double nominal_ratio = nominalRatio(args, pair);

  // The RAW of one shot: the camera's real response, measured before the (longer) pair calibration so that a bad
  // file fails fast.
  std::optional<RawTruthRun> truth;
  if (!args.raw_truth.empty()) {
    progress.stage("raw truth");
    t = Clock::now();
    truth = computeTruth(args, pair, raw);
    timings["raw_truth"] = secondsSince(t);
    progress.done(truth->file.format + " " + truth->file.path.filename().string() + " = the " +
                  (truth->shot.blurred ? "blurred" : "sharp") + " shot (" + truth->shot.reason + ")");
  }

  PairCalibrationOptions options = calibrationOptions(args, nominal_ratio);
  options.sharp_stored_chroma = {pair.sharp.chroma_block_h, pair.sharp.chroma_block_v};
  applyChromaModel(args.chroma_model, options);
  StageProgress stages{progress, {}};
  options.progress = [&stages](const std::string& stage, double fraction, const std::string& detail) {
    stages.report(stage, fraction, detail);
  };
  const PairCalibrationResult result = calibrateNamingFiles(pair, options);
  stages.finish();

  progress.stage("write");
  t = Clock::now();
  std::optional<io::RawTruthReport> truth_report;
  if (truth) {
    truth_report.emplace(io::RawTruthReport{truth->file, truth->shot.blurred, truth->shot_file, truth->shot.reason,
                                            truth->result, std::nullopt, false});
    compareWithTruth(result, *truth_report);
  }
  const io::CalibrationReportContext context{pair, nominal_ratio, args.ratio > 0 ? "--ratio" : "exif", args.fix_ratio,
                                             options.fit.ratio_prior_sigma, truth_report ? &*truth_report : nullptr};
  io::CalibrationReport report = io::calibrationReport(result, context);
  report.timings.insert(timings.begin(), timings.end());
  writeInverseCrfCsv(out, report);
  io::writeKernelText(out.file("kernel.txt"), result.kernel.kernel);
  io::writeTileKernels(out.file(""), result);
  std::map<std::string, std::vector<double>> truth_curves;
  if (truth) truth_curves = truth->result.inverse();
  io::writeCalibrationFigures(out.file(""), {result, pair, truth ? &truth_curves : nullptr});
  report.timings["write"] = secondsSince(t);
  report.timings["total"] = secondsSince(start);
  io::writeReport(out.file("report.json"), report);
  out.commit();
  progress.done();

  printCalibration(args, nominal_ratio, options, result, report, truth, truth_report);
  printVerdicts(result);
  return strictExitCode(args, result);
}

// ---- a joint calibration of several pairs (--pair / --pairs; joint_calibration.hpp)

// The pairs of the command line then of the manifest, each file checked to exist (one line naming a missing one).
std::vector<io::PairPaths> jointPairPaths(const CalibrateArgs& args) {
  std::vector<io::PairPaths> paths;
  for (const auto& [sharp, blurred] : args.pairs) {
    if (sharp.empty() || blurred.empty()) throw Error("--pair needs two files: SHARP BLURRED", sharp);
    paths.emplace_back(sharp, blurred);
  }
  if (!args.pairs_file.empty())
    for (const auto& p : io::readPairManifest(args.pairs_file)) paths.push_back(p);
  if (paths.size() < 2) throw Error("a joint calibration needs at least two pairs (--pair SHARP BLURRED, repeated, or "
                                    "--pairs FILE)");
  for (const auto& [sharp, blurred] : paths)
    for (const auto& file : {sharp, blurred})
      if (!std::filesystem::is_regular_file(file)) throw Error("no such file (a --pair/--pairs input)", file.string());
  return paths;
}

// Options that name one pair's data make no sense for several.
void requireJointCompatible(const CalibrateArgs& args) {
  if (!args.first.empty() || !args.second.empty())
    throw Error("give either SHARP BLURRED or --pair/--pairs, not both", args.first);
  for (const auto& [flag, given] : {std::pair<const char*, bool>{"--ratio", args.ratio > 0},
                                    {"--kernel", !args.kernel_file.empty()},
                                    {"--raw-truth", !args.raw_truth.empty()}})
    if (given) throw Error(std::string(flag) + " applies to one pair; it cannot be combined with --pair/--pairs");
}

int runCalibrateJoint(const CalibrateArgs& args) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  requireJointCompatible(args);
  if (args.threads > 0) cv::setNumThreads(args.threads);
  const std::vector<io::PairPaths> paths = jointPairPaths(args);
  std::vector<std::filesystem::path> inputs;
  if (!args.pairs_file.empty()) inputs.push_back(args.pairs_file);
  for (const auto& [sharp, blurred] : paths) inputs.push_back(sharp), inputs.push_back(blurred);
  io::OutputDirectory out(args.output, {"calibrate", inputs, args.force});
  Progress progress(args.quiet);
  io::RawDecodeOptions raw;
  raw.camera_white_balance = !args.no_white_balance;
  std::vector<io::LoadedPair> loaded;
  std::vector<double> nominal;
  std::vector<PairCalibrationResult> results;
  for (std::size_t p = 0; p < paths.size(); ++p) {
    CalibrateArgs one = args;
    one.first = paths[p].first.string();
    one.second = paths[p].second.string();
    progress.stage("decode " + std::to_string(p + 1));
    loaded.push_back(decodePair(one, raw));
    progress.done(loaded.back().sharp.path.filename().string() + " + " + loaded.back().blurred.path.filename().string());
    nominal.push_back(nominalRatio(one, loaded.back()));
    PairCalibrationOptions options = calibrationOptions(one, nominal.back());
    options.keep_fit_inputs = true;
    options.sharp_stored_chroma = {loaded.back().sharp.chroma_block_h, loaded.back().sharp.chroma_block_v};
    applyChromaModel(args.chroma_model, options);
    StageProgress stages{progress, {}};
    options.progress = [&stages, p](const std::string& stage, double fraction, const std::string& detail) {
      stages.report("pair " + std::to_string(p + 1) + " " + stage, fraction, detail);
    };
    results.push_back(calibrateNamingFiles(loaded.back(), options));
    stages.finish();
  }
  progress.stage("joint fit");
  JointCalibrationOptions joint_options;
  const PairCalibrationOptions pair_defaults = calibrationOptions(args, 1.0);
  joint_options.model = pair_defaults.fit;
  joint_options.band.replicates = args.band_replicates;
  joint_options.band.above_data_prior = pair_defaults.band.above_data_prior;
  if (args.joint_ratio_rounds >= 0) joint_options.ratio_rounds = args.joint_ratio_rounds;
  const JointCalibrationResult joint = calibrateJointly(results, joint_options);
  progress.done();

  progress.stage("write");
  std::vector<io::CalibrationReportContext> contexts;
  for (std::size_t p = 0; p < loaded.size(); ++p)
    contexts.push_back({loaded[p], nominal[p], "exif", args.fix_ratio, args.ratio_prior, nullptr});
  io::CalibrationReport report = io::jointCalibrationReport(joint, results, contexts);
  writeInverseCrfCsv(out, report);
  for (std::size_t p = 0; p < results.size(); ++p)
    io::writeKernelText(out.file("kernel_" + std::to_string(p + 1) + ".txt"), results[p].kernel.kernel);
  PairCalibrationResult shown;  // the joint curves in curve.png's form
  for (const auto& [c, fit] : joint.fits) shown.fits[c] = fit;
  shown.bands = joint.bands;
  shown.covered_range = joint.covered_range;
  shown.verdicts = joint.verdicts;
  io::writeCalibrationCurveFigure(out.file("curve.png"), {shown, loaded.front()});
  report.timings["total"] = secondsSince(start);
  io::writeReport(out.file("report.json"), report);
  out.commit();
  progress.done();

  std::printf("%s\n", joint.summary().c_str());
  for (const auto& w : report.warnings) std::printf("warning: %s\n", w.c_str());
  std::printf("wrote %s/{report.json, inverse_crf.csv, curve.png, kernel_1..%zu.txt}\n", args.output.c_str(),
              results.size());
  for (const char* c : {"R", "G", "B"})
    if (joint.verdicts.count(c)) std::printf("verdict %s: %s\n", c, joint.verdicts.at(c).summary().c_str());
  if (!args.strict || worstLevel(joint.verdicts) != VerdictLevel::unreliable) return kExitOk;
  std::fflush(stdout);
  std::fprintf(stderr, "crfcal: --strict: a channel of the joint fit is unreliable; outputs written to %s; exit %d\n",
               args.output.c_str(), kExitUnreliable);
  return kExitUnreliable;
}

// The shots, the pairs of a joint fit, where the output goes and how the shots are read.
void addInputOptions(CLI::App& command, const std::shared_ptr<CalibrateArgs>& args) {
  command.add_option("SHARP", args->first, "The short-exposure (sharp, noisy) shot");
  command.add_option("BLURRED", args->second, "The long-exposure (blurred) shot");
  command.add_option("--pair", args->pairs,
                     "SHARP BLURRED of one pair, repeated: several pairs of one camera fitted jointly (one phi per "
                     "channel, each pair's own kernel and r; instead of SHARP BLURRED)");
  command.add_option("--pairs", args->pairs_file,
                     "A manifest of pairs fitted jointly: one \"SHARP BLURRED\" a line (.csv or .txt; paths "
                     "relative to the manifest)");
  command.add_option("--joint-ratio-rounds", args->joint_ratio_rounds,
                     "With --pair/--pairs: rounds moving each pair's r from its own fit's r to the least-squares "
                     "r of its data at the joint phi, then refitting phi (0: each pair's r held; default " +
                         std::to_string(JointCalibrationOptions{}.ratio_rounds) + ", stopping once no r moves)")
      ->check(CLI::Range(0, 20));
  // SHARP and BLURRED are required unless the pairs come from --pair/--pairs (CLI11's own message and exit).
  command.parse_complete_callback([args] {
    if (args->joint()) return;
    if (args->first.empty()) throw CLI::RequiredError("SHARP");
    if (args->second.empty()) throw CLI::RequiredError("BLURRED");
  });
  command.add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")->required();
  command.add_flag("--force", args->force, kForceHelp);
  command.add_option("--blurred", args->blurred, "Which argument is the blurred shot: auto, first, second")
      ->check(CLI::IsMember({"auto", "first", "second"}));
  command.add_flag("--no-white-balance", args->no_white_balance, "RAW: no white balance (sensor RGB)");
  command.add_flag("--no-register", args->no_register, "The pair is already aligned (skip registration)");
  auto* raw_truth = command.add_option("--raw-truth", args->raw_truth,
                     "Camera RAW (or a linear PNG/TIFF) of one of the two shots: its RAW->JPEG relation, the "
                     "camera's real response, is written to report.json (raw_truth) and compared with the result");
  command.add_option("--raw-truth-of", args->raw_truth_of,
                     "Which shot the --raw-truth file is: auto (same exposure in EXIF, else sharp), sharp, blurred")
      ->check(CLI::IsMember({"auto", "sharp", "blurred"}))
      ->needs(raw_truth);
}

// The blur kernel: its size and growth, a given kernel, and the kernel <-> phi rounds.
void addKernelOptions(CLI::App& command, const std::shared_ptr<CalibrateArgs>& args) {
  command.add_option("--kernel-size", args->kernel_size,
                     "Kernel extent, odd (blur + residual shift); an estimate that reaches it is made again 1.5x "
                     "larger, up to --max-kernel-size")
      ->check(CLI::Range(3, 151) & oddNumber());
  command.add_option("--max-kernel-size", args->max_kernel_size,
                     "Largest kernel extent the estimate may grow to, odd, at least --kernel-size (0: a quarter "
                     "of the sharp shot's shorter side, at most 79; = --kernel-size: no growth)")
      ->capture_default_str()
      ->check(CLI::Range(0, 151));
  command.add_option("--kernel", args->kernel_file, "Use this kernel (text matrix or image) instead of estimating")
      ->check(CLI::ExistingFile);
  command.add_option("--rounds", args->rounds, "Kernel <-> phi rounds after the first fit")->check(CLI::Range(0, 10));
  command.add_option("--irradiance-kernel-lambda", args->irradiance_kernel_lambda,
                     "Sparsity weight of the irradiance-domain kernel rounds (the first estimate keeps 0.03)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_flag("--unweighted-irradiance-kernel", args->unweighted_irradiance_kernel,
                   "Irradiance-domain kernel rounds without the 1/phi'(B) weights (ablation)");
}

// The fit of phi and r (Eq. 4, 19-25): channels, model, the exposure ratio, the noise, the effects.
void addFitOptions(CLI::App& command, const std::shared_ptr<CalibrateArgs>& args) {
  command.add_option("--chroma-model", args->chroma_model,
                     "For a sharp JPEG with subsampled chroma (4:2:0, 4:2:2). check: the pointwise model, and "
                     "an R or B whose fit where the lost chroma detail is small differs in shape and lies above "
                     "(the sign of that loss's bias) is replaced by that fit (docs/RESULTS.md#chroma-replace); "
                     "auto: R and B fitted both ways in every round, keeping the chroma model's fit where it lies "
                     "above (docs/RESULTS.md#chroma-choice); off: the pointwise model everywhere")
      ->capture_default_str()
      ->check(chromaModelNames());
  command.add_option("--channels", args->channels, "Channels to fit: g (green only) or rgb")
      ->check(CLI::IsMember({"g", "rgb"}));
  command.add_option("--model", args->model, "Model of phi: ggcm (Eq. 19), emor (PCA), auto (cross-validated)")
      ->check(crfModelNames());
  command.add_option("--emor-terms", args->emor_terms,
                     "EMoR basis curves of the emor model (Grossberg & Nayar: 3-5 reach DoRF accuracy)")
      ->capture_default_str()
      ->check(CLI::Range(1, 25));
  command.add_option("--ratio", args->ratio,
                     "Exposure ratio r = dt_B/dt_I, 1/1000 .. 1000 (default 0: from EXIF, footnote 4)")
      ->check(exposureRatioOption());
  command.add_flag("--fix-ratio", args->fix_ratio,
                   "Keep r at the EXIF/--ratio value instead of fitting it (weak blur leaves r and the curve's "
                   "exponent ambiguous: phi^g, r^g fit equally)");
  command.add_flag("--always-fit-ratio", args->always_fit_ratio,
                   "Fit r even when the blur is too small to determine it (by default, with a kernel RMS radius "
                   "< 1 px and the images' r more than 10 % from the EXIF/--ratio value, r is held at that value)")
      ->excludes("--fix-ratio");
  command.add_option("--ratio-evidence", args->ratio_evidence,
                     "on: r from the images combined with the EXIF/--ratio value by their precisions, the images' "
                     "measured on half-sample refits (a blur that fixes r keeps the images' r; one that does not "
                     "hands it to EXIF); off: r from the images alone")
      ->capture_default_str()
      ->check(CLI::IsMember({"on", "off"}));
  command.add_flag("--ratio-noise-bias", args->ratio_noise_bias,
                   "With --ratio-evidence on: also measure the noise bias of the images' r by SIMEX and widen its "
                   "sigma by it (three more fits of G; measured not to help, docs/RESULTS.md)");
  command.add_option("--ratio-prior", args->ratio_prior,
                     "Fitted r: sigma of the prior on log r around the EXIF/--ratio value, weighed against what the "
                     "blur determines (0: r from the images alone)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_option("--shoulder", args->shoulder,
                     "Extrapolation of phi above the data: rising-free (the local exponent may rise freely), "
                     "mean-camera (it rises like the EMoR mean curve's) or learned (above and below the data: a "
                     "prior learned from the measured camera curves in samples/camera_curves)")
      ->capture_default_str()
      ->check(CLI::IsMember({"rising-free", "mean-camera", "learned"}));
  command.add_option("--noise-handling", args->noise_handling,
                     "The sharp shot's noise in the fit: jensen (second-order correction of Jensen's bias), none, "
                     "debias (deconvolution), denoise (bilateral)")
      ->capture_default_str()
      ->check(CLI::IsMember({"jensen", "none", "debias", "denoise"}));
  command.add_option("--censored-weight", args->censored_weight,
                     "Weight of the blurred shot's clipped pixels as censored observations of the fit (where B "
                     "clips, r (phi(I) (x) K) >= phi(1); 1: as data, 0: excluded as in the seed)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_flag("--no-effects", args->no_effects,
                   "Skip the effect diagnostics (effects.hpp): faster; phi is the base fit of Eq. 4");
}

// The band of phi, threads, the exit code and the progress output.
void addReportOptions(CLI::App& command, const std::shared_ptr<CalibrateArgs>& args) {
  command.add_option("--band-replicates", args->band_replicates,
                     "Half-sample refits per channel for the 90 % band of phi (even; more: a steadier band, "
                     "each costs about half a fit; 0: no band)")
      ->capture_default_str()
      ->check(bandReplicates());
  command.add_option("--band-above", args->band_above,
                     "The band above the covered range: the 90 % spread of the prior learned from the measured "
                     "camera curves in samples/camera_curves, given the curve's shape on the data (learned), or "
                     "bounds on phi's local exponent there (bounds)")
      ->capture_default_str()
      ->check(CLI::IsMember({"bounds", "learned"}));
  command.add_option("--threads", args->threads, "Worker threads, 0 .. " + std::to_string(kMaxThreads) +
                                                     " (0: all cores)")
      ->check(CLI::Range(0, kMaxThreads));
  command.add_flag("--strict", args->strict,
                   "Exit with code 4 when any channel's verdict is \"unreliable\" (the outputs are still written; "
                   "report.json verdict_reasons says why)");
  command.add_flag("-q,--quiet", args->quiet, "No progress output");
}

const CommandRegistration registration(
    30, "calibrate", "Measure the camera response from a real handheld sharp/blurred pair (JPEG, PNG, TIFF or RAW; Sec. 4)",
    [](CLI::App& command) {
      auto args = std::make_shared<CalibrateArgs>();
      addInputOptions(command, args);
      addKernelOptions(command, args);
      addFitOptions(command, args);
      addReportOptions(command, args);
      return [args] { return args->joint() ? runCalibrateJoint(*args) : runCalibrate(*args); };
    });

}  // namespace
}  // namespace crfcal::app
