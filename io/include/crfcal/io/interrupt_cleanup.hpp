#pragma once
// Ctrl-C leaves no partial output: on SIGINT, SIGTERM or SIGHUP every staging directory and temporary file crfcal
// has registered is removed, then the process ends as the signal would have ended it. A previous output is never
// touched: outputs are moved into place while interrupts are deferred (deferInterrupts), so an interrupt arriving
// then waits until the move is complete.
#include <filesystem>
#include <mutex>

namespace crfcal::io {

// Call first in main(), before any thread starts: blocks the three signals in every thread (threads inherit the
// mask) and waits for them in a dedicated thread, which may then safely remove files. A signal that is ignored at
// start-up (e.g. SIGINT of a background job, SIGHUP under nohup) stays ignored.
void installInterruptCleanup();

// Removes `path` (file or directory tree) if the process is interrupted while this object lives.
class RemovedOnInterrupt {
 public:
  explicit RemovedOnInterrupt(std::filesystem::path path);
  ~RemovedOnInterrupt();
  RemovedOnInterrupt(const RemovedOnInterrupt&) = delete;
  RemovedOnInterrupt& operator=(const RemovedOnInterrupt&) = delete;

 private:
  std::filesystem::path path_;
};

// While the returned lock lives, an interrupt waits (the cleanup runs after it is released). Re-entrant.
std::unique_lock<std::recursive_mutex> deferInterrupts();

}  // namespace crfcal::io
