#include "crfcal/io/output_manifest.hpp"

#include <ctime>
#include <fstream>
#include <sstream>
#include <system_error>

#include <nlohmann/json.hpp>
#include <sys/stat.h>

#include "crfcal/error.hpp"

#include "crfcal/io/atomic_output.hpp"

#ifndef CRFCAL_VERSION
#define CRFCAL_VERSION "unknown"
#endif

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {
// Last modification, nanoseconds since the Unix epoch (readable, unlike the file clock's ticks); nullopt if absent.
std::optional<std::int64_t> modifiedNs(const fs::path& path) {
  struct stat info {};
  if (::lstat(path.c_str(), &info) != 0) return std::nullopt;
  return static_cast<std::int64_t>(info.st_mtim.tv_sec) * 1000000000 + info.st_mtim.tv_nsec;
}

std::string utcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}
}  // namespace

bool OutputManifest::lists(const fs::path& relative, const fs::path& absolute) const {
  const std::string name = relative.generic_string();
  for (const auto& entry : files) {
    if (entry.path != name) continue;
    std::error_code ec;
    const auto status = fs::symlink_status(absolute, ec);
    if (ec || !fs::is_regular_file(status)) return false;
    const auto size = fs::file_size(absolute, ec);
    if (ec || size != entry.size) return false;
    return modifiedNs(absolute) == entry.modified;
  }
  return false;
}

std::optional<OutputManifest> readManifest(const fs::path& directory) {
  const fs::path path = directory / kManifestName;
  std::error_code ec;
  if (!fs::is_regular_file(fs::symlink_status(path, ec))) return std::nullopt;
  std::ifstream in(path, std::ios::binary);
  const nlohmann::json json = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (!json.is_object() || !json.contains("files") || !json["files"].is_array()) return std::nullopt;
  OutputManifest manifest;
  manifest.command = json.value("command", "");
  manifest.crfcal_version = json.value("crfcal_version", "");
  manifest.time = json.value("time", "");
  for (const auto& f : json["files"]) {
    if (!f.is_object() || !f.contains("path") || !f["path"].is_string() || !f.contains("size") ||
        !f["size"].is_number_unsigned() || !f.contains("modified") || !f["modified"].is_number_integer())
      return std::nullopt;
    const std::string name = f["path"].get<std::string>();
    const fs::path relative(name);
    // Only plain relative names below the directory: a manifest never vouches for anything outside it.
    bool inside = !name.empty() && relative.is_relative();
    for (const auto& part : relative) inside = inside && part != ".." && part != ".";
    if (!inside) return std::nullopt;
    manifest.files.push_back({name, f["size"].get<std::uintmax_t>(), f["modified"].get<std::int64_t>()});
  }
  return manifest;
}

ManifestEntry describeFile(const fs::path& directory, const fs::path& relative) {
  const fs::path absolute = directory / relative;
  ManifestEntry entry;
  entry.path = relative.generic_string();
  entry.size = fs::file_size(absolute);
  const auto modified = modifiedNs(absolute);
  if (!modified) throw Error("cannot read the file's time", absolute.string());
  entry.modified = *modified;
  return entry;
}

void writeManifest(const fs::path& directory, OutputManifest manifest) {
  nlohmann::json json;
  json["crfcal_manifest"] = 1;
  json["command"] = manifest.command;
  json["crfcal_version"] = CRFCAL_VERSION;
  json["time"] = utcNow();
  json["files"] = nlohmann::json::array();
  for (const auto& f : manifest.files)
    json["files"].push_back({{"path", f.path}, {"size", f.size}, {"modified", f.modified}});
  writeTextFile(directory / kManifestName, json.dump(1) + "\n");
}

}  // namespace crfcal::io
