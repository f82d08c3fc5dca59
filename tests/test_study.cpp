// Studies of issue 6: colour mixing, signal-dependent noise, exposure-ratio fitting — planted truth on synthetic
// data, plus smoke tests on ../shared/data when present.
#include <cmath>
#include <fstream>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/colour_mixing.hpp"
#include "crfcal/error.hpp"
#include "crfcal/exposure_fit.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/noise_model.hpp"
#include "crfcal/response_curve.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// A camera: white balance + colour matrix, gamut clip, per-channel tone curve.
std::vector<ColourSample> plantedCamera(int n, int group, std::uint64_t seed) {
  Eigen::Matrix3d m;
  m << 1.7, -0.5, -0.2, -0.3, 1.6, -0.3, -0.1, -0.6, 1.7;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<ColourSample> out;
  for (int i = 0; i < n; ++i) {
    ColourSample s;
    const double level = group == 1 ? 0.05 + 0.6 * u(rng) : 0.1 + 0.5 * u(rng);
    for (size_t c = 0; c < 3; ++c) s.raw[c] = level * (0.2 + 0.8 * u(rng));  // saturated colours
    const Eigen::Vector3d mixed = m * Eigen::Vector3d(s.raw[0], s.raw[1], s.raw[2]);
    const std::array<double, 3> gamma{2.0, 2.2, 2.4};
    for (int c = 0; c < 3; ++c)
      s.jpeg[static_cast<size_t>(c)] = std::pow(std::clamp(mixed[c], 0.0, 1.0), 1.0 / gamma[static_cast<size_t>(c)]);
    s.group = group;
    out.push_back(s);
  }
  return out;
}

TEST(StudyChannels, PlantedMixIsRecoveredAndBeatsPointwiseHeldOut) {
  const auto train = plantedCamera(150, 1, 1);
  const auto test = plantedCamera(150, 2, 2);
  const auto fits = fitColourModels(train);
  ASSERT_EQ(fits.size(), 4u);
  const double pointwise = colourRmse(fits[0].model, test);
  const double mix_clip = colourRmse(fits[2].model, test);
  EXPECT_GT(pointwise, 0.02);             // a pointwise curve cannot express the cross-talk
  EXPECT_LT(mix_clip, 0.4 * pointwise);   // the planted structure is found
  EXPECT_LT(mix_clip, 0.012);
  // The recovered matrix's row ratios match the planted one (the curve absorbs each row's scale).
  const auto& m = fits[2].model.mix;
  EXPECT_NEAR(m(0, 1) / m(0, 0), -0.5 / 1.7, 0.08);
  EXPECT_NEAR(m(1, 0) / m(1, 1), -0.3 / 1.6, 0.08);
}

TEST(StudyChannels, PointwiseDataIsFitByPointwiseModel) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<ColourSample> samples;
  for (int i = 0; i < 120; ++i) {
    ColourSample s;
    for (size_t c = 0; c < 3; ++c) {
      s.raw[c] = 0.9 * u(rng);
      s.jpeg[c] = std::pow(s.raw[c] / 0.9, 1 / 2.2);
    }
    samples.push_back(s);
  }
  const auto fit = fitColourModel(samples, ColourModelKind::pointwise);
  EXPECT_LT(fit.train_rmse, 0.01);
  EXPECT_THROW(fitColourModel(std::vector<ColourSample>(3), ColourModelKind::mix), InvalidInput);
}

TEST(StudyNoise, SignalDependentNoiseIsRecoveredFromOneImage) {
  // A ramp (locally linear: Immerkær's operator cancels it) with var = a x + b noise, identity curve.
  const PoissonGaussianNoise truth{4e-4, 2e-5};
  cv::Mat ramp(500, 500, CV_64F);
  for (int y = 0; y < ramp.rows; ++y)
    for (int x = 0; x < ramp.cols; ++x) ramp.at<double>(y, x) = 0.03 + 0.94 * x / (ramp.cols - 1.0);
  const cv::Mat noisy = addPoissonGaussianNoise(ramp, truth, 11);
  NoiseLevelOptions options;
  options.flat_quantile = 1.0;
  const auto bins = measureNoiseLevels(noisy, options);
  ASSERT_GE(bins.size(), 8u);
  std::vector<double> x, s;
  for (const auto& b : bins) {
    x.push_back(b.intensity);
    s.push_back(b.sigma);
  }
  const PoissonGaussianNoise fit = fitPoissonGaussian(x, s);
  EXPECT_NEAR(fit.a, truth.a, 0.15 * truth.a);
  EXPECT_NEAR(fit.b, truth.b, 1.5e-5);
  // Through a curve: same data seen as I = ψ(x) is mapped back to the same a, b.
  const ResponseCurve identity;
  const PoissonGaussianNoise back = fitPoissonGaussianThroughCurve(bins, identity);
  EXPECT_NEAR(back.a, fit.a, 0.05 * truth.a);
}

TEST(StudyNoise, IntensitySigmaFollowsTheCurveSlope) {
  const ResponseCurve curve(GammaModel{2.2});
  const PoissonGaussianNoise n{1e-4, 1e-6};
  const double v = 0.5, phi = std::pow(v, 2.2), slope = 2.2 * std::pow(v, 1.2);
  EXPECT_NEAR(intensityNoiseSigma(curve, n, v), std::sqrt(n.a * phi + n.b) / slope, 1e-4);
  // Pure shot noise through x^(1/2.2) is nearly flat: σ_I ∝ v^(1.1 − 1.2) = v^−0.1.
  const PoissonGaussianNoise shot{1e-4, 0};
  EXPECT_NEAR(intensityNoiseSigma(curve, shot, 0.1) / intensityNoiseSigma(curve, shot, 0.9), std::pow(9.0, 0.1), 0.02);
  // Read noise makes the darks far noisier than the brights in the intensity domain (1/φ' is large there).
  const PoissonGaussianNoise read{1e-4, 1e-5};
  EXPECT_GT(intensityNoiseSigma(curve, read, 0.1), 3 * intensityNoiseSigma(curve, read, 0.9));
  // The simulator adds the noise in the irradiance domain: the clean pair is reproduced without noise.
  const cv::Mat image = test::levinImage(1);
  const auto pair = simulatePairPoissonGaussian(image, GammaModel{2.2}, test::levinKernel(1), {});
  EXPECT_LT(cv::norm(pair.sharp - pair.sharp_clean, cv::NORM_INF), 0.5 / 255 + 1e-9);
}

std::vector<cv::Mat> plantedBracket(const std::vector<double>& exposures, const ResponseCurve& curve) {
  cv::Mat irr(240, 320, CV_64F);
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int y = 0; y < irr.rows; ++y)
    for (int x = 0; x < irr.cols; ++x)
      irr.at<double>(y, x) = std::exp(-6.0 + 5.5 * (0.6 * x / 319.0 + 0.4 * u(rng)));  // ~ 6 stops
  std::vector<cv::Mat> frames;
  for (double e : exposures) {
    cv::Mat f = cv::min(irr * (e / exposures.back()) * 3.0, 1.0);
    cv::Mat out = curve.forward(f);
    out.convertTo(out, CV_8U, 255.0);  // 8-bit like a JPEG
    frames.push_back(out);
  }
  return frames;
}

TEST(StudyRatio, BracketFitRecoversPlantedRatios) {
  const ResponseCurve curve(GammaModel{2.2});
  const std::vector<double> truth{1, 2, 4.2, 8}, nominal{1, 2, 4, 8};
  const auto frames = plantedBracket(truth, curve);
  const BracketFitResult fit = fitBracket(frames, nominal);
  ASSERT_EQ(fit.step_ratio.size(), 3u);
  EXPECT_NEAR(fit.step_ratio[0], 2.0, 0.04);
  EXPECT_NEAR(fit.step_ratio[1], 2.1, 0.04);
  EXPECT_NEAR(fit.step_ratio[2], 8 / 4.2, 0.04);
  // Known curve: per-pixel and quantile estimators.
  const auto reg = estimateExposureRatio(frames[1], frames[2], curve);
  EXPECT_NEAR(reg.ratio, 2.1, 0.03);
  ExposureRatioOptions q;
  q.registered = false;
  EXPECT_NEAR(estimateExposureRatio(frames[1], frames[2], curve, q).ratio, 2.1, 0.06);
  EXPECT_THROW(fitBracket({frames[0]}, {1.0}), InvalidInput);
}

TEST(StudyRatio, FittedExposuresPredictHeldOutFramesBetterThanWrongNominalOnes) {
  // The middle step is 10 % off its nominal value: fitted on the left half, predicted on the right half.
  const ResponseCurve curve(GammaModel{2.2});
  const std::vector<double> truth{1, 2, 4.4, 8}, nominal{1, 2, 4, 8};
  const auto frames = plantedBracket(truth, curve);
  const cv::Rect left(0, 0, frames[0].cols / 2, frames[0].rows);
  const cv::Rect right(frames[0].cols / 2, 0, frames[0].cols - frames[0].cols / 2, frames[0].rows);
  BracketFitOptions fixed, free;
  fixed.fixed_exposures = true;
  fixed.region = free.region = left;
  const BracketFitResult nominal_fit = fitBracket(frames, nominal, fixed), fitted = fitBracket(frames, nominal, free);
  ASSERT_EQ(nominal_fit.step_ratio.size(), 3u);
  EXPECT_NEAR(nominal_fit.step_ratio[1], 2.0, 1e-9);  // fixed at the nominal ratio
  const auto e_nominal = bracketPredictionRmse(frames, nominal_fit, right);
  const auto e_fitted = bracketPredictionRmse(frames, fitted, right);
  ASSERT_EQ(e_fitted.size(), 4u);  // three steps + all
  EXPECT_LT(e_fitted.back(), 0.8 * e_nominal.back());
  EXPECT_LT(e_fitted.back(), 6.0 / 255);  // and predicts within a few levels (EMoR(4) vs the γ 2.2 truth)
}

TEST(StudyDatasets, ReadsNpyAndExifCsv) {
  test::TempDir dir;
  {
    std::ofstream npy(dir / "a.npy", std::ios::binary);
    std::string header = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }";
    header.resize(117, ' ');
    header += '\n';
    npy.write("\x93NUMPY\x01\x00", 8);
    const char len[2] = {static_cast<char>(header.size() & 0xff), static_cast<char>(header.size() >> 8)};
    npy.write(len, 2);
    npy.write(header.data(), static_cast<std::streamsize>(header.size()));
    for (int i = 0; i < 6; ++i) {
      const double v = i * 0.5;
      npy.write(reinterpret_cast<const char*>(&v), 8);
    }
  }
  const cv::Mat a = io::readNpy(dir / "a.npy");
  ASSERT_EQ(a.rows, 2);
  ASSERT_EQ(a.cols, 3);
  EXPECT_DOUBLE_EQ(a.at<double>(1, 2), 2.5);
  {
    std::ofstream csv(dir / "exif.csv");
    csv << "SourceFile,FileName,Make,Model,ISO,ExposureTime,FNumber\n"
        << "x.jpg,x.jpg,NIKON,E995,100,1/60,7.7\n"
        << "y.jpg,y.jpg,\"Canon, Inc\",S3,80,2.5,2.7\n";
  }
  const auto rows = io::readExifCsv(dir / "exif.csv");
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_NEAR(rows[0].exposure_time, 1.0 / 60, 1e-12);
  EXPECT_EQ(rows[0].exposure_text, "1/60");
  EXPECT_EQ(rows[1].make, "Canon, Inc");
  EXPECT_DOUBLE_EQ(rows[1].iso, 80);
  EXPECT_THROW(io::readExifCsv(dir / "missing.csv"), Error);
}

TEST(StudyCli, MissingDataDirectoryIsOneErrorLine) {
  test::TempDir dir;
  const auto r = test::run(test::crfcalBinary().string() + " study ratio --data " + (dir / "nope").string() + " -o " +
                           (dir / "out").string() + " -q");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.output.find("shared data directory not found"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(dir / "out"));
}

TEST(StudyRealData, MiddleburyMixBeatsPointwiseOnOneCamera) {
  const auto data = test::sharedData();
  if (data.empty() || !std::filesystem::is_directory(data / "middlebury")) GTEST_SKIP() << "../shared/data absent";
  const auto cameras = io::readMiddleburyPatches(data / "middlebury");
  ASSERT_GE(cameras.size(), 1u);
  std::vector<ColourSample> s1, s2;
  for (const auto& s : cameras[0].samples) (s.group == 1 ? s1 : s2).push_back(s);
  ASSERT_GE(s1.size(), 30u);
  const auto fits = fitColourModels(s1);
  EXPECT_LT(colourRmse(fits[2].model, s2), colourRmse(fits[0].model, s2));
  const auto profiles = io::readNoiseProfiles(data / "noise_profiles" / "noiseprofiles.json");
  const auto p = io::findNoiseProfile(profiles, "EOS 5D Mark II", 100);
  ASSERT_TRUE(p.has_value());
  EXPECT_NEAR(p->a[0], 4.65e-6, 0.2e-6);
}

}  // namespace
}  // namespace crfcal
