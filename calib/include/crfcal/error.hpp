#pragma once
// Exceptions thrown by crfcal. Every error carries the reason; errors about a file also carry its path so
// that the CLI can print "FILE: reason" on one line. The computation does not know file names: it names what the
// error is about (ErrorSubject), and the caller that read the files maps the subject to the file to blame.
#include <stdexcept>
#include <string>

namespace crfcal {

// What an error is about, for the caller that knows which file holds it.
enum class ErrorSubject {
  unspecified,    // not said (the caller blames every input it gave)
  sharp_image,    // the sharp (short-exposure) shot alone
  blurred_image,  // the blurred (long-exposure) shot alone
  pair,           // the two shots together (sizes, overlap, scene)
  kernel,         // a given blur kernel
  curve,          // a given response curve
  options,        // the options / command-line values
  output,         // where the results go
};

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& reason, std::string file = {})
      : Error(reason, ErrorSubject::unspecified, std::move(file)) {}
  Error(const std::string& reason, ErrorSubject subject, std::string file = {})
      : std::runtime_error(file.empty() ? reason : file + ": " + reason),
        reason_(reason),
        file_(std::move(file)),
        subject_(subject) {}
  const std::string& reason() const noexcept { return reason_; }
  const std::string& file() const noexcept { return file_; }
  ErrorSubject subject() const noexcept { return subject_; }

 private:
  std::string reason_;
  std::string file_;
  ErrorSubject subject_ = ErrorSubject::unspecified;
};

// Input that cannot be used (bad kernel, bad curve parameters, mismatched sizes, ...).
class InvalidInput : public Error {
 public:
  using Error::Error;
};

}  // namespace crfcal
