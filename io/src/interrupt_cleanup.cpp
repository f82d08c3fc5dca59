#include "crfcal/io/interrupt_cleanup.hpp"

#include <csignal>
#include <map>
#include <system_error>
#include <thread>

#include <pthread.h>

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {

std::recursive_mutex& registryMutex() {
  static std::recursive_mutex mutex;
  return mutex;
}

// path → number of registrations (the same temporary name may be registered twice in nested scopes)
std::map<fs::path, int>& registered() {
  static std::map<fs::path, int> paths;
  return paths;
}

[[noreturn]] void cleanUpAndExit(int signal_number) {
  // Never released: whatever the main thread does next (a commit, a new staging directory) waits until the process
  // has ended.
  registryMutex().lock();
  for (const auto& [path, count] : registered()) {
    // A worker may still be writing into a staging directory: retry when a new file appeared mid-removal.
    std::error_code ec;
    for (int attempt = 0; attempt < 5 && fs::symlink_status(path, ec).type() != fs::file_type::not_found; ++attempt)
      fs::remove_all(path, ec);
  }
  std::signal(signal_number, SIG_DFL);
  sigset_t only;
  sigemptyset(&only);
  sigaddset(&only, signal_number);
  pthread_sigmask(SIG_UNBLOCK, &only, nullptr);
  std::raise(signal_number);  // ends the process with the signal's own status (130 for Ctrl-C in a shell)
  std::_Exit(128 + signal_number);
}

}  // namespace

void installInterruptCleanup() {
  sigset_t signals;
  sigemptyset(&signals);
  for (const int s : {SIGINT, SIGTERM, SIGHUP}) {
    struct sigaction current {};
    if (sigaction(s, nullptr, &current) == 0 && current.sa_handler == SIG_IGN) continue;
    sigaddset(&signals, s);
  }
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  std::thread([signals] {
    int signal_number = 0;
    while (sigwait(&signals, &signal_number) != 0) {
    }
    cleanUpAndExit(signal_number);
  }).detach();
}

RemovedOnInterrupt::RemovedOnInterrupt(fs::path path) : path_(std::move(path)) {
  std::lock_guard<std::recursive_mutex> lock(registryMutex());
  ++registered()[path_];
}

RemovedOnInterrupt::~RemovedOnInterrupt() {
  std::lock_guard<std::recursive_mutex> lock(registryMutex());
  auto it = registered().find(path_);
  if (it != registered().end() && --it->second == 0) registered().erase(it);
}

std::unique_lock<std::recursive_mutex> deferInterrupts() {
  return std::unique_lock<std::recursive_mutex>(registryMutex());
}

}  // namespace crfcal::io
