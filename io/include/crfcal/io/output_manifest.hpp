#pragma once
// crfcal-manifest.json: the list of files crfcal wrote into an output directory. It is how crfcal recognises its
// own previous output (which it may replace as a whole) and tells it apart from anything else (which it never
// deletes). A listed file whose size or modification time changed since is no longer crfcal's.
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace crfcal::io {

inline constexpr const char* kManifestName = "crfcal-manifest.json";

struct ManifestEntry {
  std::string path;             // relative to the directory, '/'-separated
  std::uintmax_t size = 0;      // bytes
  std::int64_t modified = 0;    // last modification, nanoseconds since the Unix epoch
};

struct OutputManifest {
  std::string command;          // e.g. "calibrate", "bench pairs" (the last command that wrote here)
  std::string crfcal_version;
  std::string time;             // UTC, ISO 8601
  std::vector<ManifestEntry> files;

  // Whether `relative` is listed and the file on disk (`absolute`) still has the listed size and time.
  bool lists(const std::filesystem::path& relative, const std::filesystem::path& absolute) const;
};

// The manifest of `directory`; nullopt when it has none or it is not a readable crfcal manifest.
std::optional<OutputManifest> readManifest(const std::filesystem::path& directory);

// Entry for a file as it is now on disk.
ManifestEntry describeFile(const std::filesystem::path& directory, const std::filesystem::path& relative);

// Writes `manifest` into `directory` atomically, stamping version and time.
void writeManifest(const std::filesystem::path& directory, OutputManifest manifest);

}  // namespace crfcal::io
