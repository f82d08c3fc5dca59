// crfcal — camera response function calibration from a blurred/sharp pair.
// Thin front end: parses the command line (CLI11), calls crfcal::calib / crfcal::io, prints.
#include <algorithm>
#include <cstdio>
#include <map>
#include <memory>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/core/utils/logger.hpp>

#include "command.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/interrupt_cleanup.hpp"

#ifndef CRFCAL_VERSION
#define CRFCAL_VERSION "unknown"
#endif

namespace crfcal::app {
namespace {

struct Entry {
  int order;
  std::string name;
  std::string description;
  CommandSetup setup;
};

std::vector<Entry>& registry() {
  static std::vector<Entry> entries;
  return entries;
}

}  // namespace

CommandRegistration::CommandRegistration(int order, std::string name, std::string description, CommandSetup setup) {
  registry().push_back({order, std::move(name), std::move(description), std::move(setup)});
}

}  // namespace crfcal::app

int main(int argc, char** argv) {
  using namespace crfcal::app;
  crfcal::io::installInterruptCleanup();  // first: before any thread starts (Ctrl-C leaves no partial output)
  cv::utils::logging::setLogLevel(cv::utils::logging::LOG_LEVEL_ERROR);
  CLI::App app{"crfcal " CRFCAL_VERSION
               " - measure a camera's response function (CRF) from a sharp/blurred pair and deblur with it.\n"
               "Method: Chen, Li, Yang, Yu, \"A Theoretical Analysis of Camera Response Functions in Image "
               "Deblurring\", ECCV 2012.",
               "crfcal"};
  app.set_version_flag("--version", std::string("crfcal ") + CRFCAL_VERSION);
  app.require_subcommand(1);
  app.get_formatter()->column_width(40);
  app.option_defaults()->always_capture_default();
  // One line per error, like every other crfcal error.
  app.failure_message([](const CLI::App*, const CLI::Error& e) {
    return std::string("crfcal: error: ") + e.what() + " (see --help)\n";
  });

  auto entries = registry();
  std::sort(entries.begin(), entries.end(), [](const auto& a, const auto& b) { return a.order < b.order; });
  std::map<CLI::App*, std::function<int()>> runners;
  for (const auto& entry : entries) {
    CLI::App* command = app.add_subcommand(entry.name, entry.description);
    command->option_defaults()->always_capture_default();
    runners[command] = entry.setup(*command);
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // --help and --version exit 0; every command-line error exits 2 (README), whatever CLI11's own code for it.
    const int code = app.exit(e);
    return code == 0 ? kExitOk : kExitUsage;
  }
  try {
    for (auto& [command, run] : runners)
      if (command->parsed()) return run();
  } catch (const crfcal::Error& e) {
    std::fprintf(stderr, "crfcal: error: %s\n", e.what());
    return kExitError;
  } catch (const cv::Exception& e) {
    std::fprintf(stderr, "crfcal: error: OpenCV: %s\n", e.err.c_str());
    return kExitError;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "crfcal: error: %s\n", e.what());
    return kExitError;
  }
  return kExitError;
}
