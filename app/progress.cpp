#include "progress.hpp"

#include <cstdio>

#include <unistd.h>

namespace crfcal::app {

Progress::Progress(bool quiet) : quiet_(quiet), tty_(::isatty(STDERR_FILENO) != 0) {}

void Progress::stage(const std::string& name) {
  stage_ = name;
  start_ = std::chrono::steady_clock::now();
  last_percent_ = -1;
  if (quiet_) return;
  if (tty_) std::fprintf(stderr, "\r\033[K%s ...", name.c_str());
  else std::fprintf(stderr, "%s ...\n", name.c_str());
  std::fflush(stderr);
}

void Progress::update(double fraction, const std::string& detail) {
  if (quiet_) return;
  const int percent = static_cast<int>(fraction * 100);
  if (percent == last_percent_) return;
  last_percent_ = percent;
  if (tty_) {
    std::fprintf(stderr, "\r\033[K%s %3d%% %s", stage_.c_str(), percent, detail.c_str());
  } else if (percent % 25 == 0) {
    std::fprintf(stderr, "  %s %d%% %s\n", stage_.c_str(), percent, detail.c_str());
  }
  std::fflush(stderr);
}

void Progress::done(const std::string& summary) {
  if (quiet_) return;
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  std::fprintf(stderr, "%s%s done in %.2f s%s%s\n", tty_ ? "\r\033[K" : "  ", stage_.c_str(), seconds,
               summary.empty() ? "" : ": ", summary.c_str());
  std::fflush(stderr);
}

}  // namespace crfcal::app
