// Saturated pixels of B as censored observations (CrfFitOptions::censored_weight, calib/src/crf_censored.*;
// issue 19): at r > 1 the clip of the normally exposed blurred shot ties φ near 1 to φ at the sharp shot's levels.
#include <cmath>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/error.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A camera-like inverse response with a strong shoulder: φ(x) = (x² + 3x¹²) / 4. Its local exponent rises from 2 to
// 9.5 at x = 1, so a fit whose data stop below the shoulder extrapolates the scale of the whole curve.
TableModel shoulderCurve() {
  std::vector<double> table(1024);
  for (int i = 0; i < 1024; ++i) {
    const double x = i / 1023.0;
    table[i] = 0.25 * (x * x + 3 * std::pow(x, 12));
  }
  return TableModel{table};
}

double rmseOverUnit(const std::vector<double>& fit, const ResponseModel& truth) {
  const std::vector<double> t = sampleInverse(truth);
  double s = 0;
  for (std::size_t i = 0; i < t.size(); ++i) s += (fit[i] - t[i]) * (fit[i] - t[i]);
  return std::sqrt(s / t.size());
}

struct Pair {
  cv::Mat sharp, blurred, kernel;
};

// The real regime at r = 4: the long blurred shot normally exposed, clipped on bright discs whose irradiance is
// 1.3–2.2 × its clip; the short sharp shot sees a quarter of the light (the discs at 0.33–0.55, inside its range),
// with a little noise. With bright = false the discs are dimmed below B's clip: nothing clips.
Pair realRegimePair(bool bright) {
  const double ratio = 4;
  const cv::Mat texture = test::levinImage(2);
  cv::Mat scene = 0.02 + 0.1 * texture;  // irradiance the blurred shot sees (B below 0.66)
  const double levels[] = {1.3, 1.6, 1.9, 2.2};
  for (int i = 0; i < 4; ++i) {
    const cv::Point centre(50 + 50 * i, 60 + 40 * (i % 2) + 60 * (i / 2));
    cv::circle(scene, centre, 16, cv::Scalar(bright ? levels[i] : 0.3 + 0.1 * i), cv::FILLED, cv::LINE_AA);
  }
  Pair pair;
  pair.kernel = test::levinKernel(3);
  const ResponseCurve curve(shoulderCurve());
  cv::Mat sharp_irr = scene / ratio;
  cv::Mat noise(scene.size(), CV_64F);
  cv::RNG rng(5);
  rng.fill(noise, cv::RNG::NORMAL, 0, 0.002);
  sharp_irr += noise;
  cv::Mat blurred_irr = convolve(scene, pair.kernel);
  curve.forward(cv::max(cv::min(sharp_irr, 1.0), 0.0)).convertTo(pair.sharp, CV_8U, 255.0);
  curve.forward(cv::max(cv::min(blurred_irr, 1.0), 0.0)).convertTo(pair.blurred, CV_8U, 255.0);
  return pair;
}

CrfFitOptions options(double censored_weight) {
  CrfFitOptions o;
  o.nominal_ratio = 4;
  o.censored_weight = censored_weight;
  o.fit_ratio = false;
  return o;
}

// r held at the truth. Without the term the fit's φ is too high on the data (its shoulder too flat): e0 ≈ 0.040. The
// clipped pixels bound φ(1) from above relative to φ at I's levels, i.e. they forbid the opposite error (a shoulder
// too steep), so here they must be used (the rim of the discs) and must not make φ worse. Measured during
// development: the two-sided version (also the unclipped pixels next to a clip, z < φ(s)) brought this pair to
// 0.004, but on the r = 4 bench it pulled r down by up to 8 % (resampled, JPEG-ringing B next to clips), so only
// the clipped side is used (docs/RESULTS.md#censored).
TEST(CrfCensored, ClippedRimIsUsedAndDoesNotWorsenTheScale) {
  const Pair pair = realRegimePair(true);
  ASSERT_GT(cv::countNonZero(pair.blurred >= 255), 1000);
  ASSERT_EQ(cv::countNonZero(pair.sharp >= 255), 0);  // the sharp shot's highlights are inside its range
  const CrfFitResult without = fitInverseCrf(pair.sharp, pair.blurred, pair.kernel, options(0));
  const CrfFitResult with = fitInverseCrf(pair.sharp, pair.blurred, pair.kernel, options(1));
  EXPECT_EQ(without.pixels.censored_clipped, 0);
  EXPECT_GT(with.pixels.censored_clipped, 500) << with.summary();
  const double e0 = rmseOverUnit(without.inverse_crf, shoulderCurve());
  const double e1 = rmseOverUnit(with.inverse_crf, shoulderCurve());
  EXPECT_GT(e0, 0.03) << without.summary();  // the scale is extrapolated wrong without the term
  EXPECT_LE(e1, e0 + 0.002) << with.summary();
}

TEST(CrfCensored, InactiveWithoutClippedPixels) {
  const Pair pair = realRegimePair(false);
  ASSERT_EQ(cv::countNonZero(pair.blurred >= 255), 0);
  const CrfFitResult without = fitInverseCrf(pair.sharp, pair.blurred, pair.kernel, options(0));
  const CrfFitResult with = fitInverseCrf(pair.sharp, pair.blurred, pair.kernel, options(1));
  EXPECT_EQ(with.pixels.censored_clipped, 0);
  EXPECT_EQ(with.inverse_crf, without.inverse_crf);
  EXPECT_EQ(with.ratio, without.ratio);
}

TEST(CrfCensored, OptionsAreChecked) {
  CrfFitOptions o;
  o.censored_weight = -1;
  EXPECT_THROW(o.check(), InvalidInput);
  o = CrfFitOptions{};
  o.censored_sigma_floor = 0;
  EXPECT_THROW(o.check(), InvalidInput);
  o = CrfFitOptions{};
  o.max_censored_pixels = -1;
  EXPECT_THROW(o.check(), InvalidInput);
}

}  // namespace
}  // namespace crfcal
