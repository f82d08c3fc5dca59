// crfcal study channels|noise|ratio|pairs: what the seed's simulation gets wrong on measured data (issue 6).
// Each study prints one table — simulation assumption → measured misfit → named cause → extended model → measured
// gain (held-out) — plus a detail table, and writes table.csv, details.csv, table.json and PNG plot(s) atomically.
#include <memory>
#include <string>

#include "command.hpp"
#include "study_common.hpp"

namespace crfcal::app {
namespace {
using study::StudyArgs;
using study::runChannels;
using study::runNoise;
using study::runRatio;
using study::runPairs;

void addCommon(CLI::App* sub, StudyArgs& args) {
  sub->add_option("--data", args.data, "Shared data directory (default $CRFCAL_SHARED_DATA or ../shared/data)");
  sub->add_option("-o,--output", args.output, "Output directory (created or replaced atomically)")->required();
  sub->add_flag("--force", args.force, kForceHelp);
  sub->add_flag("-q,--quiet", args.quiet, "No progress output");
}

const CommandRegistration registration(
    70, "study", "Studies on measured data: what the seed's simulation gets wrong (channels | noise | ratio | pairs)",
    [](CLI::App& command) {
      auto args = std::make_shared<StudyArgs>();
      auto which = std::make_shared<std::string>();
      command.require_subcommand(1);
      CLI::App* channels = command.add_subcommand(
          "channels", "Middlebury RAW->JPEG: pointwise per-channel curve vs 3x3 colour mix (+ gamut clip), held out");
      addCommon(channels, *args);
      channels->add_option("--knots", args->knots, "Segments of each monotone curve")->check(CLI::Range(2, 64));
      channels->callback([which] { *which = "channels"; });
      CLI::App* noise = command.add_subcommand(
          "noise", "Real noise vs the seed's homoscedastic model; realistic-noise benchmark of the fitter");
      addCommon(noise, *args);
      noise->add_option("--cases", args->cases, "Benchmark cases (at most 16)")->check(CLI::Range(1, 16));
      noise->callback([which] { *which = "noise"; });
      CLI::App* ratio = command.add_subcommand(
          "ratio", "EXIF vs fitted exposure ratios (brackets, phone pairs) and the effect of a wrong r on phi");
      addCommon(ratio, *args);
      ratio->add_option("--images", args->images, "Levin images in the wrong-r sweep")->check(CLI::Range(1, 4));
      ratio->callback([which] { *which = "ratio"; });
      CLI::App* pairs = command.add_subcommand(
          "pairs", "Real phone pairs (vivo X6S): each candidate cause of the misfit measured, supported or ruled out");
      addCommon(pairs, *args);
      pairs->callback([which] { *which = "pairs"; });
      return [args, which] {
        if (*which == "channels") return runChannels(*args);
        if (*which == "noise") return runNoise(*args);
        if (*which == "pairs") return runPairs(*args);
        return runRatio(*args);
      };
    });

}  // namespace
}  // namespace crfcal::app

