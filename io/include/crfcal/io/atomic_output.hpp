#pragma once
// All-or-nothing output. Files are written to a temporary sibling and renamed into place, so a failure or an
// interrupt (see interrupt_cleanup.hpp) never leaves a half-written file or result directory behind.
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "crfcal/io/output_guard.hpp"

namespace crfcal::io {

class RemovedOnInterrupt;

// Writes `path` by calling `write(temporary_path)` and renaming the temporary file over `path` on success.
// If `write` throws, the temporary file is removed and the exception propagates. Throws crfcal::Error naming the
// file and the reason (e.g. "no such directory", "permission denied", "is a directory").
void writeAtomically(const std::filesystem::path& path, const std::function<void(const std::filesystem::path&)>& write);

// Writes `contents` to `path` atomically. Throws crfcal::Error naming the file and the reason.
void writeTextFile(const std::filesystem::path& path, const std::string& contents);

// A result directory DIR built in a staging directory and moved into place by commit(), with a manifest
// (output_manifest.hpp) listing the files written. Construct it before the computation: the constructor decides
// whether DIR may be written and creates the staging directory, so a refused or unwritable location fails at once.
//  - DIR missing, empty, or holding only a previous crfcal output (its manifest's files, none an input):
//    DIR is replaced as a whole, atomically (staging is the sibling ".DIR.partial-<pid>").
//  - DIR holding anything else: refused (crfcal::Error naming DIR and the first such file) unless policy.force;
//    with force, crfcal's files are staged in DIR/.crfcal.partial-<pid> and each renamed into DIR, replacing only
//    files of the same name; nothing else is deleted, and an input is never replaced (refused at commit).
// Without commit() (an exception unwinds, or an interrupt) the staging directory is deleted and DIR is untouched.
class OutputDirectory {
 public:
  OutputDirectory(std::filesystem::path final_path, OutputPolicy policy);
  ~OutputDirectory();
  OutputDirectory(const OutputDirectory&) = delete;
  OutputDirectory& operator=(const OutputDirectory&) = delete;

  // Path of a file inside the staging directory.
  std::filesystem::path file(const std::string& name) const { return staging_ / name; }
  const std::filesystem::path& finalPath() const { return final_; }
  // Moves the staged files into DIR (see above) and writes the manifest.
  void commit();

 private:
  void replaceWhole();
  void mergeInto();
  void removeCreatedParents();

  std::filesystem::path final_;
  OutputPolicy policy_;
  std::filesystem::path staging_;
  bool merge_ = false;  // write beside foreign files (--force) instead of replacing DIR
  bool committed_ = false;
  std::unique_ptr<RemovedOnInterrupt> staging_cleanup_;
  std::vector<std::filesystem::path> created_parents_;  // missing parents created for DIR, deepest first
};

}  // namespace crfcal::io
