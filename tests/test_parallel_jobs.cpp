// calib/src/parallel_jobs.hpp: independent jobs on a TBB arena, jobs started inside jobs sharing the cores. Every job
// runs once, its result and its exception land at its index, and one thread runs them in the order given.
#include <atomic>
#include <stdexcept>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "../calib/src/parallel_jobs.hpp"
#include "test_support.hpp"

namespace crfcal::detail {
namespace {

TEST(ParallelJobs, NestedJobsRunOnceEachAndHandBackTheirExceptionsByIndex) {
  const test::ThreadCount scope(2);
  constexpr int kOuter = 3, kInner = 7;
  std::vector<std::vector<int>> results(kOuter, std::vector<int>(kInner, 0));
  std::atomic<int> runs{0};
  std::vector<std::vector<std::exception_ptr>> inner_errors(kOuter);
  const std::vector<std::exception_ptr> outer_errors = runInParallel(kOuter, [&](int o) {
    inner_errors[o] = runInParallel(kInner, [&](int i) {
      ++runs;
      results[o][i] += 10 * o + i;
      if (o == 1 && i == 4) throw std::runtime_error("job 1.4");
    });
    if (o == 2) throw std::logic_error("job 2");
  });
  EXPECT_EQ(runs.load(), kOuter * kInner);
  for (int o = 0; o < kOuter; ++o)
    for (int i = 0; i < kInner; ++i) {
      EXPECT_EQ(results[o][i], 10 * o + i) << o << "." << i;
      EXPECT_EQ(inner_errors[o][i] != nullptr, o == 1 && i == 4) << o << "." << i;
    }
  EXPECT_EQ(outer_errors[0], nullptr);
  EXPECT_EQ(outer_errors[1], nullptr);
  ASSERT_NE(outer_errors[2], nullptr);
  EXPECT_THROW(std::rethrow_exception(outer_errors[2]), std::logic_error);
  EXPECT_THROW(std::rethrow_exception(inner_errors[1][4]), std::runtime_error);
}

TEST(ParallelJobs, OneThreadRunsTheJobsInTheGivenOrder) {
  const test::ThreadCount scope(1);
  const std::vector<int> order{3, 0, 4, 1, 2};
  std::vector<int> ran;
  const std::vector<std::exception_ptr> errors = runInParallelDearestFirst(order, [&](int i) { ran.push_back(i); });
  EXPECT_EQ(ran, order);
  EXPECT_EQ(errors.size(), order.size());
}

}  // namespace
}  // namespace crfcal::detail
