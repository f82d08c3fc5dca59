#pragma once
// Exceptions thrown by crfcal. Every error carries the reason; errors about a file also carry its path so
// that the CLI can print "FILE: reason" on one line.
#include <stdexcept>
#include <string>

namespace crfcal {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& reason, std::string file = {})
      : std::runtime_error(file.empty() ? reason : file + ": " + reason),
        reason_(reason),
        file_(std::move(file)) {}
  const std::string& reason() const noexcept { return reason_; }
  const std::string& file() const noexcept { return file_; }

 private:
  std::string reason_;
  std::string file_;
};

// Input that cannot be used (bad kernel, bad curve parameters, mismatched sizes, ...).
class InvalidInput : public Error {
 public:
  using Error::Error;
};

}  // namespace crfcal
