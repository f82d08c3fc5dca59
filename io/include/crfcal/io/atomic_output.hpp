#pragma once
// All-or-nothing output. Files are written to a temporary sibling and renamed into place, so a failure never
// leaves a half-written file or result directory behind.
#include <filesystem>
#include <functional>
#include <string>

namespace crfcal::io {

// Writes `path` by calling `write(temporary_path)` and renaming the temporary file over `path` on success.
// If `write` throws, the temporary file is removed and the exception propagates.
void writeAtomically(const std::filesystem::path& path, const std::function<void(const std::filesystem::path&)>& write);

// Writes `contents` to `path` atomically. Throws crfcal::Error naming the file.
void writeTextFile(const std::filesystem::path& path, const std::string& contents);

// A result directory built in a temporary sibling ("DIR.partial-<pid>") and moved into place by commit().
// Without commit() (e.g. an exception unwinds) the temporary directory is deleted and DIR is untouched.
class OutputDirectory {
 public:
  explicit OutputDirectory(std::filesystem::path final_path);
  ~OutputDirectory();
  OutputDirectory(const OutputDirectory&) = delete;
  OutputDirectory& operator=(const OutputDirectory&) = delete;

  // Path of a file inside the (temporary) directory.
  std::filesystem::path file(const std::string& name) const { return staging_ / name; }
  const std::filesystem::path& finalPath() const { return final_; }
  // Replaces DIR (if it exists) with the staged directory.
  void commit();

 private:
  std::filesystem::path final_;
  std::filesystem::path staging_;
  bool committed_ = false;
};

}  // namespace crfcal::io
