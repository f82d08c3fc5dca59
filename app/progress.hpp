#pragma once
// Progress on the terminal: a rewritten status line on a TTY, one line per stage otherwise (logs, CI).
#include <chrono>
#include <string>

namespace crfcal::app {

class Progress {
 public:
  explicit Progress(bool quiet = false);
  // Starts a named stage.
  void stage(const std::string& name);
  // Fraction done of the current stage (0..1), optionally with a detail ("12/240").
  void update(double fraction, const std::string& detail = {});
  // Ends the current stage, printing its duration.
  void done(const std::string& summary = {});

 private:
  bool quiet_;
  bool tty_;
  std::string stage_;
  std::chrono::steady_clock::time_point start_;
  int last_percent_ = -1;
};

}  // namespace crfcal::app
