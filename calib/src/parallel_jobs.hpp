// Independent jobs, one per core: the pair pipeline's channel fits, half-sample refits and effect candidates, the
// bracket's frame registrations. OpenCV's parallel_for_ runs them (nested parallel loops inside a job then run in
// that job's thread); an exception cannot cross it, so each job's is kept and handed back by index, for the caller
// to rethrow or handle in job order, as a serial loop would meet them.
#pragma once

#include <algorithm>
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

}  // namespace crfcal::detail
