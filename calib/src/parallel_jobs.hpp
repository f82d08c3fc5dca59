// Independent jobs, spread over the cores: the pair pipeline's channel fits, half-sample refits and effect
// candidates, the bracket's frame registrations. They run as tasks of one TBB arena of cv::getNumThreads() threads
// (parallel_jobs.cpp). Jobs started inside a job join the same arena, so a core that runs out of jobs helps with
// another job's nested ones (OpenCV's parallel_for_ runs a loop nested in another serially, in its job's thread: three
// channel fits on two cores then left a core idle for a third of the time). An exception cannot cross the arena, so
// each job's is kept and handed back by index, for the caller to rethrow or handle in job order, as a serial loop
// would meet them. Jobs must not depend on the thread that runs them: results are written by index, and a
// thread_local cache may only hold what a job would recompute to the same bits (a thread waiting for its nested jobs
// may run another job in between).
#pragma once

#include <algorithm>
#include <exception>
#include <functional>
#include <vector>

namespace crfcal::detail {

// Runs job(order[k]) for every k, started in that order by workers on a TBB arena of cv::getNumThreads() threads
// (parallel_jobs.cpp), each taking the next job as it finishes; returns when all have finished. Called from one of
// the arena's jobs, the nested jobs share the arena's threads. `job` must not throw.
void runJobs(const std::vector<int>& order, const std::function<void(int)>& job);

// job(i) for every i of `order` (a permutation of [0, jobs)), started in that order: with the dearest jobs first, the last
// job to finish is a cheap one, so a core does not sit idle while the other finishes a long job begun late. The results are
// per index, so the order changes no result, only when each job runs. Returns the exception each job threw (null where
// none).
template <class Job>
std::vector<std::exception_ptr> runInParallelDearestFirst(const std::vector<int>& order, const Job& job) {
  std::vector<std::exception_ptr> errors(order.size());
  runJobs(order, [&](int i) {
    try {
      job(i);
    } catch (...) {
      errors[static_cast<std::size_t>(i)] = std::current_exception();
    }
  });
  return errors;
}

// Runs job(i) for i in [0, jobs); returns the exception each job threw (null where none).
template <class Job>
std::vector<std::exception_ptr> runInParallel(int jobs, const Job& job) {
  std::vector<int> order(static_cast<std::size_t>(std::max(jobs, 0)));
  for (int i = 0; i < jobs; ++i) order[static_cast<std::size_t>(i)] = i;
  return runInParallelDearestFirst(order, job);
}

}  // namespace crfcal::detail
