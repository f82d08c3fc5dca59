#include "crfcal/io/atomic_output.hpp"

#include <algorithm>
#include <cerrno>
#include <fstream>
#include <system_error>
#include <vector>

#include <unistd.h>

#include "crfcal/error.hpp"
#include "crfcal/io/interrupt_cleanup.hpp"
#include "crfcal/io/output_manifest.hpp"

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

std::error_code lastError() { return std::error_code(errno ? errno : EIO, std::generic_category()); }

// Regular files below `directory`, relative to it, sorted.
std::vector<fs::path> filesBelow(const fs::path& directory) {
  std::vector<fs::path> files;
  for (const auto& entry : fs::recursive_directory_iterator(directory))
    if (!entry.is_directory()) files.push_back(entry.path().lexically_relative(directory));
  std::sort(files.begin(), files.end());
  return files;
}

std::string refusal(const fs::path& foreign) {
  return "holds files crfcal did not write (first: " + foreign.string() +
         "); refusing to replace it: choose another directory, or give --force to write crfcal's files into it "
         "(nothing else there is deleted)";
}
}  // namespace

void writeAtomically(const fs::path& path, const std::function<void(const fs::path&)>& write) {
  if (path.empty()) throw Error("output file name is empty");
  const fs::path parent = path.has_parent_path() ? path.parent_path() : fs::path(".");
  std::error_code ec;
  const fs::file_status parent_status = fs::status(parent, ec);
  if (!fs::exists(parent_status)) throw Error("cannot write: no such directory " + parent.string(), path.string());
  if (!fs::is_directory(parent_status))
    throw Error("cannot write: " + parent.string() + " is not a directory", path.string());
  if (fs::is_directory(path, ec)) throw Error("cannot write: is a directory", path.string());
  // keep the extension last: codecs choose their format from it
  const fs::path temporary = sibling(path.stem(), "partial").string() + path.extension().string();
  const fs::path temp_path = parent / temporary.filename();
  RemovedOnInterrupt cleanup(fs::absolute(temp_path, ec));
  try {
    write(temp_path);
  } catch (...) {
    fs::remove(temp_path, ec);
    throw;
  }
  if (!fs::exists(temp_path, ec)) throw Error("cannot write: the file was not created", path.string());
  fs::rename(temp_path, path, ec);
  if (ec) {
    const std::string why = reason(ec);
    fs::remove(temp_path, ec);
    throw Error("cannot write: " + why, path.string());
  }
}

void writeTextFile(const fs::path& path, const std::string& contents) {
  writeAtomically(path, [&](const fs::path& temporary) {
    errno = 0;
    std::ofstream out(temporary, std::ios::binary);
    if (!out.is_open()) throw Error("cannot write: " + reason(lastError()), path.string());
    out << contents;
    out.flush();
    if (!out) throw Error("cannot write: " + reason(lastError()), path.string());  // e.g. no space left on device
    out.close();
    if (!out) throw Error("cannot write: " + reason(lastError()), path.string());
  });
}

OutputDirectory::OutputDirectory(fs::path final_path, OutputPolicy policy)
    : final_(std::move(final_path)), policy_(std::move(policy)) {
  if (final_.empty()) throw Error("output directory name is empty");
  // "DIR/", "." and ".." name the directory itself: its sibling staging directory needs its real name.
  const auto stripped = [](fs::path p) {
    p = p.lexically_normal();
    return p.filename().empty() && p.has_parent_path() && p != p.root_path() ? p.parent_path() : p;
  };
  final_ = stripped(final_);
  if (final_.filename() == "." || final_.filename() == "..") final_ = stripped(fs::absolute(final_));
  std::error_code ec;
  if (fs::is_symlink(fs::symlink_status(final_, ec))) {
    final_ = fs::canonical(final_, ec);  // write where the link points, keep the link
    if (ec) throw Error("cannot resolve the link: " + reason(ec), final_.string());
  }
  const fs::path parent = final_.has_parent_path() ? final_.parent_path() : fs::path(".");
  if (fs::exists(parent, ec) && !fs::is_directory(parent, ec))
    throw Error("cannot write: " + parent.string() + " is not a directory", final_.string());
  // Missing parents are created now and removed again (if still empty) when nothing is committed.
  for (fs::path p = parent; !p.empty() && !fs::exists(fs::symlink_status(p, ec)); p = p.parent_path()) {
    created_parents_.push_back(p);
    if (!p.has_relative_path() || p == p.parent_path()) break;
  }
  fs::create_directories(parent, ec);
  if (ec) {
    removeCreatedParents();
    throw Error("cannot create parent directory: " + reason(ec), final_.string());
  }
  const fs::file_status status = fs::status(final_, ec);
  if (fs::exists(status) && !fs::is_directory(status)) throw Error("exists and is not a directory", final_.string());
  if (fs::exists(status) && isSameAsInput(final_, policy_.inputs))
    throw Error("is an input of this command: refusing to write into it", final_.string());
  if (fs::exists(status)) {
    if (const auto foreign = firstForeignEntry(final_, policy_.inputs)) {
      if (!policy_.force) throw Error(refusal(*foreign), final_.string());
      merge_ = true;
    }
  }
  // Staged beside DIR when DIR is replaced as a whole, inside it otherwise: either way on DIR's file system (so the
  // final moves are renames) and created now, so an unwritable location fails before the computation.
  staging_ = merge_ ? final_ / (".crfcal.partial-" + std::to_string(::getpid())) : sibling(final_, "partial");
  const auto defer = deferInterrupts();
  staging_cleanup_ = std::make_unique<RemovedOnInterrupt>(fs::absolute(staging_, ec));
  fs::remove_all(staging_, ec);  // left by a killed run with the same process id: ours by its name
  fs::create_directory(staging_, ec);
  if (ec) removeCreatedParents();
  if (ec)
    throw Error("cannot write into " + (merge_ ? final_ : parent).string() + ": " + reason(ec), final_.string());
}

OutputDirectory::~OutputDirectory() {
  if (committed_) return;
  const auto defer = deferInterrupts();
  std::error_code ec;
  fs::remove_all(staging_, ec);
  removeCreatedParents();
}

void OutputDirectory::removeCreatedParents() {
  std::error_code ec;
  for (const auto& p : created_parents_) fs::remove(p, ec);  // only if still empty
}

void OutputDirectory::commit() {
  const auto defer = deferInterrupts();  // an interrupt now waits until DIR is complete
  std::error_code ec;
  if (!merge_ && fs::exists(final_, ec)) {
    // Checked again: something may have been put into DIR during the computation.
    if (const auto foreign = firstForeignEntry(final_, policy_.inputs)) {
      if (!policy_.force) throw Error(refusal(*foreign), final_.string());
      merge_ = true;
    }
  }
  if (merge_) mergeInto();
  else replaceWhole();
  committed_ = true;
  staging_cleanup_.reset();
}

void OutputDirectory::replaceWhole() {
  OutputManifest manifest;
  manifest.command = policy_.command;
  for (const auto& relative : filesBelow(staging_)) manifest.files.push_back(describeFile(staging_, relative));
  writeManifest(staging_, manifest);

  std::error_code ec;
  const fs::path old = sibling(final_, "old");
  fs::remove_all(old, ec);
  const bool existed = fs::exists(final_, ec);
  if (existed) {
    fs::rename(final_, old, ec);
    if (ec) throw Error("cannot replace the previous output: " + reason(ec), final_.string());
  }
  fs::rename(staging_, final_, ec);
  if (ec) {
    const std::string why = reason(ec);
    if (existed) fs::rename(old, final_, ec);
    throw Error("cannot move the results into place: " + why, final_.string());
  }
  // `old` held only files listed in its manifest (checked in commit()): crfcal's previous output.
  fs::remove_all(old, ec);
}

void OutputDirectory::mergeInto() {
  const std::vector<fs::path> files = filesBelow(staging_);
  std::error_code ec;
  // Everything is checked before anything moves: an input is never replaced, whatever the flags.
  for (const auto& relative : files) {
    const fs::path destination = final_ / relative;
    if (isInput(destination, policy_.inputs))
      throw Error("is an input of this command: refusing to overwrite it (nothing was written)", destination.string());
    if (fs::is_directory(fs::symlink_status(destination, ec)))
      throw Error("cannot write: is a directory (nothing was written)", destination.string());
  }
  if (isInput(final_ / kManifestName, policy_.inputs))
    throw Error("is an input of this command: refusing to overwrite it (nothing was written)",
                (final_ / kManifestName).string());

  const std::optional<OutputManifest> previous = readManifest(final_);
  for (const auto& relative : files) {
    const fs::path destination = final_ / relative;
    fs::create_directories(destination.parent_path(), ec);
    if (!ec) fs::rename(staging_ / relative, destination, ec);
    if (ec) throw Error("cannot write: " + reason(ec), destination.string());
  }
  // The manifest lists this run's files and the previous crfcal files that are still as crfcal wrote them.
  OutputManifest manifest;
  manifest.command = policy_.command;
  if (previous)
    for (const auto& entry : previous->files)
      if (!std::binary_search(files.begin(), files.end(), fs::path(entry.path)) &&
          previous->lists(entry.path, final_ / entry.path))
        manifest.files.push_back(entry);
  for (const auto& relative : files) manifest.files.push_back(describeFile(final_, relative));
  writeManifest(final_, manifest);
  fs::remove_all(staging_, ec);  // only the (now empty) staged directories are left
}

}  // namespace crfcal::io
