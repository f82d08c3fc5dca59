// crfcal export: a report's response curve as a lookup table for other tools (OpenCV, OCIO, Resolve, pfstools,
// Hugin, spreadsheets). Formats and their readers: crfcal/io/lut_export.hpp, docs/RESULTS.md#lut-export.
#include <cstdio>
#include <memory>

#include "command.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/band_report.hpp"
#include "crfcal/io/lut_export.hpp"
#include "crfcal/io/output_guard.hpp"
#include "crfcal/io/report.hpp"

namespace crfcal::app {
namespace {

struct ExportArgs {
  std::string report;
  std::string output;
  std::string format;
  std::string direction;  // empty: the format's natural direction (hugin: forward, else inverse)
  std::vector<double> range;
  int size = 0;
  std::string channel;
  std::string title;
  std::string band;  // empty: the curve; lower / upper: that limit of the report's band (inverse_crf_band)
};

// The report with every channel's curve replaced by its band's `limit` ("lower" or "upper"). Throws naming the
// report when it has no band for a channel (reports of chart, simulate or crfcal before the band).
io::CalibrationReport withBandLimit(io::CalibrationReport report, const std::string& limit, const std::string& path) {
  const auto bands = io::readCurveBands(report, path);
  for (auto& [name, curve] : report.inverse_crf) {
    const auto band = bands.find(name);
    if (band == bands.end())
      throw Error("no band for channel " + name + " (inverse_crf_band; written by calibrate)", ErrorSubject::curve, path);
    curve = limit == "lower" ? band->second.lower : band->second.upper;
    report.models.erase(name);  // the parametric model is the curve's, not the limit's
  }
  return report;
}

int runExport(const ExportArgs& args) {
  io::checkOutputFile(args.output, {"export", {args.report}});  // never the report itself; writable
  io::LutExportOptions options;
  if (!args.format.empty()) {
    options.format = io::parseLutFormat(args.format);
  } else if (const auto guess = io::lutFormatFromExtension(args.output)) {
    options.format = *guess;
  } else {
    throw InvalidInput("cannot tell the format from '" + args.output + "': give --format");
  }
  if (args.direction.empty())
    options.direction = options.format == io::LutFormat::Hugin ? io::LutDirection::Forward : io::LutDirection::Inverse;
  else
    options.direction = args.direction == "forward" ? io::LutDirection::Forward : io::LutDirection::Inverse;
  if (!args.range.empty()) {
    options.range_min = args.range.at(0);
    options.range_max = args.range.at(1);
  }
  options.size = args.size;
  options.channel = args.channel;
  if (!args.title.empty()) options.title = args.title;
  else if (options.direction == io::LutDirection::Forward) options.title = "crfcal camera response";
  options.check();

  io::CalibrationReport report = io::readReport(args.report);
  if (!args.band.empty()) report = withBandLimit(std::move(report), args.band, args.report);
  const io::LutExportResult result = io::exportLut(report, args.output, options);
  std::printf("%s\n", result.summary().c_str());
  return kExitOk;
}

const CommandRegistration registration(
    50, "export", "Write a report's response curve as a LUT for other tools (csv, opencv, cube, spi1d, clf, pfstools, hugin)",
    [](CLI::App& command) {
      auto args = std::make_shared<ExportArgs>();
      command.add_option("report", args->report, "report.json (calibrate/chart) or simulate's truth.json")
          ->required();
      command.add_option("-o,--output", args->output, "Output file (written atomically)")->required();
      command.add_option("-f,--format", args->format,
                         "csv | opencv (cv::FileStorage, MergeDebevec response) | cube | spi1d | clf | pfstools | "
                         "hugin (EMoR Ra..Re); default: from the output's extension");
      command.add_option("--direction", args->direction,
                         "inverse: phi, intensity -> irradiance (default); forward: psi, irradiance -> intensity "
                         "(default for hugin)")
          ->check(CLI::IsMember({"inverse", "forward"}));
      command.add_option("--size", args->size,
                         "LUT nodes; 0 = the format's default: 4096 for cube/spi1d/clf, 256 for opencv (the only "
                         "size MergeDebevec takes) and pfstools (2^bpp), 1024 for csv")
          ->check(CLI::Range(0, 1 << 24));
      command.add_option("--range", args->range,
                         "Input domain LO,HI within [0,1] (csv, cube, spi1d, clf; default 0,1; readers clamp "
                         "inputs outside it)")
          ->expected(2)
          ->delimiter(',');
      command.add_option("--channel", args->channel,
                         "Write this channel into R, G and B (default: each channel its own curve; pfstools: one "
                         "luminance 'IY' curve; hugin: one curve, default G)")
          ->check(CLI::IsMember({"R", "G", "B"}));
      command.add_option("--title", args->title,
                         "Title written into cube/clf files (default: 'crfcal inverse camera response', with "
                         "--direction forward 'crfcal camera response')");
      command.add_option("--band", args->band,
                         "Write a limit of the report's pointwise band of phi instead of the curve: lower or upper "
                         "(inverse_crf_band of calibrate's report.json; the band's level is in the report)")
          ->check(CLI::IsMember({"lower", "upper"}));
      return [args] { return runExport(*args); };
    });

}  // namespace
}  // namespace crfcal::app
