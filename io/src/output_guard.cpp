#include "crfcal/io/output_guard.hpp"

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <fstream>
#include <iterator>

#include <fcntl.h>
#include <unistd.h>

#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/output_manifest.hpp"

#ifndef CRFCAL_VERSION
#define CRFCAL_VERSION "unknown"
#endif

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {

fs::path resolved(const fs::path& path) {
  std::error_code ec;
  fs::path result = fs::weakly_canonical(fs::absolute(path), ec);
  return ec ? fs::absolute(path).lexically_normal() : result;
}

bool within(const fs::path& path, const fs::path& ancestor) {
  auto p = path.begin();
  for (auto a = ancestor.begin(); a != ancestor.end(); ++a, ++p) {
    if (a->empty() && std::next(a) == ancestor.end()) break;  // trailing separator
    if (p == path.end() || *p != *a) return false;
  }
  return true;
}

}  // namespace

std::string reason(const std::error_code& ec) {
  std::string text = ec.message();
  if (!text.empty()) text[0] = static_cast<char>(std::tolower(static_cast<unsigned char>(text[0])));
  return text;
}

fs::path specInput(const std::string& value) {
  return value.rfind("table:", 0) == 0 ? fs::path(value.substr(6)) : fs::path(value);
}

bool isSameAsInput(const fs::path& path, const std::vector<fs::path>& inputs) {
  const fs::path target = resolved(path);
  std::error_code ec;
  for (const auto& input : inputs) {
    if (input.empty()) continue;
    if (target == resolved(input)) return true;
    if (fs::exists(path, ec) && fs::exists(input, ec) && fs::equivalent(path, input, ec)) return true;  // hard link
  }
  return false;
}

bool isInput(const fs::path& path, const std::vector<fs::path>& inputs) {
  if (isSameAsInput(path, inputs)) return true;
  const fs::path target = resolved(path);
  for (const auto& input : inputs)
    if (!input.empty() && within(target, resolved(input))) return true;
  return false;
}

std::optional<fs::path> firstForeignEntry(const fs::path& directory, const std::vector<fs::path>& inputs) {
  const std::optional<OutputManifest> manifest = readManifest(directory);
  std::vector<fs::path> foreign;
  std::error_code ec;
  fs::recursive_directory_iterator it(directory, ec), end;
  if (ec) throw Error("cannot read directory: " + reason(ec), directory.string());
  for (; it != end; it.increment(ec)) {
    if (ec) throw Error("cannot read directory: " + reason(ec), directory.string());
    const fs::path relative = it->path().lexically_relative(directory);
    if (it.depth() == 0 && relative.string().rfind(".crfcal.partial-", 0) == 0) {
      it.disable_recursion_pending();  // another crfcal run's staging directory (--force): crfcal's own
      continue;
    }
    const fs::file_status status = it->symlink_status(ec);
    if (fs::is_directory(status)) {
      if (isSameAsInput(it->path(), inputs)) foreign.push_back(relative);
      continue;  // judged by what it holds (an empty directory holds nothing to lose)
    }
    const bool own_manifest = manifest && relative == fs::path(kManifestName);
    const bool listed = manifest && manifest->lists(relative, it->path());
    if ((!own_manifest && !listed) || isSameAsInput(it->path(), inputs)) foreign.push_back(relative);
  }
  if (foreign.empty()) return std::nullopt;
  return *std::min_element(foreign.begin(), foreign.end());
}

void checkOutputFile(const fs::path& file, const OutputPolicy& policy) {
  if (file.empty()) throw Error("output file name is empty");
  if (isInput(file, policy.inputs))
    throw Error("is an input of this command: refusing to overwrite it", file.string());
  std::error_code ec;
  if (fs::is_directory(file, ec)) throw Error("cannot write: is a directory", file.string());
  const fs::path parent = file.has_parent_path() ? file.parent_path() : fs::path(".");
  const fs::file_status status = fs::status(parent, ec);
  if (!fs::exists(status)) throw Error("cannot write: no such directory " + parent.string(), file.string());
  if (!fs::is_directory(status)) throw Error("cannot write: " + parent.string() + " is not a directory", file.string());
  // Probe: create (and remove) a file beside it, as the atomic write will.
  const fs::path probe = parent / (".crfcal-probe-" + std::to_string(::getpid()));
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL, 0600);
  if (fd < 0) throw Error("cannot write: " + reason(std::error_code(errno, std::generic_category())), file.string());
  ::close(fd);
  fs::remove(probe, ec);
}

void checkJsonOutputFile(const fs::path& file, const OutputPolicy& policy) {
  checkOutputFile(file, policy);
  std::error_code ec;
  if (policy.force || !fs::exists(fs::symlink_status(file, ec))) return;
  std::ifstream in(file, std::ios::binary);
  const nlohmann::json json = nlohmann::json::parse(in, nullptr, /*allow_exceptions=*/false);
  if (!json.is_object() || !json.contains("crfcal_version"))
    throw Error("exists and was not written by crfcal: refusing to overwrite it (--force overwrites it)",
                file.string());
}

void writeJsonOutput(const fs::path& file, nlohmann::json json, const std::string& command, int indent) {
  if (json.is_object()) {
    json["command"] = command;
    json["crfcal_version"] = CRFCAL_VERSION;
  }
  writeTextFile(file, json.dump(indent) + "\n");
}

}  // namespace crfcal::io
