#pragma once
// `crfcal bench <kind>`: benchmark kinds register themselves like top-level commands (see command.hpp);
// app/cmd_bench.cpp owns the `bench` parent and adds every registered kind as its subcommand.
#include <string>

#include "command.hpp"

namespace crfcal::app {

struct BenchRegistration {
  BenchRegistration(int order, std::string name, std::string description, CommandSetup setup);
};

}  // namespace crfcal::app
