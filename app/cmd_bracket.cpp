// crfcal bracket IMG… -o DIR: the camera's response from a static multi-exposure bracket of any scene (Debevec &
// Malik 1997 / Robertson et al. style, crfcal's EMoR fit; bracket_calibration.hpp). Writes report.json (the common
// schema: compare and export read it), curve.png, points.png.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>
#include <sstream>

#include "command.hpp"
#include "option_checks.hpp"
#include "crfcal/bracket_calibration.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/bracket_report.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/report.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

struct BracketArgs {
  std::vector<std::string> images;
  std::string output;
  bool force = false;
  bool no_exif = false;
  bool no_register = false;
  std::string exposures;  // e1,e2,… (relative), instead of EXIF
  std::string channels = "RGB";
  BracketCalibrationOptions options;
  bool quiet = false;
};

std::vector<double> parseExposures(const std::string& text, std::size_t images) {
  std::vector<double> values;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    std::size_t used = 0;
    double v = 0;
    try {
      v = std::stod(item, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used != item.size() || used == 0 || !(std::isfinite(v) && v > 0))
      throw InvalidInput("--exposures: '" + item + "' is not a positive number", ErrorSubject::options);
    values.push_back(v);
  }
  if (values.size() != images)
    throw InvalidInput("--exposures needs one value per IMAGE (" + std::to_string(images) + ", got " +
                           std::to_string(values.size()) + ")",
                       ErrorSubject::options);
  return values;
}

double secondsSince(std::chrono::steady_clock::time_point from) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - from).count();
}

int runBracket(BracketArgs args) {
  Progress progress(args.quiet);
  BracketCalibrationOptions options = args.options;
  options.register_frames = !args.no_register;
  options.channels.clear();
  for (char c : args.channels) {
    const std::string letters = "RGB";
    const auto i = letters.find(char(std::toupper(static_cast<unsigned char>(c))));
    if (i == std::string::npos) throw InvalidInput("--channels: '" + std::string(1, c) + "' is not R, G or B");
    options.channels.push_back(int(i));
  }
  options.check();
  std::vector<double> given;
  if (!args.exposures.empty()) given = parseExposures(args.exposures, args.images.size());
  io::OutputDirectory out(args.output, {"bracket", {args.images.begin(), args.images.end()}, args.force});

  const auto start = std::chrono::steady_clock::now();
  progress.stage("read");
  std::vector<BracketFrame> frames;
  std::vector<ExifExposure> exif;
  bool all_exif = true;
  for (std::size_t i = 0; i < args.images.size(); ++i) {
    BracketFrame frame;
    frame.name = args.images[i];
    frame.image = io::readImage(args.images[i]);
    exif.push_back(io::readExif(args.images[i]));
    all_exif = all_exif && exif.back().usable();
    frames.push_back(std::move(frame));
    progress.update(double(i + 1) / double(args.images.size()), args.images[i]);
  }
  // ISO·t/N² from EXIF; when no frame states its ISO (Exiv2 cannot read some makers' notes, e.g. the Canon S3 IS)
  // but all state the time, t/N² with one ISO assumed for the whole bracket, and the warning says so.
  std::string exposure_note;
  bool all_times = true, no_iso = true;
  for (const auto& e : exif) {
    all_times = all_times && e.exposure_time && *e.exposure_time > 0;
    no_iso = no_iso && !(e.iso && *e.iso > 0);
  }
  const bool times_only = !all_exif && all_times && no_iso;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (!given.empty()) frames[i].exposure = given[i];
    else if (!args.no_exif && (all_exif || times_only))
      frames[i].exposure = (times_only ? 1.0 : *exif[i].iso) * *exif[i].exposure_time /
                           std::pow(exif[i].f_number.value_or(1.0), 2);
  }
  if (given.empty() && !args.no_exif && times_only)
    exposure_note = "no frame's EXIF states its ISO: exposures t/N² from EXIF, the same ISO assumed for all frames";
  else if (given.empty() && !args.no_exif && !all_exif)
    exposure_note = "EXIF exposure (ISO and time) missing in at least one frame: exposures estimated from the images";
  progress.done();
  const double read_seconds = secondsSince(start);

  const auto calibrate_start = std::chrono::steady_clock::now();
  std::string stage;
  BracketCalibrationResult result = calibrateBracket(frames, options, [&](const std::string& s, double f, const std::string& d) {
    if (s != stage) {
      if (!stage.empty()) progress.done();
      progress.stage(s);
      stage = s;
    }
    progress.update(f, d);
  });
  if (!stage.empty()) progress.done();
  if (!exposure_note.empty()) result.warnings.insert(result.warnings.begin(), exposure_note);

  io::CalibrationReport report = io::bracketReport(result, exif);
  report.extra["bracket"]["exposures_given"] =
      !given.empty() ? "--exposures" : args.no_exif || !(all_exif || times_only) ? "images" : times_only ? "exif time and f-number (no ISO)" : "exif";
  report.timings = {{"read", read_seconds}, {"calibrate", secondsSince(calibrate_start)}, {"total", secondsSince(start)}};
  std::size_t reference = 0;
  for (std::size_t j = 0; j < result.frames.size(); ++j)
    if (result.frames[j].reference) reference = j;
  io::writeReport(out.file("report.json"), report);
  io::writeBracketFigures(out.file("curve.png"), out.file("points.png"), result, frames[reference].image, exif[reference].camera());
  out.commit();
  if (!args.quiet) std::printf("%s", result.summary().c_str());
  for (const auto& w : report.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
  std::printf("wrote %s/{report.json, curve.png, points.png}\n", args.output.c_str());
  return kExitOk;
}

const CommandRegistration registration(
    42, "bracket",
    "Calibrate the inverse response from a static multi-exposure bracket of any scene (EMoR fit per channel, "
    "exposures from EXIF refined)",
    [](CLI::App& command) {
      auto args = std::make_shared<BracketArgs>();
      command.add_option("images", args->images, "Frames of one scene at different exposures (≥ 2; handheld is fine)")
          ->required()
          ->check(CLI::ExistingFile);
      command.add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")->required();
      command.add_flag("--force", args->force, kForceHelp);
      command.add_option("--exposures", args->exposures,
                         "Relative exposures e1,e2,… of the frames (default: EXIF ISO·t/N²; without EXIF they are "
                         "estimated from the images)");
      command.add_flag("--no-exif", args->no_exif, "Ignore EXIF: exposures estimated from the images");
      command.add_flag("--no-register", args->no_register, "Frames are already aligned (tripod): skip registration");
      command.add_option("--channels", args->channels, "Channels to calibrate (letters of RGB)");
      command.add_option("--points", args->options.sampling.points, "Scene points sampled")->check(CLI::Range(10, 100000));
      command.add_option("--terms", args->options.fit.terms, "EMoR terms K (0 = cross-validation)")->check(CLI::Range(0, 25));
      command.add_option("--max-terms", args->options.fit.max_terms, "Largest K tried by cross-validation")
          ->check(CLI::Range(1, 25));
      command.add_option("--exposure-rounds", args->options.exposure_rounds,
                         "Refinements of the inner frames' exposures (the darkest and brightest keep their ratio)")
          ->check(CLI::Range(0, 10));
      command.add_option("--band-replicates", args->options.band.replicates,
                         "Refits on halves of the scene points per channel for the 90 % band of phi (even; 0: no band)")
          ->capture_default_str()
          ->check(bandReplicates());
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runBracket(*args); };
    });

}  // namespace
}  // namespace crfcal::app
