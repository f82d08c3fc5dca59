// The dual-image CRF fitter (seed Sec. 4): level mixtures, noise estimation/debiasing, recovery of φ and r,
// saturation handling, validity and rejection of unusable pairs.
#include <algorithm>
#include <cmath>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_debias.hpp"
#include "crfcal/noise_estimation.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

cv::Mat randomImage(cv::Size size, unsigned seed) {
  cv::Mat image(size, CV_8U);
  cv::RNG rng(seed);
  rng.fill(image, cv::RNG::UNIFORM, 0, 256);
  return image;
}

TEST(LevelMixture, EqualsDirectConvolution) {
  const cv::Mat image = randomImage({64, 48}, 3);
  const cv::Mat kernel = test::levinKernel(4);
  const LevelImage levels = toLevels(image, 256);
  const cv::Rect inside = interiorRect(image.size(), kernel);
  std::vector<cv::Point> pixels;
  for (int y = inside.y; y < inside.y + inside.height; y += 3)
    for (int x = inside.x; x < inside.x + inside.width; x += 2) pixels.emplace_back(x, y);
  const LevelMixture mixture = LevelMixture::build(levels, kernel, pixels);
  const ResponseCurve curve(GammaModel{2.2});
  const std::vector<double>& lut = curve.inverseLut(8);
  std::vector<double> mixed(pixels.size());
  mixture.mix(lut, mixed);
  const cv::Mat direct = convolve(curve.inverse(image), kernel);
  for (std::size_t i = 0; i < pixels.size(); ++i) EXPECT_NEAR(mixed[i], direct.at<double>(pixels[i]), 1e-12);
}

TEST(LevelMixture, RejectsPixelsAtTheBorder) {
  const cv::Mat image = randomImage({40, 40}, 4);
  const std::vector<cv::Point> pixels{{0, 0}};
  EXPECT_THROW(LevelMixture::build(toLevels(image, 256), test::levinKernel(1), pixels), InvalidInput);
}

TEST(NoiseEstimation, RecoversSigmaOfGaussianNoise) {
  const cv::Mat clean = test::levinImage(1);
  for (double sigma : {0.03, 0.07}) {
    const cv::Mat noisy = quantize(addGaussianNoise(clean, sigma * sigma, 7), 8);
    const NoiseEstimate estimate = estimateNoiseSigma(noisy);
    EXPECT_NEAR(estimate.sigma, sigma, 0.15 * sigma) << sigma;
    EXPECT_GT(estimate.samples, 1000);
  }
}

TEST(NoiseEstimation, HalfResolutionRecoversWhiteNoiseAndSeesLowPassedNoise) {
  cv::Mat image(240, 320, CV_64F), noise(240, 320, CV_64F);
  for (int y = 0; y < image.rows; ++y)
    for (int x = 0; x < image.cols; ++x) image.at<double>(y, x) = 0.3 + 0.4 * x / image.cols;
  cv::RNG rng(3);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 0.01);
  EXPECT_NEAR(estimateNoiseSigmaAtHalfResolution(image + noise).sigma, 0.01, 0.0015);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 1.0);  // the finest scale removed, as a JPEG does
  const double full = estimateNoiseSigma(image + noise).sigma, half = estimateNoiseSigmaAtHalfResolution(image + noise).sigma;
  EXPECT_GT(half, 2 * full);
  EXPECT_THROW(estimateNoiseSigmaAtHalfResolution(cv::Mat(16, 16, CV_64F, cv::Scalar(0.5))), InvalidInput);
}

TEST(NoiseDebias, ExpectationOfDebiasedFunctionIsTheCleanFunction) {
  const double sigma = 0.07;
  NoiseDebiasOptions options;
  options.sigma = sigma;
  const NoiseDebias debias(options);
  std::vector<double> f(256);
  for (int v = 0; v < 256; ++v) f[v] = std::pow(v / 255.0, 2.2);
  const std::vector<double> g = debias.apply(f);
  double worst_plain = 0, worst_debiased = 0;
  for (int c = 0; c < 256; ++c) {
    double plain = 0, debiased = 0;
    for (int v = 0; v < 256; ++v) {
      plain += debias.transition()(c, v) * f[v];
      debiased += debias.transition()(c, v) * g[v];
    }
    worst_plain = std::max(worst_plain, std::abs(plain - f[c]));
    worst_debiased = std::max(worst_debiased, std::abs(debiased - f[c]));
  }
  EXPECT_GT(worst_plain, 5e-3);
  EXPECT_LT(worst_debiased, 0.2 * worst_plain);
}

const GgcmModel kTrueGgcm{{0.42, 0.15, -0.08, 0.05, 0.02}};

TEST(CrfFit, RecoversExactGgcmFromNoiseFreeData) {
  ASSERT_TRUE(checkValidity(kTrueGgcm));
  SimulationOptions sim;
  sim.bits = 16;  // noise-free: no 8-bit quantisation floor either
  const SimulationResult pair = simulatePair(test::levinImage(2), kTrueGgcm, test::levinKernel(3), sim);
  CrfFitOptions options;
  options.model = CrfModelChoice::ggcm;
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), options);
  EXPECT_LE(curveRmse(fit.model, kTrueGgcm), 1e-3) << fit.summary();
  EXPECT_TRUE(checkValidity(fit.model));
  EXPECT_EQ(fit.inverse_crf.size(), 1024u);
  EXPECT_NEAR(fit.ratio, 1.0, 0.01);
}

// CrfFitOptions::start (the curve band's half-sample refits): a fit started from the whole pair's fit alone ends
// where the usual multi-start fit ends, on the whole pair and on a half of it; a start of the other model's kind
// is ignored (that model keeps its usual starts).
TEST(CrfFit, StartFromAFitReachesTheMultiStartOptimum) {
  SimulationOptions sim;
  sim.noise_variance = 0.0002;
  sim.ratio = 1.5;
  const SimulationResult pair = simulatePair(test::levinImage(2), kTrueGgcm, test::levinKernel(3), sim);
  CrfFitOptions options;
  options.model = CrfModelChoice::ggcm;
  options.nominal_ratio = 1.5;
  const CrfFitResult whole = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), options);
  ASSERT_EQ(whole.chosen, "ggcm");
  cv::Mat half = cv::Mat::zeros(pair.sharp.size(), CV_8U);
  half(cv::Rect(0, 0, half.cols / 2, half.rows)).setTo(255);
  for (const cv::Mat& selection : {cv::Mat(), half}) {
    CrfFitOptions usual = options;
    usual.pixel_selection = selection;
    CrfFitOptions started = usual;
    started.start = CrfFitOptions::Start{whole.model, whole.ratio};
    const CrfFitResult a = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), usual);
    const CrfFitResult b = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), started);
    EXPECT_LT(curveRmse(a.model, b.model), 1e-4) << a.summary() << "\n" << b.summary();
    EXPECT_NEAR(a.ratio, b.ratio, 1e-3 * a.ratio);
    EXPECT_LT(b.evaluations, a.evaluations);  // fewer LM runs
  }
  CrfFitOptions other_kind = options;
  other_kind.start = CrfFitOptions::Start{EmorModel{std::vector<double>(options.emor_terms, 0.0)}, 1.5};
  const CrfFitResult c = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), other_kind);
  EXPECT_EQ(c.evaluations, whole.evaluations);
  EXPECT_EQ(c.inverse_crf, whole.inverse_crf);
  CrfFitOptions bad = options;
  bad.start = CrfFitOptions::Start{whole.model, 0.0};
  EXPECT_THROW(bad.check(), InvalidInput);
}

TEST(CrfFit, SeedMethodRecoversNoiseFreeGgcm) {
  const SimulationResult pair = simulatePair(test::levinImage(2), kTrueGgcm, test::levinKernel(3));
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), CrfFitOptions::seed());
  EXPECT_LE(curveRmse(fit.model, kTrueGgcm), 1e-2) << fit.summary();
  EXPECT_EQ(fit.chosen, "ggcm");
}

TEST(CrfFit, RecoversRatioFromInitialValueOffBy20Percent) {
  SimulationOptions sim;
  sim.ratio = 0.8;
  sim.bits = 16;
  const SimulationResult pair = simulatePair(test::levinImage(3), GammaModel{2.2}, test::levinKernel(2), sim);
  CrfFitOptions options;
  options.nominal_ratio = 0.96;  // 20 % off
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(2), options);
  EXPECT_NEAR(fit.ratio, 0.8, 0.008) << fit.summary();
  EXPECT_DOUBLE_EQ(fit.nominal_ratio, 0.96);
  EXPECT_LT(curveRmse(fit.model, GammaModel{2.2}), 5e-3) << fit.summary();
}

TEST(CrfFit, SaturatedPixelsNeverEnterTheEnergy) {
  cv::Mat latent = test::levinImage(1).clone();
  latent(cv::Rect(100, 100, 60, 60)).setTo(1.0);  // a saturated patch in both images
  const cv::Mat kernel = test::levinKernel(1);
  const SimulationResult pair = simulatePair(latent, GammaModel{2.2}, kernel);
  for (const CrfFitOptions& options : {CrfFitOptions{}, CrfFitOptions::seed()}) {
    const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, kernel, options);
    EXPECT_GT(fit.pixels.saturated, 3600);
    cv::Mat saturated = (pair.sharp >= 254.5 / 255) | (pair.blurred >= 254.5 / 255);
    cv::dilate(saturated, saturated, cv::getStructuringElement(cv::MORPH_RECT, kernel.size()));
    EXPECT_EQ(cv::countNonZero(saturated & fit.pixels.used_mask), 0);
    EXPECT_EQ(fit.pixels.used, cv::countNonZero(fit.pixels.used_mask));
    EXPECT_EQ(fit.pixels.total, fit.pixels.used + fit.pixels.border + fit.pixels.saturated + fit.pixels.low_weight +
                                    fit.pixels.subsampled);
  }
}

// A black pixel of a noisy I whose neighbourhood is not black is noise that reached black: it hides at most φ of the
// noise's reach above black, so it stays data, and its neighbours with it; only regions whose local median is black
// are censored. A clean I's black pixels are clipped signal: each one's support is dropped.
TEST(CrfFit, BlackPixelsDropTheirSupportInACleanSharpShotAndOnlyBlackRegionsDoInANoisyOne) {
  cv::Mat latent = 0.05 + 0.9 * test::levinImage(2);
  latent(cv::Rect(60, 60, 40, 40)).setTo(0.0);  // a black region: its support is censored either way
  const cv::Mat kernel = test::levinKernel(1);
  const SimulationResult pair = simulatePair(latent, GammaModel{2.2}, kernel);
  cv::Mat dotted_sharp = pair.sharp.clone();
  int dots = 0;
  for (int y = 130; y < dotted_sharp.rows - 20; y += 9)
    for (int x = 20; x < dotted_sharp.cols - 20; x += 9, ++dots) dotted_sharp.at<double>(y, x) = 0.0;
  ASSERT_GT(dots, 100);
  cv::Mat black_support = cv::Mat::zeros(latent.size(), CV_8U);
  black_support(cv::Rect(62, 62, 36, 36)).setTo(255);  // where the 5×5 median is black
  cv::dilate(black_support, black_support, cv::getStructuringElement(cv::MORPH_RECT, kernel.size()));
  CrfFitOptions options;
  for (const double sigma : {0.0, 2.0 / 255}) {  // given: a clean I, then a noisy one (more than one level)
    options.noise_sigma = sigma;
    const CrfFitResult plain = fitInverseCrf(pair.sharp, pair.blurred, kernel, options);
    const CrfFitResult dotted = fitInverseCrf(dotted_sharp, pair.blurred, kernel, options);
    EXPECT_EQ(cv::countNonZero(black_support & dotted.pixels.used_mask), 0) << "sigma " << sigma;
    EXPECT_GT(plain.pixels.saturated, 40 * 40);
    if (sigma == 0) EXPECT_GT(dotted.pixels.saturated, plain.pixels.saturated + dots * 10) << dotted.summary();
    else EXPECT_EQ(dotted.pixels.saturated, plain.pixels.saturated) << plain.summary() << "\n" << dotted.summary();
  }
}

// The real regime's sharp shot after a JPEG: its noise reaches black, but the quantisation removed the high
// frequencies the full-resolution estimate reads (emulated: noise low-passed by a 1 px Gaussian). The half-resolution
// estimate still sees it, so the black pixels it makes stay data; the ablation (the rule before stop 37) drops their
// supports, the dark side of the edges.
TEST(CrfFit, NoiseHiddenFromTheFullResolutionEstimateStillKeepsItsBlackPixelsInTheFit) {
  const cv::Mat kernel = test::levinKernel(3);
  cv::Mat latent;
  cv::pow(test::levinImage(3), 2.0, latent);  // dark regions near black
  SimulationOptions sim;
  sim.ratio = 8;
  sim.bits = 16;
  const SimulationResult pair = simulatePair(latent * (1.0 / 8), GammaModel{2.2}, kernel, sim);
  cv::Mat noise(latent.size(), CV_64F);
  cv::RNG rng(7);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(noise, noise, cv::Size(0, 0), 1.0);
  cv::Scalar mean, stddev;
  cv::meanStdDev(noise, mean, stddev);
  cv::Mat sharp = pair.sharp_clean + noise * (3.0 / 255 / stddev[0]), blurred;
  sharp.convertTo(sharp, CV_8U, 255.0);  // clipped at black and rounded, as a camera stores it
  pair.blurred.convertTo(blurred, CV_8U, 255.0);
  ASSERT_GT(cv::countNonZero(sharp == 0), 100);
  const double full = estimateNoiseSigma(sharp).sigma, half = estimateNoiseSigmaAtHalfResolution(sharp).sigma;
  EXPECT_LT(full * 255, 1.0);
  EXPECT_GT(half * 255, 1.0);
  CrfFitOptions options;
  options.nominal_ratio = 8;
  const CrfFitResult fit = fitInverseCrf(sharp, blurred, kernel, options);
  options.experimental.black_per_pixel_when_clean = true;
  const CrfFitResult ablation = fitInverseCrf(sharp, blurred, kernel, options);
  EXPECT_LT(fit.noise_sigma * 255, 1.0);
  EXPECT_GT(ablation.pixels.saturated, 4 * std::max(fit.pixels.saturated, 1000)) << fit.summary() << "\n" << ablation.summary();
}

TEST(CrfFit, NeverReturnsAnInvalidCurve) {
  // Unrelated images: nothing fits, but whatever is returned must be a valid φ.
  const cv::Mat sharp = randomImage({96, 96}, 11), blurred = randomImage({96, 96}, 12);
  for (const CrfFitOptions& options : {CrfFitOptions{}, CrfFitOptions::seed()}) {
    try {
      const CrfFitResult fit = fitInverseCrf(sharp, blurred, test::levinKernel(5), options);
      EXPECT_TRUE(checkValidity(fit.model)) << fit.summary();
      EXPECT_TRUE(checkValidity(TableModel{fit.inverse_crf}));
    } catch (const InvalidInput&) {
      SUCCEED();
    }
  }
}

TEST(CrfFit, RejectsPairWithoutEdges) {
  const cv::Mat flat(80, 80, CV_8U, cv::Scalar(120));
  try {
    fitInverseCrf(flat, flat, test::levinKernel(1));
    FAIL() << "expected InvalidInput";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("no usable edges"), std::string::npos) << e.what();
  }
}

TEST(CrfFit, RejectsSizeMismatchAndAllSaturated) {
  EXPECT_THROW(fitInverseCrf(cv::Mat(50, 50, CV_8U, cv::Scalar(1)), cv::Mat(50, 60, CV_8U, cv::Scalar(1)),
                             test::levinKernel(1)),
               InvalidInput);
  const cv::Mat white(80, 80, CV_8U, cv::Scalar(255));
  try {
    fitInverseCrf(white, white, test::levinKernel(1));
    FAIL() << "expected InvalidInput";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("saturated"), std::string::npos) << e.what();
  }
}

TEST(CrfFit, NoiseHandlingReducesBiasOnNoisySharpImage) {
  SimulationOptions sim;
  sim.noise_variance = 0.005;
  sim.seed = 5;
  const GammaModel truth{2.2};
  const SimulationResult pair = simulatePair(test::levinImage(4), truth, test::levinKernel(2), sim);
  CrfFitOptions plain;
  plain.experimental.noise = NoiseHandling::none;
  plain.model = CrfModelChoice::ggcm;
  CrfFitOptions aware = plain;
  aware.experimental.noise = NoiseHandling::debias;
  const CrfFitResult a = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(2), plain);
  const CrfFitResult b = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(2), aware);
  EXPECT_NEAR(b.noise_sigma, std::sqrt(0.005), 0.15 * std::sqrt(0.005));
  EXPECT_TRUE(b.noise_sigma_estimated);
  EXPECT_LT(curveRmse(b.model, truth), curveRmse(a.model, truth)) << a.summary() << "\n" << b.summary();
}

// The moment sums form the squared aggregated masses only for the CUE ablation (experimental.variance_correction),
// their one reader: with it on, the CUE refinement runs on them and decides the model, and its energy is a
// chi-square per bin near 1 (the noise of I through the masses is most of each bin's variance; without the masses
// only the quantisation would be left and the chi-square would be far above 1).
TEST(CrfFit, CueAblationStillHasItsSquaredMasses) {
  SimulationOptions sim;
  sim.noise_variance = 0.005;
  sim.seed = 5;
  const SimulationResult pair = simulatePair(test::levinImage(4), GammaModel{2.2}, test::levinKernel(2), sim);
  CrfFitOptions options;
  options.experimental.variance_correction = true;
  const CrfFitResult cue = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(2), options);
  EXPECT_NE(cue.choice_reason.find("CUE"), std::string::npos) << cue.summary();
  EXPECT_NE(cue.chosen, "fallback") << cue.summary();
  EXPECT_GT(cue.energy, 0.3) << cue.summary();
  EXPECT_LT(cue.energy, 3.0) << cue.summary();
}

// A pair with a 3-px blur and a noisy sharp shot (σ = 5 levels), r = 2: nearly a plain two-exposure pair, where
// φ^γ with r^γ fit alike but for the blur inconsistency and Jensen's bias ½σ²φ'' of the noise.
struct SmallBlurPair {
  cv::Mat kernel = cv::Mat::zeros(3, 3, CV_64F);
  SimulationResult pair;
  SmallBlurPair() {
    kernel.row(1).setTo(1.0 / 3);
    SimulationOptions sim;
    sim.ratio = 2;
    sim.noise_variance = 0.02 * 0.02;
    sim.seed = 9;
    pair = simulatePair(0.45 * test::levinImage(1), GammaModel{2.2}, kernel, sim);
  }
};

TEST(CrfFit, JensenCorrectionRemovesTheNoiseBiasOfASmallBlurPair) {
  const SmallBlurPair p;
  CrfFitOptions plain;
  plain.nominal_ratio = 2.2;  // 10 % off
  plain.noise_sigma = 0.02;
  CrfFitOptions jensen = plain;
  jensen.experimental.noise = NoiseHandling::jensen;
  const CrfFitResult a = fitInverseCrf(p.pair.sharp, p.pair.blurred, p.kernel, plain);
  const CrfFitResult b = fitInverseCrf(p.pair.sharp, p.pair.blurred, p.kernel, jensen);
  EXPECT_LT(std::abs(b.ratio / 2 - 1), 0.03) << b.summary();
  EXPECT_LT(std::abs(a.ratio / 2 - 1), 0.03) << a.summary();
  EXPECT_LT(curveRmse(b.model, GammaModel{2.2}), curveRmse(a.model, GammaModel{2.2})) << a.summary() << "\n" << b.summary();
}

TEST(CrfFit, RatioPriorPullsOnlyAnUndeterminedRatio) {
  // Without a usable blur signal the prior decides (tiny σ: r stays at the centre); with a real blur the images do.
  const SmallBlurPair p;
  CrfFitOptions options;
  options.nominal_ratio = 2.6;
  options.noise_sigma = 0.02;
  const CrfFitResult free_fit = fitInverseCrf(p.pair.sharp, p.pair.blurred, p.kernel, options);
  options.ratio_prior_sigma = 1e-3;
  const CrfFitResult pinned = fitInverseCrf(p.pair.sharp, p.pair.blurred, p.kernel, options);
  EXPECT_GT(std::abs(free_fit.ratio / 2.6 - 1), 0.05) << free_fit.summary();
  EXPECT_NEAR(pinned.ratio, 2.6, 0.03 * 2.6) << pinned.summary();
  EXPECT_GT(pinned.ratio_prior_scale, 0);
  EXPECT_GT(pinned.ratio_images_only, 0);

  SimulationOptions sim;
  sim.ratio = 0.8;
  sim.bits = 16;
  const SimulationResult sharp_blur = simulatePair(test::levinImage(3), GammaModel{2.2}, test::levinKernel(2), sim);
  CrfFitOptions exif;
  exif.nominal_ratio = 0.96;  // EXIF 20 % off
  exif.ratio_prior_sigma = 0.2;
  const CrfFitResult fit = fitInverseCrf(sharp_blur.sharp, sharp_blur.blurred, test::levinKernel(2), exif);
  EXPECT_NEAR(fit.ratio, 0.8, 0.01) << fit.summary();
}

TEST(CrfFit, ShoulderReferenceKeepsExactDataExact) {
  // The data reach x ≈ 0.45 only, so the shoulder prior acts on half the curve; it only breaks ties, and exact
  // data have none (the real-pair effect of the prior: CalibrateRealPairs.PhonePairsGreenCurvesWithinPointOneRms).
  SimulationOptions sim;
  sim.bits = 16;
  const GammaModel truth{2.2};
  const SimulationResult pair = simulatePair(0.2 * test::levinImage(2), truth, test::levinKernel(3), sim);
  CrfFitOptions options;
  options.experimental.shoulder_follows_emor_mean = true;
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, test::levinKernel(3), options);
  EXPECT_LT(fit.covered_levels.second, 0.5 * (fit.levels - 1)) << fit.summary();
  EXPECT_LT(curveRmse(fit.model, truth), 5e-3) << fit.summary();
}

TEST(NoiseEstimation, ProfileFollowsSignalDependentNoise) {
  // variance = 4e-4 x + 1e-5 (Poisson–Gaussian) on a smooth ramp: σ from 0.003 to 0.02
  cv::Mat clean(240, 320, CV_64F);
  for (int y = 0; y < clean.rows; ++y)
    for (int x = 0; x < clean.cols; ++x) clean.at<double>(y, x) = 0.05 + 0.9 * x / (clean.cols - 1.0);
  cv::Mat noise(clean.size(), CV_64F);
  cv::RNG rng(3);
  rng.fill(noise, cv::RNG::NORMAL, 0, 1);
  cv::Mat sd;
  cv::sqrt(4e-4 * clean + 1e-5, sd);
  const cv::Mat noisy = clean + noise.mul(sd);
  const NoiseProfile profile = estimateNoiseProfile(noisy);
  ASSERT_GE(profile.level.size(), 4u);
  for (std::size_t i = 0; i < profile.level.size(); ++i) {
    const double expected = std::sqrt(4e-4 * profile.level[i] + 1e-5);
    EXPECT_NEAR(profile.sigma[i], expected, 0.1 * expected) << profile.level[i];
  }
  const std::vector<double> per_level = noiseSigmaPerLevel(profile.level, profile.sigma, 256);
  EXPECT_DOUBLE_EQ(per_level.front(), profile.sigma.front());
  EXPECT_DOUBLE_EQ(per_level.back(), profile.sigma.back());
  EXPECT_THROW(noiseSigmaPerLevel({}, {}, 256), InvalidInput);
}

TEST(CrfFit, OptionsAreChecked) {
  CrfFitOptions options;
  options.nominal_ratio = 0;
  EXPECT_THROW(options.check(), InvalidInput);
  options = {};
  options.emor_terms = 0;
  EXPECT_THROW(options.check(), InvalidInput);
  EXPECT_NO_THROW(CrfFitOptions::seed().check());
  options = {};
  options.ratio_prior_sigma = -1;
  EXPECT_THROW(options.check(), InvalidInput);
  EXPECT_EQ(noiseHandlingFromString("jensen"), NoiseHandling::jensen);
  EXPECT_THROW(noiseHandlingFromString("median"), InvalidInput);
}

TEST(CrfFit, ExperimentalOptionsAreCheckedAndDefaultToCrfcalsMethod) {
  const CrfFitOptions defaults;
  EXPECT_EQ(defaults.experimental.objective, CrfObjective::moments);
  EXPECT_EQ(defaults.experimental.optimizer, CrfOptimizer::levenberg_marquardt);
  EXPECT_EQ(defaults.experimental.noise, NoiseHandling::none);
  EXPECT_FALSE(defaults.experimental.variance_correction);
  EXPECT_FALSE(defaults.experimental.shoulder_follows_emor_mean);
  EXPECT_EQ(CrfFitOptions::seed().experimental.objective, CrfObjective::seed_intensity);
  CrfFitOptions options;
  options.experimental.ratio_rounds = 0;
  EXPECT_THROW(options.check(), InvalidInput);
  options = {};
  options.experimental.tau1 = -0.1;
  EXPECT_THROW(options.check(), InvalidInput);
  options = {};
  options.experimental.debias_regularization = 0;
  EXPECT_THROW(options.check(), InvalidInput);
}

}  // namespace
}  // namespace crfcal

namespace crfcal {
namespace {

// The band's ratio rule fits φ twice per half (r free, then r held); fitInverseCrfThenHoldRatio shares the prepared
// pixels and moments between the two. Its results must be those of two separate fits, bit for bit.
TEST(CrfFit, HoldingTheRatioOnSharedMomentsEqualsTwoSeparateFits) {
  SimulationOptions sim;
  sim.ratio = 4;
  sim.noise_variance = 0.0002;
  const cv::Mat kernel = test::levinKernel(3);
  const SimulationResult pair = simulatePair(test::levinImage(2) * 0.2, GammaModel{2.2}, kernel, sim);
  CrfFitOptions options;
  options.nominal_ratio = 4;
  const auto held_ratio = [](double fitted) { return 0.5 * fitted + 2.0; };  // any rule of the fitted r
  const CrfFitAtHeldRatio shared = fitInverseCrfThenHoldRatio(pair.sharp, pair.blurred, kernel, options, held_ratio);

  const CrfFitResult free_fit = fitInverseCrf(pair.sharp, pair.blurred, kernel, options);
  CrfFitOptions held = options;
  held.fit_ratio = false;
  held.nominal_ratio = held_ratio(free_fit.ratio);
  const CrfFitResult held_fit = fitInverseCrf(pair.sharp, pair.blurred, kernel, held);

  EXPECT_EQ(shared.free_ratio.ratio, free_fit.ratio);
  EXPECT_EQ(shared.free_ratio.inverse_crf, free_fit.inverse_crf);
  EXPECT_EQ(shared.held_ratio.ratio, held_fit.ratio);
  EXPECT_DOUBLE_EQ(shared.held_ratio.ratio, held_ratio(free_fit.ratio));
  EXPECT_EQ(shared.held_ratio.inverse_crf, held_fit.inverse_crf);
  EXPECT_EQ(shared.held_ratio.pixels.used, held_fit.pixels.used);
  EXPECT_NE(shared.held_ratio.inverse_crf, shared.free_ratio.inverse_crf) << "holding r elsewhere changes φ";
  options.fit_ratio = false;
  EXPECT_THROW(fitInverseCrfThenHoldRatio(pair.sharp, pair.blurred, kernel, options, held_ratio), InvalidInput);
}

}  // namespace
}  // namespace crfcal
