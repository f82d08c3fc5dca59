#include "parallel_jobs.hpp"

#include <algorithm>
#include <atomic>
#include <map>
#include <memory>
#include <mutex>

#include <opencv2/core.hpp>
#include <tbb/task_arena.h>
#include <tbb/task_group.h>

namespace crfcal::detail {

namespace {

// One arena per thread count (`--threads` sets OpenCV's; a bench may change it between cases), made on first use
// and kept for the process. A job that starts jobs of its own is already inside the arena: task_arena::execute then
// runs in place, and the nested jobs are shared out among the arena's threads (a thread waiting for its nested jobs
// takes part in them) instead of running one after another in the job's thread.
tbb::task_arena& arenaFor(int threads) {
  static std::mutex mutex;
  static std::map<int, std::unique_ptr<tbb::task_arena>> arenas;
  const std::lock_guard<std::mutex> lock(mutex);
  std::unique_ptr<tbb::task_arena>& arena = arenas[threads];
  if (!arena) arena = std::make_unique<tbb::task_arena>(threads);
  return *arena;
}

}  // namespace

void runJobs(const std::vector<int>& order, const std::function<void(int)>& job) {
  const int jobs = static_cast<int>(order.size());
  const int threads = std::max(1, cv::getNumThreads());
  if (jobs == 0) return;
  if (jobs == 1 || threads == 1) {  // as a serial loop
    for (int i : order) job(i);
    return;
  }
  // Workers that each take the next job in `order` as they finish (dearest first when the caller orders so).
  std::atomic<int> next{0};
  const int workers = std::min(jobs, threads);
  arenaFor(threads).execute([&] {
    tbb::task_group group;
    for (int w = 0; w < workers; ++w)
      group.run([&] {
        for (int k = next++; k < jobs; k = next++) job(order[static_cast<std::size_t>(k)]);
      });
    group.wait();
  });
}

}  // namespace crfcal::detail
