// The pair pipeline runs its independent fits one per core (channels, half-sample refits, effect candidates;
// docs/RESULTS.md#speed-small). A race between them would make two runs differ; the fitter splits its sums into as
// many stripes as OpenCV has threads (crf_objective.cpp), so one thread agrees with two only to rounding.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "crfcal/pair_calibration.hpp"
#include "crfcal/response_model.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

PairCalibrationResult calibrateWithThreads(const cv::Mat& sharp, const cv::Mat& blurred, int threads) {
  const test::ThreadCount scope(threads);
  PairCalibrationOptions options;
  options.register_pair = false;
  options.fit.nominal_ratio = 2.1;  // EXIF 5 % off: the ratio stage runs its half-sample refits
  return calibratePair(sharp, blurred, options);
}

// Three channels from one simulated pair (the channels differ by a gain, so their fits differ).
cv::Mat colourOf(const cv::Mat& grey_unit) {
  std::vector<cv::Mat> planes{0.85 * grey_unit, grey_unit, 0.92 * grey_unit};
  cv::Mat bgr, out;
  cv::merge(planes, bgr);
  bgr.convertTo(out, CV_8U, 255);
  return out;
}

struct SimulatedColourPair {
  cv::Mat sharp, blurred;
};

SimulatedColourPair simulatedColourPair() {
  SimulationOptions sim;
  sim.ratio = 2;
  sim.noise_variance = 1e-4;
  const SimulationResult pair =
      simulatePair(0.45 * test::levinImage(1), GammaModel{2.2}, test::levinKernel(3), sim);
  return {colourOf(pair.sharp), colourOf(pair.blurred)};
}

double largestDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double d = a.size() == b.size() ? 0 : 1e300;
  for (std::size_t i = 0; i < std::min(a.size(), b.size()); ++i) d = std::max(d, std::abs(a[i] - b[i]));
  return d;
}

TEST(ParallelDeterminism, TwoRunsWithTwoThreadsAreIdentical) {
  const SimulatedColourPair pair = simulatedColourPair();
  const PairCalibrationResult first = calibrateWithThreads(pair.sharp, pair.blurred, 2);
  const PairCalibrationResult second = calibrateWithThreads(pair.sharp, pair.blurred, 2);
  ASSERT_EQ(first.fits.size(), 3u);
  for (const auto& [name, fit] : first.fits) {
    SCOPED_TRACE(name);
    ASSERT_TRUE(second.fits.count(name) && first.bands.count(name) && second.bands.count(name));
    EXPECT_EQ(fit.inverse_crf, second.fits.at(name).inverse_crf);
    EXPECT_EQ(fit.ratio, second.fits.at(name).ratio);
    EXPECT_EQ(first.bands.at(name).lower, second.bands.at(name).lower);
    EXPECT_EQ(first.bands.at(name).upper, second.bands.at(name).upper);
  }
  EXPECT_EQ(first.effects.detected(), second.effects.detected());
  EXPECT_EQ(first.ratio_evidence.ratio, second.ratio_evidence.ratio);
}

TEST(ParallelDeterminism, OneThreadAgreesWithTwoToRounding) {
  const SimulatedColourPair pair = simulatedColourPair();
  const PairCalibrationResult serial = calibrateWithThreads(pair.sharp, pair.blurred, 1);
  const PairCalibrationResult parallel = calibrateWithThreads(pair.sharp, pair.blurred, 2);
  ASSERT_EQ(serial.fits.size(), 3u);
  for (const auto& [name, fit] : serial.fits) {
    SCOPED_TRACE(name);
    ASSERT_TRUE(parallel.fits.count(name) && serial.bands.count(name) && parallel.bands.count(name));
    EXPECT_LT(largestDifference(fit.inverse_crf, parallel.fits.at(name).inverse_crf), 1e-5);
    EXPECT_NEAR(fit.ratio / parallel.fits.at(name).ratio, 1, 1e-5);
    EXPECT_LT(largestDifference(serial.bands.at(name).lower, parallel.bands.at(name).lower), 1e-4);
    EXPECT_LT(largestDifference(serial.bands.at(name).upper, parallel.bands.at(name).upper), 1e-4);
  }
  EXPECT_EQ(serial.effects.detected(), parallel.effects.detected());
}

}  // namespace
}  // namespace crfcal
