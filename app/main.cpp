// crfcal — camera response function calibration from a blurred/sharp pair.
// Thin front end: parses the command line (CLI11), calls crfcal::calib / crfcal::io, prints.
#include <algorithm>
#include <cstdio>
#include <map>
#include <memory>
#include <vector>

#if defined(__GLIBC__)
#include <malloc.h>
#endif

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

namespace {

// glibc's allocator returns every freed block above its mmap threshold (dynamic, from 128 KiB) to the kernel and trims
// the heap top above 128 KiB, so each stage's images, moment tables and Eigen temporaries come back as fresh
// zero-filled pages: a 0.1 MP phone pair took 226,000 page faults, 12 % of its CPU time in the kernel's fault handler.
// Blocks up to 32 MiB now come from the heap and freed memory stays for the next stage. Measured on vivo pair 2
// (docs/RESULTS.md#speed-small): 8.7 → 6.5 CPU s, 226,000 → 81,000 faults, peak RSS unchanged (350 MB); results
// identical. Setting only the trim threshold is worse (it freezes the dynamic mmap threshold at 128 KiB).
void configureAllocator() {
#if defined(__GLIBC__)
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
#endif
}

}  // namespace
}  // namespace crfcal::app

int main(int argc, char** argv) {
  using namespace crfcal::app;
  configureAllocator();  // before the first allocation of any size that matters
  crfcal::io::installInterruptCleanup();  // before any thread starts (Ctrl-C leaves no partial output)
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
