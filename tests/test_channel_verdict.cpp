// The verdict per channel (channel_verdict.hpp): every ground triggers its own reason on constructed evidence; a
// clean fit is "ok".
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "crfcal/channel_verdict.hpp"
#include "crfcal/error.hpp"

namespace crfcal {
namespace {

std::vector<double> gammaCurve(double gamma) {
  std::vector<double> phi(1024);
  for (int i = 0; i < 1024; ++i) phi[i] = std::pow(i / 1023.0, gamma);
  return phi;
}

// A clean channel: r = 4 as EXIF says, the shots' brightness agrees, data over 0.05-0.9, φ = x^2.2.
ChannelEvidence clean(const std::string& channel = "G", double ratio = 4.0) {
  ChannelEvidence e;
  e.channel = channel;
  e.ratio = ratio;
  e.nominal_ratio = 4.0;
  e.brightness_ratio = 4.1;
  e.covered = std::make_pair(0.05, 0.9);
  e.inverse_crf = gammaCurve(2.2);
  return e;
}

bool mentions(const ChannelVerdict& v, const std::string& needle) {
  for (const auto& r : v.reasons)
    if (r.find(needle) != std::string::npos) return true;
  return false;
}

ChannelVerdict judgeOne(const ChannelEvidence& e, const RefitEvidence& refit = {}) {
  return judgeChannels({e}, refit).at(e.channel);
}

TEST(ChannelVerdict, CleanFitIsOkWithTheChecksItPassed) {
  const ChannelVerdict v = judgeOne(clean());
  EXPECT_EQ(v.level, VerdictLevel::ok) << v.summary();
  ASSERT_EQ(v.reasons.size(), 1u);
  EXPECT_TRUE(mentions(v, "EXIF 4")) << v.summary();
  EXPECT_TRUE(mentions(v, "4.1")) << v.summary();
}

TEST(ChannelVerdict, RatioFarFromExifAndFlatRegionsIsUnreliable) {
  ChannelEvidence e = clean();
  e.ratio = 2.36;  // ≈ 4^0.6: the exponent ambiguity
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::unreliable) << v.summary();
  EXPECT_TRUE(mentions(v, "below EXIF 4")) << v.summary();
  EXPECT_TRUE(mentions(v, "brightness ratio")) << v.summary();
}

TEST(ChannelVerdict, RatioFarFromOneSourceOnlyIsWeak) {
  ChannelEvidence e = clean();
  e.brightness_ratio = 1.5;  // the brightness ratio disagrees with EXIF and with the fit, even for the most convex curve
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::weak) << v.summary();
  EXPECT_TRUE(mentions(v, "one source is off")) << v.summary();
  // Inside the factor 1.5: ok.
  e.brightness_ratio = 3.0;
  EXPECT_EQ(judgeOne(e).level, VerdictLevel::ok);
  // Measured with the mean curve, a convex camera's ratio comes out as r^(1/k), k up to 1.6: 8^(1/1.6) = 3.7.
  e.nominal_ratio = e.ratio = 8;
  e.brightness_ratio = 3.7;
  EXPECT_EQ(judgeOne(e).level, VerdictLevel::ok) << judgeOne(e).summary();
  // but not the other way: a brightness ratio above r by more than the factor.
  e.brightness_ratio = 13;
  EXPECT_EQ(judgeOne(e).level, VerdictLevel::weak) << judgeOne(e).summary();
}

TEST(ChannelVerdict, FixedRatioContradictedByTheFlatRegionsIsUnreliable) {
  ChannelEvidence e = clean();
  e.ratio_fixed = true;
  e.brightness_ratio = 1.05;
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::unreliable) << v.summary();
  EXPECT_TRUE(mentions(v, "contradicts")) << v.summary();
}

TEST(ChannelVerdict, RatioOnTheWrongSideOfOneIsUnreliable) {
  ChannelEvidence e = clean();
  e.brightness_ratio = 0;  // not measured
  e.nominal_ratio = 1.3;
  e.ratio = 0.9;  // inside the factor 1.5 of EXIF, but the blurred shot would be darker
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::unreliable) << v.summary();
  EXPECT_TRUE(mentions(v, "physically impossible")) << v.summary();
  // Near 1 EXIF's tolerance leaves either side possible.
  e.nominal_ratio = 1.05;
  EXPECT_EQ(judgeOne(e).level, VerdictLevel::ok) << judgeOne(e).summary();
}

TEST(ChannelVerdict, RatioHeldBecauseTheBlurIsSmallIsWeak) {
  ChannelEvidence e = clean();
  e.ratio_held_small_blur = true;
  e.ratio_images_small_blur = 1.51;
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::weak) << v.summary();
  EXPECT_TRUE(mentions(v, "1.51")) << v.summary();
}

TEST(ChannelVerdict, ChannelsWhoseRatioLeavesTheBandAreFlagged) {
  const auto verdicts = judgeChannels({clean("R", 4.0), clean("G", 4.05), clean("B", 4.6)}, {});
  EXPECT_EQ(verdicts.at("G").level, VerdictLevel::ok) << verdicts.at("G").summary();
  EXPECT_EQ(verdicts.at("R").level, VerdictLevel::ok) << verdicts.at("R").summary();
  EXPECT_EQ(verdicts.at("B").level, VerdictLevel::weak) << verdicts.at("B").summary();
  EXPECT_TRUE(mentions(verdicts.at("B"), "median r")) << verdicts.at("B").summary();
  // Within 10 %: nobody flagged.
  const auto close = judgeChannels({clean("R", 4.0), clean("G", 4.1), clean("B", 4.3)}, {});
  for (const auto& [name, v] : close) EXPECT_EQ(v.level, VerdictLevel::ok) << name << ": " << v.summary();
}

TEST(ChannelVerdict, NarrowCoveredRangeIsWeak) {
  ChannelEvidence e = clean();
  e.covered = std::make_pair(0.01, 0.47);
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::weak) << v.summary();
  EXPECT_TRUE(mentions(v, "0.01-0.47")) << v.summary();
}

TEST(ChannelVerdict, ColourChannelFromSubsampledSharpChromaIsWeak) {
  ChannelEvidence e = clean("B");
  e.pointwise_from_subsampled_chroma = "4:2:0";
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::weak) << v.summary();
  EXPECT_TRUE(mentions(v, "4:2:0")) << v.summary();
}

// The chroma check (docs/RESULTS.md#chroma-now): a pointwise B whose fit where the sharp shot's chroma is flat has the
// same shape was not biased by the subsampling; one that differs by more than the shape target and lies above it (the
// sign of the lost chroma's bias) was; one that lies below moved against that sign.
TEST(ChannelVerdict, SubsampledChromaIsWeakOnlyWhenTheFlatChromaFitDiffersInShapeAndLiesAbove) {
  ChannelEvidence e = clean("B");
  e.pointwise_from_subsampled_chroma = "4:2:0";
  e.chroma_check_shape_difference = 0.004;
  e.chroma_check_pixels_left_out = 500;
  const ChannelVerdict agreeing = judgeOne(e);
  EXPECT_EQ(agreeing.level, VerdictLevel::ok) << agreeing.summary();
  EXPECT_TRUE(mentions(agreeing, "same shape (RMSE 0.0040")) << agreeing.summary();
  e.chroma_check_shape_difference = 0.03;
  const ChannelVerdict differing = judgeOne(e);
  EXPECT_EQ(differing.level, VerdictLevel::weak) << differing.summary();
  EXPECT_TRUE(mentions(differing, "without the 500 pixels")) << differing.summary();
  EXPECT_TRUE(mentions(differing, "differs in shape by 0.0300")) << differing.summary();
  e.chroma_check_scale = 1.2;  // the flat-chroma fit lies above: the sign of the lost chroma's bias
  const ChannelVerdict above = judgeOne(e);
  EXPECT_EQ(above.level, VerdictLevel::weak) << above.summary();
  EXPECT_TRUE(mentions(above, "lies above it (scale 1.200)")) << above.summary();
  e.chroma_check_not_replaced = "that fit does not fix the curve's exponent by itself";
  EXPECT_TRUE(mentions(judgeOne(e), "(scale 1.200), as the lost chroma's bias predicts; that fit does not fix"));
  e.chroma_check_not_replaced.clear();
  e.chroma_check_scale = 0.9;  // below: against that sign, the thinner fit's own noise
  const ChannelVerdict below = judgeOne(e);
  EXPECT_EQ(below.level, VerdictLevel::ok) << below.summary();
  EXPECT_TRUE(mentions(below, "lies below it (scale 0.900 <= 1)")) << below.summary();
  // Replaced by the flat-chroma fit (the pair stage's decision): no longer pointwise, a note says why.
  ChannelEvidence replaced = clean("B");
  replaced.chroma_check_replaced = true;
  replaced.chroma_check_shape_difference = 0.03;
  replaced.chroma_check_scale = 1.2;
  const ChannelVerdict flat = judgeOne(replaced);
  EXPECT_EQ(flat.level, VerdictLevel::ok) << flat.summary();
  EXPECT_TRUE(mentions(flat, "fitted where the sharp shot's subsampled chroma is flat: the pointwise fit differed "
                             "from this one in shape by 0.0300"))
      << flat.summary();
  e.chroma_check_scale = 0;
  e.chroma_check_shape_difference = 0;  // nothing left out: the same fit
  e.chroma_check_pixels_left_out = 0;
  const ChannelVerdict nothing = judgeOne(e);
  EXPECT_EQ(nothing.level, VerdictLevel::ok) << nothing.summary();
  EXPECT_TRUE(mentions(nothing, "nothing for the pointwise model to miss")) << nothing.summary();
  e.chroma_check_shape_difference = -1;  // the check's fit failed: not measured, the sampling alone decides
  EXPECT_EQ(judgeOne(e).level, VerdictLevel::weak);
  VerdictOptions loose;
  loose.max_chroma_shape_difference = 0.05;
  e.chroma_check_shape_difference = 0.03;
  EXPECT_EQ(judgeChannels({e}, {}, loose).at("B").level, VerdictLevel::ok);
  loose.max_chroma_shape_difference = 0;
  EXPECT_THROW(loose.check(), InvalidInput);
}

TEST(ChannelVerdict, FlatCurveOverPartOfTheCoveredRangeIsUnreliable) {
  ChannelEvidence e = clean();
  // φ = 0 up to x = 0.75, then rising (the held-out phone pair of issue 17).
  for (int i = 0; i < 1024; ++i) {
    const double x = i / 1023.0;
    e.inverse_crf[i] = x <= 0.75 ? 0.0 : (x - 0.75) / 0.25;
  }
  const ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::unreliable) << v.summary();
  EXPECT_TRUE(mentions(v, "nearly constant")) << v.summary();
  EXPECT_NEAR(flatFraction(e.inverse_crf, {0.05, 0.9}), (0.75 - 0.05) / 0.85, 0.05);
  EXPECT_EQ(flatFraction(gammaCurve(2.2), {0.05, 0.9}), 0.0);
  EXPECT_EQ(flatFraction(gammaCurve(2.2), {0.0, 1.0}), 0.0);
  EXPECT_EQ(flatFraction(gammaCurve(3.0), {0.05, 1.0}), 0.0);  // more convex than any measured camera, still rising
  // A steep power law: near 0 over data that stop at 0.47, all its rise above them (a real phone pair's R).
  EXPECT_GT(flatFraction(gammaCurve(12.0), {0.02, 0.46}), 0.5);
}

TEST(ChannelVerdict, RefitOutcomeIsReportedAsANote) {
  RefitEvidence adopted{true, true, "", 2e-4, 1.5e-4};
  const ChannelVerdict a = judgeOne(clean(), adopted);
  EXPECT_EQ(a.level, VerdictLevel::ok);
  EXPECT_TRUE(mentions(a, "refit is reported")) << a.summary();
  RefitEvidence rejected{true, false, "its phi explains the held-back pixels worse than the base fit", 1e-4, 2e-4};
  const ChannelVerdict r = judgeOne(clean(), rejected);
  EXPECT_EQ(r.level, VerdictLevel::ok);
  EXPECT_TRUE(mentions(r, "base fit is reported")) << r.summary();
}

TEST(ChannelVerdict, WideShapeBandIsWeakAndANarrowOneIsReported) {
  ChannelEvidence e = clean();
  e.shape_band_sigma = 0.004;  // inside issue 17's 0.01
  ChannelVerdict v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::ok) << v.summary();
  EXPECT_TRUE(mentions(v, "shape band sigma 0.004")) << v.summary();
  e.shape_band_sigma = 0.025;
  v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::weak) << v.summary();
  EXPECT_TRUE(mentions(v, "median sigma 0.025")) << v.summary();
  e.shape_band_sigma = -1;  // no band: no ground, no mention
  v = judgeOne(e);
  EXPECT_EQ(v.level, VerdictLevel::ok) << v.summary();
  EXPECT_FALSE(mentions(v, "band")) << v.summary();
}

TEST(ChannelVerdict, WorstLevelAndOptionChecks) {
  ChannelEvidence bad = clean("B");
  bad.ratio = 0.5;
  const auto verdicts = judgeChannels({clean("G"), bad}, {});
  EXPECT_EQ(worstLevel(verdicts), VerdictLevel::unreliable);
  EXPECT_STREQ(toString(VerdictLevel::weak), "weak");
  VerdictOptions o;
  o.max_ratio_factor = 1.0;
  EXPECT_THROW(o.check(), InvalidInput);
  o = {};
  o.max_flat_fraction = 0;
  EXPECT_THROW(o.check(), InvalidInput);
  o = {};
  o.max_shape_sigma = 0;
  EXPECT_THROW(o.check(), InvalidInput);
}

}  // namespace
}  // namespace crfcal
