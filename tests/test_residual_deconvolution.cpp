// Residual deconvolution with the pair's sharp shot (calib/include/crfcal/residual_deconvolution.hpp) and
// `crfcal deblur --sharp`.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <sstream>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/deconvolution.hpp"
#include "crfcal/error.hpp"
#include "crfcal/handheld_simulation.hpp"
#include "crfcal/reference_comparison.hpp"
#include "crfcal/residual_deconvolution.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A 112×112 crop of Levin im1, blurred in irradiance by levin kernel 3 under gamma 2.2 (8-bit), and its sharp shot
// underexposed by r = 4 with a phone's ISO-400 raw noise (LGE Nexus 5, darktable: variance = a·x + b).
struct SyntheticPair {
  cv::Mat scene, blurred, sharp_shot, kernel;
};

SyntheticPair syntheticPair() {
  SyntheticPair pair;
  pair.scene = test::levinImage(1)(cv::Rect(70, 70, 112, 112)).clone();
  pair.kernel = test::levinKernel(3);
  pair.blurred = quantize(irradianceBlur(pair.scene, ResponseCurve(GammaModel{2.2}), pair.kernel), 8);
  pair.sharp_shot = underexposedSharpShot(pair.scene, GammaModel{2.2}, 4.0, PoissonGaussian{5.4e-5, 2.9e-7}, 7);
  return pair;
}

TEST(ResidualDeconvolution, BeatsBlindTvOnSyntheticPairWithKnownKernel) {
  const SyntheticPair pair = syntheticPair();
  const ResponseCurve curve(GammaModel{2.2});
  const DeconvolutionResult blind = deconvolve(pair.blurred, pair.kernel, {curve});
  const ResidualDeconvolutionResult residual =
      deconvolveResidual(pair.blurred, pair.sharp_shot, cv::Mat(), pair.kernel, {curve});
  const double blind_psnr = psnr(blind.deblurred, pair.scene), residual_psnr = psnr(residual.deblurred, pair.scene);
  const double prior_psnr = psnr(residual.sharp_denoised, pair.scene);
  std::printf("blind TV %.2f dB, denoised sharp shot %.2f dB, residual %.2f dB (%s)\n", blind_psnr, prior_psnr,
              residual_psnr, residual.summary().c_str());
  EXPECT_GT(residual_psnr, blind_psnr + 1.0);
  EXPECT_GT(residual_psnr, prior_psnr);  // the residual's deconvolution adds what the denoised shot lacks
}

TEST(ResidualDeconvolution, FitsTheExposureRatioOfThePair) {
  const SyntheticPair pair = syntheticPair();
  const ResidualDeconvolutionResult residual =
      deconvolveResidual(pair.blurred, pair.sharp_shot, cv::Mat(), pair.kernel, {ResponseCurve(GammaModel{2.2})});
  ASSERT_EQ(residual.ratio.size(), 1u);
  EXPECT_NEAR(residual.ratio[0], 4.0, 0.2);
  EXPECT_GT(residual.noise_sigma[0], 0.0);
}

TEST(ResidualDeconvolution, RejectsSharpShotOfOtherSizeAsTheSharpImagesFault) {
  const SyntheticPair pair = syntheticPair();
  const cv::Mat smaller = pair.sharp_shot(cv::Rect(0, 0, 100, 112)).clone();
  try {
    deconvolveResidual(pair.blurred, smaller, cv::Mat(), pair.kernel, {ResponseCurve(GammaModel{2.2})});
    FAIL() << "a sharp shot of another size was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_EQ(e.subject(), ErrorSubject::sharp_image) << e.what();
  }
  ResidualDeconvolutionOptions options;
  options.template_window = 4;
  EXPECT_THROW(options.check(), InvalidInput);
}

using test::quote;

int lineCount(const std::string& text) {
  return static_cast<int>(std::count(text.begin(), text.end(), '\n')) + (!text.empty() && text.back() != '\n');
}

TEST(DeblurCli, SharpShotGivesResidualResultAndRejectsWrongSizeNamingTheFile) {
  test::TempDir dir;
  const SyntheticPair pair = syntheticPair();
  cv::Mat blurred8;
  pair.blurred.convertTo(blurred8, CV_8U, 255.0);
  cv::imwrite((dir / "blurred.png").string(), blurred8);
  cv::imwrite((dir / "sharp.png").string(), pair.sharp_shot);
  cv::imwrite((dir / "small.png").string(), pair.sharp_shot(cv::Rect(0, 0, 100, 112)));
  const std::string command = quote(test::crfcalBinary()) + " deblur " + quote(dir / "blurred.png") + " --kernel " +
                              quote(test::samples() / "levin09" / "kernel03.txt") + " --crf gamma:2.2 --registered --sharp ";

  const auto wrong = test::run(command + quote(dir / "small.png") + " -o " + quote(dir / "bad"));
  EXPECT_EQ(wrong.exit_code, 1) << wrong.output;
  EXPECT_EQ(lineCount(wrong.output), 1) << wrong.output;
  EXPECT_NE(wrong.output.find("small.png"), std::string::npos) << wrong.output;
  EXPECT_FALSE(std::filesystem::exists(dir / "bad"));

  const auto ok = test::run(command + quote(dir / "sharp.png") + " -o " + quote(dir / "out"));
  ASSERT_EQ(ok.exit_code, 0) << ok.output;
  const auto unit = [&](const char* name) {
    cv::Mat image = cv::imread((dir / "out" / name).string(), cv::IMREAD_UNCHANGED), converted;
    EXPECT_FALSE(image.empty()) << name;
    image.convertTo(converted, CV_64F, 1.0 / 65535);
    return converted;
  };
  EXPECT_GT(psnr(unit("deblurred.png"), pair.scene), psnr(unit("deblurred_blind.png"), pair.scene) + 1.0);
  EXPECT_TRUE(std::filesystem::exists(dir / "out" / "side_by_side.png"));
}

}  // namespace
}  // namespace crfcal

namespace crfcal {
namespace {

TEST(ReferenceComparison, MonotoneBrightnessMatchUndoesAToneCurveOfTheReference) {
  const cv::Mat target = test::levinImage(2)(cv::Rect(0, 0, 96, 96)).clone();
  cv::Mat brighter;
  cv::pow(target, 0.5, brighter);  // the reference: the same scene through another, brighter tone curve
  const cv::Mat mask(target.size(), CV_8U, cv::Scalar(255));
  const cv::Mat matched = matchBrightness(brighter, target, mask);
  EXPECT_GT(scoreAgainstReference(target, matched, mask).psnr, 40.0);
  EXPECT_LT(scoreAgainstReference(target, brighter, mask).psnr, 20.0);
}

}  // namespace
}  // namespace crfcal
