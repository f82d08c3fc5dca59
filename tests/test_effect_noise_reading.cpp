// How the effect search reads the sharp shot's noise (calib/src/effect_problem.cpp, readChannels): as the base fit it
// tests does — I's level functions debiased only when the fit debiases (NoiseHandling::debias), a noisy I's black and
// white read by region either way (docs/RESULTS.md#effects-debias).
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "../calib/src/effect_problem.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/effect_planting.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/io/response_io.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A clean pair with the seed's intensity noise on I (2.6 levels), its green base fit under `noise`, read by the search.
struct NoiseReading {
  EffectInputs in;
  EffectOptions options;
  explicit NoiseReading(NoiseHandling noise) {
    cv::Mat a, b, photo;
    test::levinImage(1).convertTo(a, CV_8U, 255.0);
    test::levinImage(2).convertTo(b, CV_8U, 255.0);
    cv::hconcat(a, b, photo);
    const ResponseModel truth =
        TableModel{io::readCurveTable(test::samples() / "camera_curves" / "CanonPowerShotG9.csv")};
    const cv::Mat K = test::levinKernel(1);
    PlantingOptions po;
    po.ratio = 1.25;
    po.seed = 7;
    const PlantedPair pair = plantEffect(photo, truth, K, po);
    CrfFitOptions fo;
    fo.nominal_ratio = pair.exif_ratio;
    fo.experimental.noise = noise;
    in = test::greenEffectInputs(pair.sharp, pair.blurred, K, fo);
  }
};

TEST(EffectNoiseReading, SharpShotIsDebiasedOnlyWhenTheBaseFitDebiases) {
  for (const NoiseHandling noise : {NoiseHandling::none, NoiseHandling::debias}) {
    const NoiseReading reading(noise);
    effect::EffectSearch search(reading.in, reading.options);
    ASSERT_TRUE(effect::prepareProblem(search));
    ASSERT_EQ(search.p.noisy.size(), 1u);
    EXPECT_TRUE(search.p.noisy[0]) << "2.6 levels of noise: the black and white are read by region";
    EXPECT_EQ(search.p.debias[0].identity(), noise != NoiseHandling::debias) << toString(noise);
  }
}

}  // namespace
}  // namespace crfcal
