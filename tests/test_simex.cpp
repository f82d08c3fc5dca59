// SIMEX around the fitter (calib/include/crfcal/simex.hpp): options, and what the extrapolation does on a pair
// whose sharp shot carries the seed's middle noise level (σ² = 0.005, I in [0, 1]).
#include <cmath>

#include <gtest/gtest.h>

#include "crfcal/error.hpp"
#include "crfcal/simex.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

TEST(Simex, OptionsRejectNonPositiveMultiplesAndTooHighDegree) {
  SimexOptions o;
  EXPECT_NO_THROW(o.check());
  o.added_variance_multiples = {0.5, -1.0};
  EXPECT_THROW(o.check(), InvalidInput);
  o = SimexOptions{};
  o.added_variance_multiples = {1.0};
  o.extrapolation_degree = 2;
  EXPECT_THROW(o.check(), InvalidInput);
  o = SimexOptions{};
  o.replicates = 0;
  EXPECT_THROW(o.check(), InvalidInput);
}

// The noise of I biases the fitted r low at r = 1 (errors in variables); the extra-noise refits show the trend
// and the linear extrapolation to zero noise must move r towards the truth, and return a valid curve.
TEST(Simex, LinearExtrapolationMovesRatioTowardsTruthOnNoisyPair) {
  const cv::Mat image = test::levinImage(1);
  const cv::Mat kernel = test::levinKernel(2);
  SimulationOptions sim;
  sim.noise_variance = 0.005;
  sim.seed = 5;
  const SimulationResult pair = simulatePair(image, GammaModel{2.2}, kernel, sim);
  CrfFitOptions fit;
  fit.threads = 1;
  SimexOptions simex;
  simex.extrapolation_degree = 1;
  SimexSummary summary;
  const CrfFitResult result = fitInverseCrfSimex(pair.sharp, pair.blurred, kernel, fit, simex, &summary);
  ASSERT_TRUE(summary.extrapolated) << result.choice_reason;
  ASSERT_EQ(summary.multiples.size(), 5u);
  const double naive_ratio = summary.ratios.front();
  EXPECT_LT(naive_ratio, 1.0);  // the bias SIMEX is there to remove
  EXPECT_LT(std::abs(std::log(result.ratio)), std::abs(std::log(naive_ratio)))
      << "naive r " << naive_ratio << ", SIMEX r " << result.ratio;
  ASSERT_EQ(result.inverse_crf.size(), static_cast<std::size_t>(kCurveSamples));
  EXPECT_DOUBLE_EQ(result.inverse_crf.front(), 0.0);
  EXPECT_DOUBLE_EQ(result.inverse_crf.back(), 1.0);
  for (int i = 1; i < kCurveSamples; ++i) ASSERT_GE(result.inverse_crf[i], result.inverse_crf[i - 1]);
  EXPECT_NE(result.chosen.find("+simex"), std::string::npos);
}

}  // namespace
}  // namespace crfcal
