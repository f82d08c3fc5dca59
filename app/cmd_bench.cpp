// crfcal bench: the benchmark group. Every `crfcal bench NAME` registers itself with BenchRegistration
// (bench_command.hpp) from its own cmd_bench_*.cpp; this command adds them as subcommands in their order.
#include <algorithm>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "bench_command.hpp"
#include "command.hpp"

namespace crfcal::app {
namespace {

struct BenchEntry {
  int order;
  std::string name;
  std::string description;
  CommandSetup setup;
};
std::vector<BenchEntry>& benchRegistry() {
  static std::vector<BenchEntry> entries;
  return entries;
}

}  // namespace

BenchRegistration::BenchRegistration(int order, std::string name, std::string description, CommandSetup setup) {
  benchRegistry().push_back({order, std::move(name), std::move(description), std::move(setup)});
}

namespace {

const CommandRegistration bench_registration(
    60, "bench", "Benchmarks (subcommands: synthetic, ...)", [](CLI::App& command) {
      command.require_subcommand(1);
      auto entries = benchRegistry();
      std::sort(entries.begin(), entries.end(), [](const auto& a, const auto& b) { return a.order < b.order; });
      auto runners = std::make_shared<std::vector<std::pair<CLI::App*, std::function<int()>>>>();
      for (const auto& entry : entries) {
        CLI::App* sub = command.add_subcommand(entry.name, entry.description);
        sub->option_defaults()->always_capture_default();
        runners->emplace_back(sub, entry.setup(*sub));
      }
      return [runners]() -> int {
        for (auto& [sub, run] : *runners)
          if (sub->parsed()) return run();
        return kExitUsage;
      };
    });

}  // namespace
}  // namespace crfcal::app
