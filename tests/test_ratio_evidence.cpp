// The exposure ratio from the pair's evidence (ratio_evidence.hpp): the images' r and the nominal ratio combined by
// their precisions, the images' precision measured by half-sample refits; conflicts decided by the brightness
// interval; the verdict reports a conflict.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/channel_verdict.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ratio_evidence.hpp"

namespace crfcal {
namespace {

RatioEvidenceOptions noFloor() {
  RatioEvidenceOptions o;
  o.images_exponent_sigma_floor = 0;
  return o;
}

TEST(RatioEvidence, TightHalfSamplesKeepTheImagesRatio) {
  // Half-samples within 1 % of each other: σ_images ≈ 0.01 ≪ 0.13, so the images' r stands.
  const RatioEvidence e = combineRatioEvidence(4.0, {4.04, 3.96, 4.02, 3.98}, 4.4, noFloor());
  ASSERT_TRUE(e.combined);
  EXPECT_EQ(e.decision, RatioDecision::combined);
  EXPECT_GT(e.images_weight, 0.98);
  EXPECT_NEAR(e.ratio, 4.0, 0.01);
  EXPECT_FALSE(e.conflict);
}

TEST(RatioEvidence, ScatteredHalfSamplesHandRToTheNominalRatio) {
  // Halves spread by a factor 1.5 in each direction: σ_images ≈ 0.4 > 0.13, so the nominal ratio dominates.
  const RatioEvidence e = combineRatioEvidence(4.0, {6.0, 2.67, 6.0, 2.67}, 5.0, noFloor());
  ASSERT_TRUE(e.combined);
  EXPECT_LT(e.images_weight, 0.15);
  EXPECT_NEAR(std::log(e.ratio), std::log(5.0), 0.05);
  EXPECT_LT(e.log_sigma, 0.13);  // a posterior is tighter than either source
}

TEST(RatioEvidence, FloorIsAnExponentErrorAddedInQuadrature) {
  RatioEvidenceOptions o;
  o.images_exponent_sigma_floor = 0.072;
  const RatioEvidence e = combineRatioEvidence(4.0, {4.0, 4.0}, 4.4, o);
  EXPECT_DOUBLE_EQ(e.resampled_log_sigma, 0);
  const double floor = 0.072 * std::log(4.0);
  EXPECT_NEAR(e.images_log_sigma, floor, 1e-12);
  const double w = (1 / (floor * floor)) / (1 / (floor * floor) + 1 / (0.13 * 0.13));
  EXPECT_NEAR(e.images_weight, w, 1e-9);
  EXPECT_NEAR(e.ratio, std::exp(w * std::log(4.0) + (1 - w) * std::log(4.4)), 1e-9);
  // At r = 1 brightness alone fixes r: a precise images' r is kept whatever the nominal ratio says.
  const RatioEvidence at_one = combineRatioEvidence(1.0, {1.0004, 0.9996}, 1.04, o);
  EXPECT_GT(at_one.images_weight, 0.999);
  EXPECT_NEAR(at_one.ratio, 1.0, 1e-4);
}

TEST(RatioEvidence, ConflictSidedByBrightnessHoldsTheNominalRatio) {
  // The images give 2 with tight halves, EXIF 6.25; the brightness allows 4-25: EXIF is inside, the images are not.
  const RatioEvidence e = combineRatioEvidence(2.0, {2.02, 1.98, 2.01, 1.99}, 6.25, RatioEvidenceOptions{}, {4, 25});
  EXPECT_TRUE(e.conflict);
  EXPECT_GT(e.conflict_sigmas, 3);
  EXPECT_EQ(e.decision, RatioDecision::nominal_held);
  EXPECT_DOUBLE_EQ(e.ratio, 6.25);
}

TEST(RatioEvidence, ConflictSidedByBrightnessKeepsTheImagesRatio) {
  // EXIF mis-states the exposure (a multi-frame long shot): the brightness agrees with the images.
  const RatioEvidence e = combineRatioEvidence(2.0, {2.02, 1.98, 2.01, 1.99}, 6.25, RatioEvidenceOptions{}, {1.3, 3.5});
  EXPECT_TRUE(e.conflict);
  EXPECT_EQ(e.decision, RatioDecision::images_kept);
  EXPECT_DOUBLE_EQ(e.ratio, 2.0);
}

TEST(RatioEvidence, ConflictWithoutBrightnessKeepsTheCombination) {
  const RatioEvidence e = combineRatioEvidence(2.0, {2.02, 1.98, 2.01, 1.99}, 6.25, RatioEvidenceOptions{});
  EXPECT_TRUE(e.conflict);
  EXPECT_EQ(e.decision, RatioDecision::combined);
  EXPECT_GT(e.ratio, 2.0);
  EXPECT_LT(e.ratio, 6.25);
}

TEST(RatioEvidence, TooFewRefitsOrNoNominalRatioLeaveTheImagesRatio) {
  EXPECT_FALSE(combineRatioEvidence(3.0, {3.1}, 4.0, RatioEvidenceOptions{}).combined);
  EXPECT_FALSE(combineRatioEvidence(3.0, {3.1, 2.9}, 0, RatioEvidenceOptions{}).combined);
  const RatioEvidence e = combineRatioEvidence(3.0, {}, 4.0, RatioEvidenceOptions{});
  EXPECT_EQ(e.decision, RatioDecision::images_alone);
  EXPECT_DOUBLE_EQ(e.ratio, 3.0);
}

TEST(RatioEvidence, BadOptionsAreRefused) {
  RatioEvidenceOptions o;
  o.nominal_log_sigma = 0;
  EXPECT_THROW(combineRatioEvidence(3.0, {3.1, 2.9}, 4.0, o), InvalidInput);
  o = {};
  o.replicates = 3;
  EXPECT_THROW(o.check(), InvalidInput);
}

TEST(RatioEvidence, BrightnessIntervalCoversTheCurveExponents) {
  const auto [lo, hi] = brightnessRatioInterval(4.0, 1.0, 1.6, 1.5);
  EXPECT_NEAR(lo, 4.0 / 1.5, 1e-12);
  EXPECT_NEAR(hi, std::pow(4.0, 1.6) * 1.5, 1e-9);
  const auto none = brightnessRatioInterval(0, 1.0, 1.6, 1.5);
  EXPECT_EQ(none.second, 0);
}

TEST(RatioEvidence, VerdictOfAHeldConflictIsWeakAndSaysWhy) {
  ChannelEvidence e;
  e.channel = "G";
  e.ratio = 6.25;
  e.nominal_ratio = 6.25;
  e.brightness_ratio = 5.9;
  e.covered = std::make_pair(0.05, 0.9);
  e.inverse_crf.resize(1024);
  for (int i = 0; i < 1024; ++i) e.inverse_crf[i] = std::pow(i / 1023.0, 2.2);
  const ChannelVerdict clean = judgeChannels({e}, {}).at("G");
  EXPECT_EQ(clean.level, VerdictLevel::ok);
  e.ratio_conflict = true;
  e.ratio_held_at_nominal = true;
  e.ratio_images = 2.0;
  e.ratio_conflict_sigmas = 6.0;
  e.ratio_decision = toString(RatioDecision::nominal_held);
  const ChannelVerdict v = judgeChannels({e}, {}).at("G");
  EXPECT_EQ(v.level, VerdictLevel::weak);
  bool said = false;
  for (const auto& r : v.reasons) said = said || r.find("sides with EXIF") != std::string::npos;
  EXPECT_TRUE(said);
}

}  // namespace
}  // namespace crfcal
