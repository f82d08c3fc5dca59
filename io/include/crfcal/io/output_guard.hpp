#pragma once
// What a command may write where. crfcal never deletes or overwrites a file it did not write, and never an input
// of the command, whatever the flags: an output location is checked against the command's inputs (resolved paths,
// so "./a/../photo.jpg", symbolic and hard links to an input count as the input) before any computation starts.
#include <filesystem>
#include <optional>
#include <string>
#include <system_error>
#include <vector>

#include <nlohmann/json.hpp>

namespace crfcal::io {

struct OutputPolicy {
  std::string command;                        // recorded in the manifest, e.g. "calibrate", "bench pairs"
  std::vector<std::filesystem::path> inputs;  // files or directories the command reads: never written
  bool force = false;  // --force: write crfcal's files into a directory that also holds others (never deleted)
};

// The file a command-line value may name, for OutputPolicy::inputs: "table:PATH" gives PATH, anything else itself
// (a value that names no file, like "gamma:2.2", matches no output).
std::filesystem::path specInput(const std::string& value);

// Whether `path` is one of `inputs` (same resolved path, or a hard link to it).
bool isSameAsInput(const std::filesystem::path& path, const std::vector<std::filesystem::path>& inputs);

// Whether `path` is one of `inputs` or lies inside one (an input directory): a place crfcal never writes.
bool isInput(const std::filesystem::path& path, const std::vector<std::filesystem::path>& inputs);

// The first entry (relative path, in sorted order) of `directory` that crfcal did not write: not listed in its
// manifest, changed since, or an input of this command (isSameAsInput). nullopt when everything in it is crfcal's (or it is empty).
std::optional<std::filesystem::path> firstForeignEntry(const std::filesystem::path& directory,
                                                       const std::vector<std::filesystem::path>& inputs);

// Before the computation: `file` may be written by this command. Throws crfcal::Error naming the file and the
// reason when it is an input, a directory, in a missing or unwritable directory.
void checkOutputFile(const std::filesystem::path& file, const OutputPolicy& policy);

// checkOutputFile, and an existing `file` must be a JSON object crfcal wrote (it has "crfcal_version"), unless
// policy.force.
void checkJsonOutputFile(const std::filesystem::path& file, const OutputPolicy& policy);

// Writes `json` to `file` atomically, recording "command" and "crfcal_version" in it when it is an object (so a
// later run recognises the file as crfcal's, see checkJsonOutputFile).
void writeJsonOutput(const std::filesystem::path& file, nlohmann::json json, const std::string& command,
                     int indent = 1);

// The reason of a failed file-system call, as a lower-case phrase ("permission denied").
std::string reason(const std::error_code& ec);

}  // namespace crfcal::io
