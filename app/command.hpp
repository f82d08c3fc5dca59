#pragma once
// Subcommand registry: each app/cmd_*.cpp registers itself, so adding a command touches no other file.
#include <functional>
#include <string>

#include <CLI/CLI.hpp>

namespace crfcal::app {

// setup() declares the subcommand's options on `command` and returns the function that runs it (exit code).
using CommandSetup = std::function<std::function<int()>(CLI::App& command)>;

struct CommandRegistration {
  CommandRegistration(int order, std::string name, std::string description, CommandSetup setup);
};

// Exit codes shared by all commands.
inline constexpr int kExitOk = 0;
inline constexpr int kExitError = 1;      // bad input or a failed computation (one line on stderr)
inline constexpr int kExitUsage = 2;      // command-line syntax (CLI11's own)
inline constexpr int kExitTolerance = 3;  // a --tolerance check failed (compare)
inline constexpr int kExitUnreliable = 4; // calibrate --strict: a channel's verdict is "unreliable" (outputs written)

// --force, the same in every command that writes an output directory or file (io::OutputDirectory, io/output_guard.hpp).
inline constexpr const char* kForceHelp =
    "Write into an existing output directory (or over a file) crfcal did not write: only the files crfcal writes are "
    "replaced, nothing else there is deleted, and an input of the command is never overwritten";

}  // namespace crfcal::app
