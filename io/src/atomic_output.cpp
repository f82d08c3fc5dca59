#include "crfcal/io/atomic_output.hpp"

#include <fstream>
#include <system_error>

#include <unistd.h>

#include "crfcal/error.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {
fs::path sibling(const fs::path& path, const std::string& tag) {
  fs::path name = path.filename();
  if (name.empty()) name = path.parent_path().filename();
  const fs::path parent = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::string hidden(".");  // built by appending: GCC 12 warns falsely (-Wrestrict) on chained operator+
  hidden.append(name.string()).append(".").append(tag).append("-").append(std::to_string(::getpid()));
  return parent / hidden;
}
}  // namespace

void writeAtomically(const fs::path& path, const std::function<void(const fs::path&)>& write) {
  const fs::path parent = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(parent, ec)) throw Error("directory " + parent.string() + " does not exist", path.string());
  // keep the extension last: codecs choose their format from it
  const fs::path temporary = sibling(path.stem(), "partial").string() + path.extension().string();
  const fs::path temp_path = parent / temporary.filename();
  try {
    write(temp_path);
  } catch (...) {
    fs::remove(temp_path, ec);
    throw;
  }
  fs::rename(temp_path, path, ec);
  if (ec) {
    fs::remove(temp_path, ec);
    throw Error("cannot write: " + ec.message(), path.string());
  }
}

void writeTextFile(const fs::path& path, const std::string& contents) {
  writeAtomically(path, [&](const fs::path& temporary) {
    std::ofstream out(temporary, std::ios::binary);
    out << contents;
    out.close();
    if (!out) throw Error("cannot write", path.string());
  });
}

OutputDirectory::OutputDirectory(fs::path final_path) : final_(std::move(final_path)) {
  if (final_.empty()) throw Error("output directory name is empty");
  std::error_code ec;
  const fs::path parent = final_.has_parent_path() ? final_.parent_path() : fs::path(".");
  if (!fs::is_directory(parent, ec)) fs::create_directories(parent, ec);
  if (ec) throw Error("cannot create parent directory: " + ec.message(), final_.string());
  if (fs::exists(final_, ec) && !fs::is_directory(final_, ec))
    throw Error("exists and is not a directory", final_.string());
  staging_ = sibling(final_, "partial");
  fs::remove_all(staging_, ec);
  fs::create_directory(staging_, ec);
  if (ec) throw Error("cannot create output directory: " + ec.message(), final_.string());
}

OutputDirectory::~OutputDirectory() {
  if (committed_) return;
  std::error_code ec;
  fs::remove_all(staging_, ec);
}

void OutputDirectory::commit() {
  std::error_code ec;
  const fs::path old = sibling(final_, "old");
  fs::remove_all(old, ec);
  if (fs::exists(final_, ec)) {
    fs::rename(final_, old, ec);
    if (ec) throw Error("cannot replace existing directory: " + ec.message(), final_.string());
  }
  fs::rename(staging_, final_, ec);
  if (ec) {
    fs::rename(old, final_, ec);
    throw Error("cannot move results into place", final_.string());
  }
  fs::remove_all(old, ec);
  committed_ = true;
}

}  // namespace crfcal::io
