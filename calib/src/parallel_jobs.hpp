// Independent jobs, one per core: the pair pipeline's channel fits, half-sample refits and effect candidates, the
// bracket's frame registrations. OpenCV's parallel_for_ runs them (nested parallel loops inside a job then run in
// that job's thread); an exception cannot cross it, so each job's is kept and handed back by index, for the caller
// to rethrow or handle in job order, as a serial loop would meet them.
#pragma once

#include <algorithm>
#include <atomic>
#include <exception>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal::detail {

// Runs job(i) for i in [0, jobs); returns the exception each job threw (null where none).
template <class Job>
std::vector<std::exception_ptr> runInParallel(int jobs, const Job& job) {
  std::vector<std::exception_ptr> errors(static_cast<std::size_t>(std::max(jobs, 0)));
  cv::parallel_for_(cv::Range(0, std::max(jobs, 0)), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      try {
        job(i);
      } catch (...) {
        errors[static_cast<std::size_t>(i)] = std::current_exception();
      }
    }
  });
  return errors;
}

// The same, the jobs started in the order `order` (a permutation of [0, jobs)) by workers that each take the next
// one as they finish: with the dearest jobs first, the last job to finish is a cheap one, so a core does not sit
// idle while the other finishes a long job begun late. The results are still per index, so the order changes no
// result, only when each job runs.
template <class Job>
std::vector<std::exception_ptr> runInParallelDearestFirst(const std::vector<int>& order, const Job& job) {
  const int jobs = static_cast<int>(order.size());
  std::vector<std::exception_ptr> errors(static_cast<std::size_t>(jobs));
  std::atomic<int> next{0};
  const int workers = std::max(1, std::min(jobs, cv::getNumThreads()));
  cv::parallel_for_(cv::Range(0, workers), [&](const cv::Range& range) {
    for (int worker = range.start; worker < range.end; ++worker)
      for (int k = next++; k < jobs; k = next++) {
        const int i = order[static_cast<std::size_t>(k)];
        try {
          job(i);
        } catch (...) {
          errors[static_cast<std::size_t>(i)] = std::current_exception();
        }
      }
  });
  return errors;
}

}  // namespace crfcal::detail
