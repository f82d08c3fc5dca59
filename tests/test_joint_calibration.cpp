// Several pairs of one camera fitted jointly (joint_crf_fit.hpp, joint_calibration.hpp; issue 19): the covered
// ranges add up, the pairs' r are held, bad input is refused naming the pair.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/error.hpp"
#include "crfcal/joint_calibration.hpp"
#include "crfcal/joint_crf_fit.hpp"
#include "crfcal/response_model.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A curve with a shoulder, so that extrapolating from a pair's own top is not enough.
const GgcmModel kTruth{{0.42, 0.15, -0.08, 0.05, 0.02}};

// A pair whose sharp intensities span [lo, hi] (the Levin image rescaled), blurred by Levin kernel `k` with ratio r.
struct RangePair {
  SimulationResult pair;
  cv::Mat kernel;
  double ratio;
  RangePair(int image, int k, double lo, double hi, double r, std::uint64_t seed) : kernel(test::levinKernel(k)), ratio(r) {
    SimulationOptions sim;
    sim.ratio = r;
    sim.noise_variance = 0.0004;
    sim.image_is_irradiance = false;
    sim.seed = seed;
    pair = simulatePair(lo + (hi - lo) * test::levinImage(image), kTruth, kernel, sim);
  }
  JointFitPair input() const { return {pair.sharp, pair.blurred, kernel, CrfFitOptions{}, ratio}; }
};

// RMSE of a against b over x in [lo, hi]; shape: after a's best common scale onto b there (φ → sφ leaves Eq. 4
// unchanged, so inside the data only the shape is measured; the scale is extrapolated from the top of the data).
double rmseOver(const std::vector<double>& a, const std::vector<double>& b, double lo, double hi, bool shape = false) {
  double num = 0, den = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const double x = double(i) / (a.size() - 1);
    if (x >= lo && x <= hi) num += a[i] * b[i], den += a[i] * a[i];
  }
  const double s = shape && den > 0 ? num / den : 1.0;
  double sum = 0;
  int n = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const double x = double(i) / (a.size() - 1);
    if (x < lo || x > hi) continue;
    sum += (s * a[i] - b[i]) * (s * a[i] - b[i]);
    ++n;
  }
  return std::sqrt(sum / std::max(n, 1));
}

TEST(JointFit, TwoPairsWithDifferentRangesBeatEachPairOverTheUnion) {
  const RangePair dark(1, 2, 0.04, 0.45, 2.0, 3), bright(3, 4, 0.35, 0.97, 1.0, 4);
  const std::vector<double> truth = sampleInverse(kTruth);
  CrfFitOptions single;
  single.nominal_ratio = 2.0;
  const CrfFitResult a = fitInverseCrf(dark.pair.sharp, dark.pair.blurred, dark.kernel, single);
  single.nominal_ratio = 1.0;
  const CrfFitResult b = fitInverseCrf(bright.pair.sharp, bright.pair.blurred, bright.kernel, single);
  const JointCrfFitResult joint = fitInverseCrfJointly({dark.input(), bright.input()});
  const double lo = std::min(a.covered_levels.first, b.covered_levels.first) / 255.0;
  const double hi = std::max(a.covered_levels.second, b.covered_levels.second) / 255.0;
  const double e_joint = rmseOver(joint.fit.inverse_crf, truth, lo, hi);
  const double e_a = rmseOver(a.inverse_crf, truth, lo, hi), e_b = rmseOver(b.inverse_crf, truth, lo, hi);
  const double s_joint = rmseOver(joint.fit.inverse_crf, truth, lo, hi, true);
  const double s_a = rmseOver(a.inverse_crf, truth, lo, hi, true), s_b = rmseOver(b.inverse_crf, truth, lo, hi, true);
  const std::string numbers = joint.summary() + "\nRMSE over the union: joint " + std::to_string(e_joint) + ", dark " +
                              std::to_string(e_a) + ", bright " + std::to_string(e_b) + "; shape: joint " +
                              std::to_string(s_joint) + ", dark " + std::to_string(s_a) + ", bright " +
                              std::to_string(s_b);
  EXPECT_LT(e_joint, std::min(e_a, e_b)) << numbers;
  EXPECT_LT(s_joint, std::min(s_a, s_b)) << numbers;
  EXPECT_LT(s_joint, 0.01) << numbers;
  std::cout << numbers << "\n";
  EXPECT_EQ(joint.fit.covered_levels.first, std::min(joint.covered_levels[0].first, joint.covered_levels[1].first));
  EXPECT_EQ(joint.fit.covered_levels.second, std::max(joint.covered_levels[0].second, joint.covered_levels[1].second));
  // r held; at the joint φ each pair's own rows still say its r
  EXPECT_DOUBLE_EQ(joint.ratios[0], 2.0);
  EXPECT_NEAR(joint.ratios_at_joint_phi[0], 2.0, 0.1);
  EXPECT_NEAR(joint.ratios_at_joint_phi[1], 1.0, 0.05);
}

TEST(JointFit, RefusesABadPairNamingIt) {
  const RangePair good(1, 2, 0.1, 0.9, 1.0, 3);
  JointFitPair flat = good.input();
  flat.sharp = cv::Mat(good.pair.sharp.size(), CV_64F, cv::Scalar(0.5));
  flat.blurred = flat.sharp.clone();
  try {
    fitInverseCrfJointly({good.input(), flat});
    FAIL() << "a pair without edges was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_EQ(std::string(e.reason()).rfind("pair 2: ", 0), 0u) << e.reason();
  }
  EXPECT_THROW(fitInverseCrfJointly({}), InvalidInput);
  JointFitPair wrong_ratio = good.input();
  wrong_ratio.ratio = 0;
  EXPECT_THROW(fitInverseCrfJointly({good.input(), wrong_ratio}), InvalidInput);
}

TEST(JointCalibration, NeedsTwoPairsWithTheirFitInputs) {
  EXPECT_THROW(calibrateJointly({PairCalibrationResult{}}), InvalidInput);
  EXPECT_THROW(calibrateJointly({PairCalibrationResult{}, PairCalibrationResult{}}), InvalidInput);
}

}  // namespace
}  // namespace crfcal
