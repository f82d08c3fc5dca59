// crfcal compare: two reports (or a report and simulate's truth.json) side by side — φ RMSE and max error per
// channel over [0,1] and over the range covered by data, the exposure ratios, an overlaid plot.
// Exit status 3 (kExitTolerance) when --tolerance is given and a channel's RMSE exceeds it.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>

#include <nlohmann/json.hpp>

#include "command.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/band_report.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/io/report.hpp"

namespace crfcal::app {
namespace {

struct CompareArgs {
  std::string a, b;
  std::string output;
  bool force = false;  // write into an output directory holding other files (never deletes them)
  std::optional<double> tolerance;
  std::string tolerance_range = "full";
  int samples = 1024;
  bool quiet = false;
};

std::string ratioText(const std::optional<double>& r) {
  if (!r) return "-";
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.6g", *r);
  return buffer;
}

std::string sourceText(const io::CalibrationReport& report) {
  return report.nominal_ratio_source.empty() ? "-" : report.nominal_ratio_source;
}

nlohmann::json ratioJson(const std::optional<double>& r) { return r ? nlohmann::json(*r) : nlohmann::json(nullptr); }

// One report's exposure ratios for compare.json (the names of report.json's "exposure_ratio").
nlohmann::json ratiosJson(const io::CalibrationReport& report) {
  return {{"nominal", ratioJson(report.nominal_ratio)},
          {"nominal_source", report.nominal_ratio_source.empty() ? nlohmann::json(nullptr)
                                                                 : nlohmann::json(report.nominal_ratio_source)},
          {"fitted", ratioJson(report.fitted_ratio)}};
}

cv::Scalar channelColor(const std::string& channel, int index) {
  if (channel == "R") return {40, 39, 214};
  if (channel == "G") return {44, 160, 44};
  if (channel == "B") return {180, 119, 31};
  return io::seriesColor(index);
}

std::vector<double> grid(size_t n) {
  std::vector<double> x(n);
  for (size_t i = 0; i < n; ++i) x[i] = double(i) / double(n - 1);
  return x;
}

CurveComparison::Range toleranceRange(const std::string& name) {
  return name == "covered"   ? CurveComparison::Range::Covered
         : name == "aligned" ? CurveComparison::Range::CoveredAligned
                             : CurveComparison::Range::Full;
}

// Per compared channel, the agreement judged by the reports' bands (curve_band.hpp), when either report has one and
// both curves share its grid; absent otherwise.
using Agreements = std::map<std::string, BandAgreement>;

Agreements bandAgreements(const CompareArgs& args, const io::CalibrationReport& a, const io::CalibrationReport& b,
                          const CurveComparison& comparison) {
  const auto bands_a = io::readCurveBands(a, args.a), bands_b = io::readCurveBands(b, args.b);
  Agreements agreements;
  for (const auto& c : comparison.channels) {
    const auto ia = bands_a.find(c.channel_a), ib = bands_b.find(c.channel_b);
    const CurveBand* band_a = ia == bands_a.end() ? nullptr : &ia->second;
    const CurveBand* band_b = ib == bands_b.end() ? nullptr : &ib->second;
    const auto& phi_a = a.inverse_crf.at(c.channel_a);
    const auto& phi_b = b.inverse_crf.at(c.channel_b);
    if ((!band_a && !band_b) || phi_a.size() != phi_b.size()) continue;
    agreements[c.channel] = bandAgreement(phi_a, band_a, phi_b, band_b, c.covered, c.scale_covered);
  }
  return agreements;
}

void printBandAgreements(const Agreements& agreements) {
  if (agreements.empty()) return;
  std::printf("agreement by the bands over the covered range (A vs a*B; shape bands combined; about the band's level "
              "when the curves differ only by sampling error; mean z^2 about 1):\n");
  for (const auto& [channel, g] : agreements)
    std::printf("  %-2s within the combined %.0f %% band %5.1f %% of %d samples, mean z^2 %.3g, absolute bands "
                "overlap %5.1f %%\n",
                channel.c_str(), 100 * g.level, 100 * g.fraction_within, g.samples, g.mean_z2,
                100 * g.fraction_absolute_overlap);
}

// The console table: per-channel errors, then both reports' exposure ratios.
void printComparison(const CompareArgs& args, const io::CalibrationReport& a, const io::CalibrationReport& b,
                     const CurveComparison& comparison) {
  std::printf("A: %s\nB: %s\n\n%s\n", args.a.c_str(), args.b.c_str(), comparison.summary().c_str());
  std::printf("exposure ratio  %-12s %-12s\n", "A", "B");
  std::printf("  nominal       %-12s %-12s  (source: %s / %s)\n", ratioText(a.nominal_ratio).c_str(),
              ratioText(b.nominal_ratio).c_str(), sourceText(a).c_str(), sourceText(b).c_str());
  std::printf("  fitted        %-12s %-12s", ratioText(a.fitted_ratio).c_str(), ratioText(b.fitted_ratio).c_str());
  if (a.fitted_ratio && b.fitted_ratio && *b.fitted_ratio != 0)
    std::printf("  (A/B - 1 = %+.3e)", *a.fitted_ratio / *b.fitted_ratio - 1);
  std::printf("\n");
}

// The overlaid curves of compare.png, built once per side and channel.
struct CompareSeries {
  const CurveComparison& comparison;
  std::vector<io::PlotSeries> series;
  std::vector<std::string> drawn;  // "A:G", "B:G", … — a grey side's single curve is drawn once, in black

  void add(const io::CalibrationReport& report, const char* side, const std::string& channel, const cv::Scalar& color,
           bool dashed) {
    const std::string key = std::string(side) + ":" + channel;
    if (std::find(drawn.begin(), drawn.end(), key) != drawn.end()) return;
    drawn.push_back(key);
    const bool grey = report.inverse_crf.size() == 1 && comparison.channels.size() > 1;
    const auto& curve = report.inverse_crf.at(channel);
    series.push_back({grid(curve.size()), curve, grey ? cv::Scalar(40, 40, 40) : color,
                      std::string(side) + " " + channel, 2, false, dashed});
  }
};

void writeComparePlot(io::OutputDirectory& out, const io::CalibrationReport& a, const io::CalibrationReport& b,
                      const CurveComparison& comparison) {
  CompareSeries plotted{comparison, {}, {}};
  int index = 0;
  for (const auto& c : comparison.channels) {
    plotted.add(a, "A", c.channel_a, channelColor(c.channel, index), false);
    plotted.add(b, "B", c.channel_b, channelColor(c.channel, index), true);
    ++index;
  }
  // The covered range (where it is narrower than [0,1]): grey dashed verticals.
  std::vector<double> edges;
  for (const auto& c : comparison.channels)
    for (double e : {c.covered.first, c.covered.second})
      if (e > 0 && e < 1 && std::find(edges.begin(), edges.end(), e) == edges.end()) edges.push_back(e);
  for (double e : edges)
    plotted.series.push_back({{e, e}, {0.0, 1.0}, cv::Scalar(150, 150, 150), "", 1, false, true});
  io::PlotOptions plot;
  plot.title = "inverse CRF phi: A (solid) vs B (dashed)";
  plot.x_label = "intensity x";
  plot.y_label = "phi(x)";
  plot.x_min = 0;
  plot.x_max = 1;
  plot.y_min = 0;
  plot.y_max = 1;
  io::writePlot(out.file("compare.png"), plotted.series, plot);
}

nlohmann::json compareJson(const CompareArgs& args, const io::CalibrationReport& a, const io::CalibrationReport& b,
                           const CurveComparison& comparison, const Agreements& agreements, bool pass) {
  nlohmann::json json;
  json["a"] = args.a;
  json["b"] = args.b;
  json["samples"] = args.samples;
  json["channels"] = nlohmann::json::array();
  for (const auto& c : comparison.channels)
    json["channels"].push_back({{"channel", c.channel},
                                {"channel_a", c.channel_a},
                                {"channel_b", c.channel_b},
                                {"rmse", c.rmse},
                                {"max_error", c.max_error},
                                {"argmax", c.argmax},
                                {"covered_range", {c.covered.first, c.covered.second}},
                                {"covered_source", c.covered_source},
                                {"rmse_covered", c.rmse_covered},
                                {"max_error_covered", c.max_error_covered},
                                {"scale_covered", c.scale_covered},
                                {"rmse_covered_aligned", c.rmse_covered_aligned}});
  for (auto& entry : json["channels"]) {
    const auto g = agreements.find(entry["channel"].get<std::string>());
    if (g == agreements.end()) continue;
    entry["band_agreement"] = {{"samples", g->second.samples},
                               {"level", g->second.level},
                               {"fraction_within", g->second.fraction_within},
                               {"mean_z2", g->second.mean_z2},
                               {"fraction_absolute_overlap", g->second.fraction_absolute_overlap}};
  }
  json["worst_rmse"] = comparison.worst_rmse;
  json["worst_rmse_covered"] = comparison.worst_rmse_covered;
  json["worst_rmse_covered_aligned"] = comparison.worst_rmse_covered_aligned;
  json["exposure_ratio"] = {{"a", ratiosJson(a)}, {"b", ratiosJson(b)}};
  if (args.tolerance) {
    json["tolerance"] = *args.tolerance;
    json["tolerance_range"] = args.tolerance_range;
    json["within_tolerance"] = pass;
  }
  return json;
}

int runCompare(const CompareArgs& args) {
  // Decided first: a refused or unwritable output directory fails at once.
  std::optional<io::OutputDirectory> staged;
  if (!args.output.empty()) staged.emplace(args.output, io::OutputPolicy{"compare", {args.a, args.b}, args.force});
  const io::CalibrationReport a = io::readReport(args.a);
  const io::CalibrationReport b = io::readReport(args.b);
  CurveComparisonOptions options;
  options.samples = args.samples;
  const CurveComparison comparison = compareChannels(a.inverse_crf, b.inverse_crf, a.covered_range, b.covered_range, options);
  const Agreements agreements = bandAgreements(args, a, b, comparison);

  const CurveComparison::Range range = toleranceRange(args.tolerance_range);
  const bool pass = !args.tolerance || comparison.withinTolerance(*args.tolerance, range);

  if (!args.quiet) {
    printComparison(args, a, b, comparison);
    printBandAgreements(agreements);
  }

  if (!args.output.empty()) {
    io::OutputDirectory& out = *staged;
    writeComparePlot(out, a, b, comparison);
    io::writeTextFile(out.file("compare.json"), compareJson(args, a, b, comparison, agreements, pass).dump(2) + "\n");
    out.commit();
    if (!args.quiet) std::printf("wrote %s/{compare.png, compare.json}\n", args.output.c_str());
  }

  if (args.tolerance) {
    std::printf("tolerance %.3e on RMSE over %s: %s\n", *args.tolerance,
                range == CurveComparison::Range::Full      ? "[0,1]"
                : range == CurveComparison::Range::Covered ? "the covered range"
                                                           : "the covered range, scale-aligned",
                pass ? "PASS" : "FAIL");
    return pass ? kExitOk : kExitTolerance;
  }
  return kExitOk;
}

const CommandRegistration registration(
    55, "compare", "Compare two reports' curves: RMSE/max error per channel, exposure ratios, overlaid plot",
    [](CLI::App& command) {
      auto args = std::make_shared<CompareArgs>();
      command.add_option("a", args->a, "First report.json (or truth.json)")->required();
      command.add_option("b", args->b, "Second report.json (or truth.json)")->required();
      command.add_option("-o,--output", args->output, "Directory for compare.png and compare.json (atomic)");
      command.add_flag("--force", args->force, kForceHelp);
      command.add_option("--tolerance", args->tolerance,
                         "Exit with status 3 if any channel's phi RMSE exceeds this")
          ->check(CLI::NonNegativeNumber);
      command.add_option("--tolerance-range", args->tolerance_range,
                         "RMSE the tolerance applies to: full ([0,1]), covered (range supported by data) or "
                         "aligned (covered range after the best factor a: A vs a*B, free of the phi(1)=1 "
                         "normalisation)")
          ->check(CLI::IsMember({"full", "covered", "aligned"}));
      command.add_option("--samples", args->samples, "Comparison grid points on [0,1]")->check(CLI::Range(2, 1 << 20));
      command.add_flag("-q,--quiet", args->quiet, "Print only the tolerance verdict");
      return [args] { return runCompare(*args); };
    });

}  // namespace
}  // namespace crfcal::app
