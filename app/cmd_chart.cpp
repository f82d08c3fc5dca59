// crfcal chart: ColorChecker calibration of the inverse response (EMoR/PCA fit, converted to GGCM).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "command.hpp"
#include "option_checks.hpp"
#include "crfcal/chart_calibration.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/band_report.hpp"
#include "crfcal/io/chart_io.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

struct ChartArgs {
  std::vector<std::string> images;
  std::vector<std::string> raws;
  std::vector<std::string> corners;
  std::string layout = "auto";
  std::string reference = "all";  // measured better than "neutral" on the Middlebury cameras (docs/RESULTS.md#chart)
  std::string patches = "neutral";
  std::string exposures;
  std::string scenes;  // --scenes: a scene label per image (default: one scene)
  bool no_exif = false;
  std::string truth;
  std::string output;
  bool force = false;  // write into an output directory holding other files (never deletes them)
  std::string channels = "RGB";
  ChartCalibrationOptions options;
  chart::PatchSamplingOptions sampling;
  bool quiet = false;
};

std::vector<double> parseList(const std::string& text, const std::string& what) {
  std::vector<double> values;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    try {
      size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InvalidInput(what + ": '" + item + "' is not a number");
    }
  }
  return values;
}

// --exposures: relative exposures (ISO·t/N² up to a common factor), one per IMAGE in the same order. Each must be
// positive and finite: a bad value used to turn every shot into a free scale silently.
std::vector<double> parseExposures(const std::string& text, size_t images) {
  const std::vector<double> exposures = parseList(text, "--exposures");
  if (exposures.size() != images)
    throw InvalidInput("--exposures needs one value per IMAGE (" + std::to_string(images) + ", got " +
                       std::to_string(exposures.size()) + ")");
  for (const double e : exposures)
    if (!(std::isfinite(e) && e > 0))
      throw InvalidInput("--exposures: " + text + ": every exposure must be a positive finite number");
  return exposures;
}

// The exposures pair with the images in the order given; the order itself does not matter. But a shot given more
// exposure than another must not be darker on the patches both measure: reversed values (8,4,2,1 for shots taken
// 1,2,4,8) fitted with an RMSE of 0.24–0.30 instead of being refused. The test is the majority of common usable
// patches (green channel), so that noise on one patch cannot trip it.
void requireExposuresFollowBrightness(const std::vector<ChartShot>& shots, const std::vector<std::string>& names) {
  for (size_t i = 0; i < shots.size(); ++i)
    for (size_t j = 0; j < shots.size(); ++j) {
      if (!(shots[i].exposure > 1.05 * shots[j].exposure)) continue;
      int common = 0, darker = 0;
      for (size_t p = 0; p < shots[i].measured.size() && p < shots[j].measured.size(); ++p) {
        const chart::PatchStats &a = shots[i].measured[p], &b = shots[j].measured[p];
        if (!a.usable() || !b.usable()) continue;
        ++common;
        darker += a.median[1] < b.median[1];
      }
      if (common >= 3 && 2 * darker > common)
      {
        char text[200];
        std::snprintf(text, sizeof text, " is given %.3gx the exposure of %s but is darker on %d of %d patches: ",
                      shots[i].exposure / shots[j].exposure, names[j].c_str(), darker, common);
        throw InvalidInput("--exposures: " + names[i] + text + "the values must follow the order of the images");
      }
    }
}

// --scenes: one label per IMAGE (any integers; equal labels = the same scene: chart, light and white balance).
std::vector<int> parseScenes(const std::string& text, size_t images) {
  std::vector<int> scenes;
  for (const double v : parseList(text, "--scenes")) {
    if (v != std::floor(v) || std::abs(v) > 1e6) throw InvalidInput("--scenes: " + text + ": labels must be integers");
    scenes.push_back(int(v));
  }
  if (scenes.size() != images)
    throw InvalidInput("--scenes needs one label per IMAGE (" + std::to_string(images) + ", got " +
                       std::to_string(scenes.size()) + ")");
  return scenes;
}

double secondsSince(std::chrono::steady_clock::time_point from) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - from).count();
}

// The calibration options the flags ask for (refusing unknown channel letters).
ChartCalibrationOptions chartOptions(const ChartArgs& args) {
  ChartCalibrationOptions options = args.options;
  options.use_raw = !args.raws.empty();
  options.raw_neutral_only = args.patches == "neutral";
  options.reference = chart::parseReferenceSet(args.reference);
  options.channels.clear();
  for (char c : args.channels) {
    if (c == 'R') options.channels.push_back(0);
    else if (c == 'G') options.channels.push_back(1);
    else if (c == 'B') options.channels.push_back(2);
    else throw InvalidInput("--channels: use letters R, G, B");
  }
  return options;
}

// The sampled shots with what report.json says of each input, and what the rectified charts look like.
struct SampledCharts {
  std::vector<ChartShot> shots;
  std::vector<cv::Mat> rectified;  // written as chart_<i>.png to check the detection
  nlohmann::json inputs = nlohmann::json::array();
  std::vector<std::string> warnings;
};

nlohmann::json rejectedPatches(const std::vector<chart::PatchStats>& measured) {
  nlohmann::json rejections = nlohmann::json::object();
  for (const auto& p : measured)
    if (!p.usable()) rejections[std::string(chart::reference()[static_cast<size_t>(p.patch)].name)] = p.rejection();
  return rejections;
}

// Image i: the chart found and rectified, its patches sampled (and those of its RAW rendering), its exposure.
void sampleShot(const ChartArgs& args, const ChartCalibrationOptions& options, const io::ChartLayout& layout,
                const std::vector<double>& exposures, size_t i, SampledCharts& sampled, Progress& progress) {
  std::optional<chart::ChartCorners> corners;
  if (!args.corners.empty()) corners = io::parseCorners(args.corners.size() == 1 ? args.corners[0] : args.corners[i]);
  const io::LoadedChart loaded = io::loadChart(args.images[i], layout, corners);
  ChartShot shot;
  shot.name = std::filesystem::path(args.images[i]).filename().string();
  shot.measured = chart::sampleRectified(loaded.rectified, args.sampling);
  if (options.use_raw) {
    // The RAW rendering of the same shot has the same geometry.
    const io::LoadedChart raw = io::loadChart(args.raws[i], layout, loaded.corners);
    shot.raw = chart::sampleRectified(raw.rectified, args.sampling);
  }
  if (!args.scenes.empty()) shot.scene = parseScenes(args.scenes, args.images.size())[i];
  if (!exposures.empty()) shot.exposure = exposures[i];
  else if (!args.no_exif && !options.use_raw) {
    const ExifExposure exif = io::readExif(args.images[i]);
    if (exif.usable()) shot.exposure = *exif.iso * *exif.exposure_time / std::pow(exif.f_number.value_or(1.0), 2);
  }
  sampled.rectified.push_back(loaded.rectified);
  nlohmann::json entry;
  entry["image"] = args.images[i];
  entry["rectified"] = "chart_" + std::to_string(i + 1) + ".png";
  if (options.use_raw) entry["raw"] = args.raws[i];
  entry["chart"] = loaded.how;
  entry["corners"] = nlohmann::json::array();
  for (const auto& p : loaded.corners) entry["corners"].push_back({p.x, p.y});
  entry["exposure"] = shot.exposure > 0 ? nlohmann::json(shot.exposure) : nlohmann::json(nullptr);
  entry["rejected_patches"] = rejectedPatches(shot.measured);
  // A shot without a single usable patch contributes nothing: say so rather than fit silently without it.
  for (const auto* side : {&shot.measured, &shot.raw}) {
    if (side->empty()) continue;
    int usable = 0;
    for (const auto& p : *side) usable += p.usable();
    if (usable == 0)
      sampled.warnings.push_back((side == &shot.raw ? args.raws[i] : args.images[i]) +
                                 ": no usable patch (all clipped or non-uniform); the shot adds no data");
  }
  sampled.inputs.push_back(entry);
  sampled.shots.push_back(std::move(shot));
  progress.update(double(i + 1) / double(args.images.size()), loaded.how);
}

// Too few usable patches: the refusal names the image with the most rejected patches and says why.
[[noreturn]] void refuseTooFewPatches(const ChartArgs& args, const std::vector<ChartShot>& shots, const InvalidInput& e) {
  std::string worst;
  int worst_clipped = -1, worst_non_uniform = 0;
  for (size_t i = 0; i < shots.size(); ++i)
    for (const bool raw : {false, true}) {
      const auto& side = raw ? shots[i].raw : shots[i].measured;
      int clipped = 0, non_uniform = 0;
      for (const auto& p : side) clipped += p.clipped, non_uniform += !p.clipped && p.non_uniform;
      if (!side.empty() && clipped + non_uniform > worst_clipped + worst_non_uniform) {
        worst = raw ? args.raws[i] : args.images[i];
        worst_clipped = clipped;
        worst_non_uniform = non_uniform;
      }
    }
  throw InvalidInput(e.reason() + "; in this image " + std::to_string(worst_clipped) + " of 24 patches are clipped, " +
                         std::to_string(worst_non_uniform) + " non-uniform (wrong chart geometry? try --corners)",
                     worst);
}

nlohmann::json channelJson(const ChartChannelResult& c) {
  nlohmann::json ch;
  ch["emor"] = {{"kind", "emor"}, {"parameters", c.fit.model.coefficients}, {"spec", describe(c.fit.model)}};
  ch["terms"] = c.fit.terms;
  ch["cv_rmse"] = nlohmann::json::object();
  for (const auto& [k, e] : c.fit.cv_rmse) ch["cv_rmse"][std::to_string(k)] = e;
  ch["rmse"] = c.fit.rmse;
  ch["max_error"] = c.fit.max_error;
  ch["scales"] = c.fit.scales;
  ch["ggcm_rmse_vs_emor"] = c.ggcm_rmse;
  ch["ggcm_valid"] = c.ggcm_valid;
  ch["patch_samples"] = c.fit.observations;
  ch["censored_samples"] = c.fit.censored;
  ch["rejected_samples"] = c.rejected;
  return ch;
}

// The curves and the chart section of report.json (timings and truth are added by the caller).
io::CalibrationReport chartReport(const ChartArgs& args, const ChartCalibrationOptions& options,
                                  const SampledCharts& sampled, const ChartCalibrationResult& result) {
  io::CalibrationReport report;
  report.command = "chart";
  report.warnings = sampled.warnings;
  report.warnings.insert(report.warnings.end(), result.warnings.begin(), result.warnings.end());
  nlohmann::json channels_json = nlohmann::json::object();
  nlohmann::json patches_json = nlohmann::json::array();
  std::map<std::string, CurveBand> bands;
  for (const auto& c : result.channels) {
    const std::string name = channelName(c.channel);
    addScaledFitChannel(report, name, c.fit, c.ggcm);
    channels_json[name] = channelJson(c);
    if (!c.band.empty()) bands[name] = c.band;
    for (const auto& p : c.patches)
      patches_json.push_back({{"channel", name},
                              {"shot", sampled.shots[static_cast<size_t>(p.shot)].name},
                              {"patch", std::string(chart::reference()[static_cast<size_t>(p.patch)].name)},
                              {"x", p.x},
                              {"reference", p.reference},
                              {"residual", p.residual}});
  }
  report.extra["chart"] = {{"reference", options.use_raw ? "raw" : chart::referenceSetName(options.reference)},
                           {"patches", options.use_raw ? args.patches : chart::referenceSetName(options.reference)},
                           {"inputs", sampled.inputs},
                           {"channels", channels_json},
                           {"inverse_crf_model", "emor (models: its GGCM conversion, seed Eq. 19)"}};
  // --reference all: the relative exposure of each shot the fit used (given or fitted; the brightest = 1), its scene.
  if (!result.exposures.empty()) {
    report.extra["chart"]["exposures"] = result.exposures;
    nlohmann::json scenes = nlohmann::json::array();
    for (const auto& shot : sampled.shots) scenes.push_back(shot.scene);
    report.extra["chart"]["scenes"] = scenes;
  }
  report.extra["patch_residuals"] = patches_json;
  if (!bands.empty())
    report.extra["inverse_crf_band"] = io::curveBandsJson(
        bands, "half-sample refits of the patches, K and exposures held (shape) + local-exponent bounds beyond the "
               "covered range (scale); scaled_fit_band.hpp");
  return report;
}

// --truth: each channel's error against the known curve (printed, and in report.json); returns the curves to plot.
std::vector<std::pair<std::string, std::vector<double>>> compareWithTruth(const ChartArgs& args,
                                                                          const ChartCalibrationResult& result,
                                                                          io::CalibrationReport& report) {
  std::vector<std::pair<std::string, std::vector<double>>> truth_curves;
  // The truth's covered range (a report's) is intersected with the calibration's, as `crfcal compare` does.
  std::map<std::string, IntensityRange> truth_covered;
  if (std::filesystem::path(args.truth).extension() == ".json") truth_covered = io::readReport(args.truth).covered_range;
  nlohmann::json comparison = nlohmann::json::object();
  if (!args.quiet)
    std::printf("%-3s %10s %12s %12s %10s\n", "ch", "rmse[0,1]", "rmse covered", "rmse aligned", "max[0,1]");
  for (const auto& c : result.channels) {
    const std::string name = channelName(c.channel);
    const std::vector<double> truth = io::readCurveTable(args.truth, name, kCurveSamples);
    const auto it = truth_covered.find(name);
    const ChannelComparison e =
        compareCurves(truth, c.fit.inverse,
                      it == truth_covered.end() ? std::optional<IntensityRange>() : std::optional<IntensityRange>(it->second),
                      c.fit.covered_range);
    comparison[name] = {{"rmse", e.rmse},
                        {"rmse_covered", e.rmse_covered},
                        {"rmse_covered_aligned", e.rmse_covered_aligned},
                        {"scale_covered", e.scale_covered},
                        {"covered_range", {e.covered.first, e.covered.second}},
                        {"max_error", e.max_error},
                        {"ggcm_rmse", curveRmse(truth, sampleInverse(c.ggcm, kCurveSamples))}};
    truth_curves.emplace_back(name + " truth", truth);
    std::printf("%-3s %10.4f %12.4f %12.4f %10.4f\n", name.c_str(), e.rmse, e.rmse_covered, e.rmse_covered_aligned,
                e.max_error);
  }
  report.extra["truth"] = {{"file", args.truth}, {"phi_error", comparison}};
  return truth_curves;
}

int runChart(ChartArgs args) {
  Progress progress(args.quiet);
  if (!args.raws.empty() && args.raws.size() != args.images.size())
    throw InvalidInput("--raw needs one RAW image per IMAGE (" + std::to_string(args.images.size()) + ")");
  if (!args.corners.empty() && args.corners.size() != 1 && args.corners.size() != args.images.size())
    throw InvalidInput("--corners: give one set for all images or one per image");
  const io::ChartLayout layout = io::parseChartLayout(args.layout);
  // A bad --truth (NaN, decreasing, not a curve) is refused before the calibration, not after it; the same reader
  // and validation as every other curve (io::readCurveTable, checkInverseSamples).
  if (!args.truth.empty()) io::readCurveTable(args.truth, args.channels.find('G') != std::string::npos ? "G" : "R");
  const ChartCalibrationOptions options = chartOptions(args);
  std::vector<double> exposures;
  if (!args.exposures.empty()) exposures = parseExposures(args.exposures, args.images.size());
  if (!args.scenes.empty()) parseScenes(args.scenes, args.images.size());  // refused before any output

  // Decided before the computation: a refused or unwritable output directory fails at once.
  std::vector<std::filesystem::path> input_files(args.images.begin(), args.images.end());
  input_files.insert(input_files.end(), args.raws.begin(), args.raws.end());
  input_files.push_back(args.truth);
  io::OutputDirectory out(args.output, {"chart", input_files, args.force});

  const auto start = std::chrono::steady_clock::now();
  progress.stage("sample patches");
  SampledCharts sampled;
  for (size_t i = 0; i < args.images.size(); ++i) sampleShot(args, options, layout, exposures, i, sampled, progress);
  if (!exposures.empty()) requireExposuresFollowBrightness(sampled.shots, args.images);
  progress.done();
  const double sample_seconds = secondsSince(start);

  const auto fit_start = std::chrono::steady_clock::now();
  progress.stage("fit");
  ChartCalibrationResult result;
  try {
    result = calibrateChart(sampled.shots, options, [&](double f, const std::string& d) { progress.update(f, d); });
  } catch (const InvalidInput& e) {
    refuseTooFewPatches(args, sampled.shots, e);
  }
  progress.done();
  const std::map<std::string, double> timings = {
      {"sample", sample_seconds}, {"fit", secondsSince(fit_start)}, {"total", secondsSince(start)}};

  io::CalibrationReport report = chartReport(args, options, sampled, result);
  report.timings = timings;
  std::vector<std::pair<std::string, std::vector<double>>> truth_curves;
  if (!args.truth.empty()) truth_curves = compareWithTruth(args, result, report);

  io::writeReport(out.file("report.json"), report);
  for (size_t i = 0; i < sampled.rectified.size(); ++i)
    io::writeImage(out.file("chart_" + std::to_string(i + 1) + ".png"), sampled.rectified[i]);
  io::writeChartPlot(out.file("chart_fit.png"), result,
                     "ColorChecker: patches on the fitted curve (" +
                         std::string(options.use_raw ? "RAW reference" : chart::referenceSetName(options.reference)) +
                         ")",
                     truth_curves);
  out.commit();
  if (!args.quiet) std::printf("%s", result.summary().c_str());
  for (const auto& w : report.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
  std::printf("wrote %s/{report.json, chart_fit.png, chart_<i>.png}\n", args.output.c_str());
  return kExitOk;
}

const CommandRegistration registration(
    40, "chart",
    "Calibrate the inverse response from ColorChecker Classic shots (EMoR fit with exposure scales, GGCM conversion)",
    [](CLI::App& command) {
      auto args = std::make_shared<ChartArgs>();
      command.add_option("images", args->images, "Chart shots (several exposures extend the covered range)")
          ->required()
          ->check(CLI::ExistingFile);
      command.add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")->required();
      command.add_flag("--force", args->force, kForceHelp);
      command.add_option("--raw", args->raws,
                         "Linear RAW renderings of the same shots (same geometry): the reference instead of the "
                         "published reflectances (exact, per channel)")
          ->check(CLI::ExistingFile);
      command.add_option("--layout", args->layout,
                         "auto: rectified when the image is a 3:2 crop ≤ 1000 px wide, else mcc detection | "
                         "rectified: the whole image is the 6×4 patch grid | detect: OpenCV mcc")
          ->check(CLI::IsMember({"auto", "rectified", "detect"}));
      command.add_option("--corners", args->corners,
                         "x1,y1,x2,y2,x3,y3,x4,y4: outer corners of the patch grid at dark skin, bluish green, "
                         "black, white (once for all images or once per image)");
      command.add_option("--reference", args->reference,
                         "Reference: all (default; 24 patches: the greys' Y anchor, each coloured patch an unknown "
                         "irradiance shared by the shots of a scene) | neutral (6 greys, Y) | srgb (24 "
                         "patches, linear sRGB of the channel) | luminance (24 patches, Y)")
          ->check(CLI::IsMember({"neutral", "all", "srgb", "luminance"}));
      command.add_option("--patches", args->patches, "With --raw: patches used (neutral = the 6 greys)")
          ->check(CLI::IsMember({"all", "neutral"}));
      command.add_option("--exposures", args->exposures,
                         "Relative exposures e1,e2,… of the shots (default: EXIF ISO·t/N²; without EXIF one free "
                         "scale per shot)");
      command.add_option("--scenes", args->scenes,
                         "With --reference all: a scene label per image, e.g. 1,1,1,1,2,2,2,2 (shots of one scene share "
                         "chart, light and white balance; default: all one scene)");
      command.add_option("--colour-outliers", args->options.colour_outlier_factor,
                         "With --reference all: leave out coloured patches misfitting the channel's curve by more than "
                         "this many times the median patch (0 = keep all)")
          ->check(CLI::NonNegativeNumber);
      command.add_flag("--no-exif", args->no_exif, "Ignore EXIF: one free exposure scale per shot");
      command.add_option("--channels", args->channels, "Channels to calibrate (letters of RGB)");
      command.add_option("--terms", args->options.fit.terms, "EMoR terms K (0 = cross-validation)")
          ->check(CLI::Range(0, 25));
      command.add_option("--max-terms", args->options.fit.max_terms, "Largest K tried by cross-validation")
          ->check(CLI::Range(1, 25));
      command.add_option("--smoothness", args->options.fit.smoothness,
                         "Roughness penalty on phi's second differences (ScaledFitOptions::smoothness)")
          ->check(CLI::NonNegativeNumber);
      command.add_option("--exponent-smoothness", args->options.fit.exponent_smoothness,
                         "Penalty on changes of phi's local exponent dlog(phi)/dlog(x); decides phi between the "
                         "brightest patch and phi(1) = 1 (ScaledFitOptions::exponent_smoothness)")
          ->check(CLI::NonNegativeNumber);
          command.add_option("--inner", args->sampling.inner_fraction,
                         "Side of the sampled square in each patch, as a fraction of the patch pitch")
          ->check(CLI::Range(0.1, 1.0));
      command.add_option("--clip", args->sampling.clip_high,
                         "A pixel at or above this value (unit scale, any channel) counts as clipped; a patch with "
                         "more than 2 % such pixels is only a bound")
          ->check(CLI::Range(0.5, 1.0));
      command.add_option("--truth", args->truth,
                         "Reference curve (report.json or table) to compare with: phi RMSE per channel over [0,1], "
                         "over the covered range, and there after the best common factor (as crfcal compare)")
          ->check(CLI::ExistingFile);
      command.add_option("--band-replicates", args->options.band.replicates,
                         "With --reference all: refits on halves of the patches per channel for the 90 % band of phi "
                         "(even; 0: no band)")
          ->capture_default_str()
          ->check(bandReplicates());
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runChart(*args); };
    });

}  // namespace
}  // namespace crfcal::app
