// crfcal chart: ColorChecker calibration of the inverse response (EMoR/PCA fit, converted to GGCM).
#include <cmath>
#include <cstdio>
#include <sstream>

#include <nlohmann/json.hpp>

#include "command.hpp"
#include "crfcal/chart_calibration.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
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
  std::string reference = "neutral";
  std::string patches = "neutral";
  std::string exposures;
  bool no_exif = false;
  std::string truth;
  std::string output;
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
      values.push_back(std::stod(item));
    } catch (const std::exception&) {
      throw InvalidInput(what + ": '" + item + "' is not a number");
    }
  }
  return values;
}

// RMSE over [lo, hi] after the best common factor a·φ (the normalisation φ(1) = 1 depends on the extrapolation
// above the data; this isolates the shape error).
double scaledRmseOver(const std::vector<double>& truth, const std::vector<double>& fit, double lo, double hi) {
  double num = 0, den = 0;
  for (size_t i = 0; i < truth.size() && i < fit.size(); ++i) {
    const double x = double(i) / double(truth.size() - 1);
    if (x < lo || x > hi) continue;
    num += truth[i] * fit[i];
    den += fit[i] * fit[i];
  }
  const double a = den > 0 ? num / den : 1.0;
  std::vector<double> scaled(fit);
  for (double& v : scaled) v *= a;
  double sum = 0;
  int n = 0;
  for (size_t i = 0; i < truth.size() && i < fit.size(); ++i) {
    const double x = double(i) / double(truth.size() - 1);
    if (x < lo || x > hi) continue;
    sum += (truth[i] - scaled[i]) * (truth[i] - scaled[i]);
    ++n;
  }
  return n > 0 ? std::sqrt(sum / n) : 0.0;
}

double rmseOver(const std::vector<double>& a, const std::vector<double>& b, double lo, double hi) {
  double sum = 0;
  int n = 0;
  for (size_t i = 0; i < a.size() && i < b.size(); ++i) {
    const double x = double(i) / double(a.size() - 1);
    if (x < lo || x > hi) continue;
    sum += (a[i] - b[i]) * (a[i] - b[i]);
    ++n;
  }
  return n > 0 ? std::sqrt(sum / n) : 0.0;
}

int runChart(ChartArgs args) {
  Progress progress(args.quiet);
  if (!args.raws.empty() && args.raws.size() != args.images.size())
    throw InvalidInput("--raw needs one RAW image per IMAGE (" + std::to_string(args.images.size()) + ")");
  if (!args.corners.empty() && args.corners.size() != 1 && args.corners.size() != args.images.size())
    throw InvalidInput("--corners: give one set for all images or one per image");
  const io::ChartLayout layout = io::parseChartLayout(args.layout);
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
  std::vector<double> exposures;
  if (!args.exposures.empty()) {
    exposures = parseList(args.exposures, "--exposures");
    if (exposures.size() != args.images.size()) throw InvalidInput("--exposures needs one value per IMAGE");
  }

  progress.stage("sample patches");
  std::vector<ChartShot> shots;
  std::vector<cv::Mat> rectified;  // written as chart_<i>.png to check the detection
  nlohmann::json inputs = nlohmann::json::array();
  for (size_t i = 0; i < args.images.size(); ++i) {
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
    if (!exposures.empty()) shot.exposure = exposures[i];
    else if (!args.no_exif && !options.use_raw) {
      const ExifExposure exif = io::readExif(args.images[i]);
      if (exif.usable()) shot.exposure = *exif.iso * *exif.exposure_time / std::pow(exif.f_number.value_or(1.0), 2);
    }
    rectified.push_back(loaded.rectified);
    nlohmann::json entry;
    entry["image"] = args.images[i];
    entry["rectified"] = "chart_" + std::to_string(i + 1) + ".png";
    if (options.use_raw) entry["raw"] = args.raws[i];
    entry["chart"] = loaded.how;
    entry["corners"] = nlohmann::json::array();
    for (const auto& p : loaded.corners) entry["corners"].push_back({p.x, p.y});
    entry["exposure"] = shot.exposure > 0 ? nlohmann::json(shot.exposure) : nlohmann::json(nullptr);
    int rejected = 0;
    nlohmann::json rejections = nlohmann::json::object();
    for (const auto& p : shot.measured)
      if (!p.usable()) {
        ++rejected;
        rejections[std::string(chart::reference()[static_cast<size_t>(p.patch)].name)] = p.rejection();
      }
    entry["rejected_patches"] = rejections;
    inputs.push_back(entry);
    shots.push_back(std::move(shot));
    progress.update(double(i + 1) / double(args.images.size()), loaded.how);
  }
  progress.done();

  progress.stage("fit");
  const ChartCalibrationResult result =
      calibrateChart(shots, options, [&](double f, const std::string& d) { progress.update(f, d); });
  progress.done();

  io::CalibrationReport report;
  report.command = "chart";
  report.warnings = result.warnings;
  nlohmann::json channels_json = nlohmann::json::object();
  nlohmann::json patches_json = nlohmann::json::array();
  for (const auto& c : result.channels) {
    const std::string name = channelName(c.channel);
    report.inverse_crf[name] = c.fit.inverse;
    report.models[name] = c.ggcm;
    report.covered_range[name] = c.fit.covered_range;
    report.pixels_used[name] = c.fit.observations;
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
    channels_json[name] = ch;
    for (const auto& p : c.patches)
      patches_json.push_back({{"channel", name},
                              {"shot", shots[static_cast<size_t>(p.shot)].name},
                              {"patch", std::string(chart::reference()[static_cast<size_t>(p.patch)].name)},
                              {"x", p.x},
                              {"reference", p.reference},
                              {"residual", p.residual}});
  }
  report.extra["chart"] = {{"reference", options.use_raw ? "raw" : chart::referenceSetName(options.reference)},
                           {"patches", options.use_raw ? args.patches : chart::referenceSetName(options.reference)},
                           {"inputs", inputs},
                           {"channels", channels_json},
                           {"inverse_crf_model", "emor (models: its GGCM conversion, seed Eq. 19)"}};
  report.extra["patch_residuals"] = patches_json;

  std::vector<std::pair<std::string, std::vector<double>>> truth_curves;
  if (!args.truth.empty()) {
    nlohmann::json comparison = nlohmann::json::object();
    if (!args.quiet) std::printf("%-3s %10s %12s %14s %10s\n", "ch", "rmse[0,1]", "rmse covered", "scaled covered", "max");
    for (const auto& c : result.channels) {
      const std::string name = channelName(c.channel);
      const std::vector<double> truth = io::readCurveTable(args.truth, name, kCurveSamples);
      double max_error = 0;
      for (size_t i = 0; i < truth.size(); ++i) max_error = std::max(max_error, std::abs(truth[i] - c.fit.inverse[i]));
      const double rmse = curveRmse(truth, c.fit.inverse);
      const double covered = rmseOver(truth, c.fit.inverse, c.fit.covered_range.first, c.fit.covered_range.second);
      const double scaled = scaledRmseOver(truth, c.fit.inverse, c.fit.covered_range.first, c.fit.covered_range.second);
      comparison[name] = {{"rmse", rmse}, {"rmse_covered", covered}, {"rmse_covered_scale_aligned", scaled},
                          {"max_error", max_error},
                          {"ggcm_rmse", curveRmse(truth, sampleInverse(c.ggcm, kCurveSamples))}};
      truth_curves.emplace_back(name + " truth", truth);
      std::printf("%-3s %10.4f %12.4f %14.4f %10.4f\n", name.c_str(), rmse, covered, scaled, max_error);
    }
    report.extra["truth"] = {{"file", args.truth}, {"phi_error", comparison}};
  }

  io::OutputDirectory out(args.output);
  io::writeReport(out.file("report.json"), report);
  for (size_t i = 0; i < rectified.size(); ++i) io::writeImage(out.file("chart_" + std::to_string(i + 1) + ".png"), rectified[i]);
  io::writeChartPlot(out.file("chart_fit.png"), result,
                     "ColorChecker: patches on the fitted curve (" +
                         std::string(options.use_raw ? "RAW reference" : chart::referenceSetName(options.reference)) +
                         ")",
                     truth_curves);
  out.commit();
  if (!args.quiet) std::printf("%s", result.summary().c_str());
  for (const auto& w : result.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
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
                         "Published reference: neutral (6 greys, Y; default) | srgb (24 patches, linear sRGB of the "
                         "channel) | luminance (24 patches, Y)")
          ->check(CLI::IsMember({"neutral", "srgb", "luminance"}));
      command.add_option("--patches", args->patches, "With --raw: patches used (neutral = the 6 greys)")
          ->check(CLI::IsMember({"all", "neutral"}));
      command.add_option("--exposures", args->exposures,
                         "Relative exposures e1,e2,… of the shots (default: EXIF ISO·t/N²; without EXIF one free "
                         "scale per shot)");
      command.add_flag("--no-exif", args->no_exif, "Ignore EXIF: one free exposure scale per shot");
      command.add_option("--channels", args->channels, "Channels to calibrate (letters of RGB)");
      command.add_option("--terms", args->options.fit.terms, "EMoR terms K (0 = cross-validation)")
          ->check(CLI::Range(0, 25));
      command.add_option("--max-terms", args->options.fit.max_terms, "Largest K tried by cross-validation")
          ->check(CLI::Range(1, 25));
      command.add_option("--smoothness", args->options.fit.smoothness, "Roughness penalty (see chart_calibration.hpp)")
          ->check(CLI::NonNegativeNumber);
      command.add_option("--inner", args->sampling.inner_fraction, "Sampled fraction of the patch pitch")
          ->check(CLI::Range(0.1, 1.0));
      command.add_option("--truth", args->truth,
                         "Reference curve (report.json or table) to compare with: phi RMSE per channel")
          ->check(CLI::ExistingFile);
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runChart(*args); };
    });

}  // namespace
}  // namespace crfcal::app
