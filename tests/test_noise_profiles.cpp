// darktable's camera noise profiles (io/noise_profiles.hpp) on the bundled excerpt, and the real-regime handheld
// simulation (handheld_simulation.hpp): the sharp shot underexposed by r, each shot with the planted a·x + b noise;
// the blurred frame moved in the irradiance or the intensity domain; that noise in a shot's levels.
#include <cmath>
#include <fstream>
#include <functional>
#include <iterator>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "crfcal/error.hpp"
#include "crfcal/exposure_ratio.hpp"
#include "crfcal/handheld_simulation.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/noise_profiles.hpp"
#include "crfcal/sensor_noise.hpp"
#include "test_support.hpp"

namespace crfcal::test {
namespace {
namespace fs = std::filesystem;

fs::path excerpt() { return samples() / "noise_profiles" / "noiseprofiles.json"; }

std::string errorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return {};
}

TEST(NoiseProfiles, ReadsACameraByMakerAndModelFromTheBundledExcerpt) {
  const auto nexus = io::readCameraNoiseProfile(excerpt(), "LGE Nexus 5");
  EXPECT_EQ(nexus.camera(), "LGE Nexus 5");
  ASSERT_EQ(nexus.by_iso.size(), 6u);  // 100 … 3200, the two ISO 3200 measurements as one
  EXPECT_EQ(nexus.minIso(), 100);
  EXPECT_EQ(nexus.maxIso(), 3200);
  const SensorNoise iso100 = nexus.atIso(100);
  EXPECT_DOUBLE_EQ(iso100.red.a, 2.43081198620952e-05);
  EXPECT_DOUBLE_EQ(iso100.green.a, 1.33827792338459e-05);
  EXPECT_DOUBLE_EQ(iso100.blue.b, 9.89959561056272e-08);
  // The model alone, any case and spacing, finds the same camera.
  EXPECT_DOUBLE_EQ(io::readCameraNoiseProfile(excerpt(), "  nexus   5 ").atIso(100).green.a, iso100.green.a);
}

TEST(NoiseProfiles, RepeatedMeasurementsOfAnIsoAreAveraged) {
  const auto nexus = io::readCameraNoiseProfile(excerpt(), "LGE Nexus 5");
  EXPECT_DOUBLE_EQ(nexus.atIso(3200).green.a, (0.000424195799109644 + 0.000442218441209912) / 2);
  EXPECT_DOUBLE_EQ(nexus.atIso(3200).red.b, (1.42802529339895e-05 + 1.15050395187219e-05) / 2);
}

TEST(NoiseProfiles, SkippedProfilesAreIgnored) {
  // The 5D Mark II has a superseded ("skip") ISO 100 profile with a = 2.83e-6 on every channel.
  const auto canon = io::readCameraNoiseProfile(excerpt(), "Canon EOS 5D Mark II");
  EXPECT_DOUBLE_EQ(canon.atIso(100).green.a, 2.54268633057631e-06);
  EXPECT_EQ(canon.by_iso.size(), 22u);
  // The G10 keeps one of its several measurements per ISO.
  EXPECT_DOUBLE_EQ(io::readCameraNoiseProfile(excerpt(), "Canon PowerShot G10").atIso(800).green.a,
                   0.000139637366609320);
}

TEST(NoiseProfiles, InterpolatesLinearlyBetweenMeasuredIsos) {
  const auto nexus = io::readCameraNoiseProfile(excerpt(), "LGE Nexus 5");
  const SensorNoise at300 = nexus.atIso(300), at200 = nexus.atIso(200), at400 = nexus.atIso(400);
  EXPECT_DOUBLE_EQ(at300.green.a, (at200.green.a + at400.green.a) / 2);
  EXPECT_DOUBLE_EQ(at300.blue.b, (at200.blue.b + at400.blue.b) / 2);
  const SensorNoise at250 = nexus.atIso(250);
  EXPECT_NEAR(at250.red.a, 0.75 * at200.red.a + 0.25 * at400.red.a, 1e-18);
}

TEST(NoiseProfiles, ErrorsNameTheFileAndTheProblem) {
  const auto nexus = io::readCameraNoiseProfile(excerpt(), "LGE Nexus 5");
  const std::string outside = errorOf([&] { nexus.atIso(6400); });
  EXPECT_NE(outside.find(excerpt().string()), std::string::npos) << outside;
  EXPECT_NE(outside.find("ISO 100–3200"), std::string::npos) << outside;
  const std::string absent = errorOf([] { io::readCameraNoiseProfile(excerpt(), "Canon EOS 5D"); });
  EXPECT_NE(absent.find(excerpt().string()), std::string::npos) << absent;
  EXPECT_NE(absent.find("did you mean: Canon EOS 5D Mark II"), std::string::npos) << absent;
  TempDir dir;
  {
    std::ofstream(dir / "broken.json") << "{\"noiseprofiles\": [";
    std::ofstream(dir / "layout.json") << "{\"noiseprofiles\": [{\"maker\": \"X\", \"models\": [{\"model\": \"Y\", "
                                          "\"profiles\": [{\"iso\": 100, \"a\": [1]}]}]}]}";
  }
  const std::string broken = errorOf([&] { io::readCameraNoiseProfile(dir / "broken.json", "X Y"); });
  EXPECT_NE(broken.find((dir / "broken.json").string() + ": invalid JSON"), std::string::npos) << broken;
  const std::string layout = errorOf([&] { io::readCameraNoiseProfile(dir / "layout.json", "X Y"); });
  EXPECT_NE(layout.find((dir / "layout.json").string() + ": unexpected noise-profile layout"), std::string::npos)
      << layout;
  const std::string missing = errorOf([&] { io::readCameraNoiseProfile(dir / "none.json", "X Y"); });
  EXPECT_NE(missing.find("none.json: cannot open"), std::string::npos) << missing;
}

TEST(NoiseProfiles, ListsTheExcerptsCameras) {
  const auto names = io::listNoiseProfileCameras(excerpt());
  EXPECT_EQ(names, (std::vector<std::string>{"Canon EOS 5D Mark II", "Canon PowerShot G10", "LGE Nexus 5", "Nikon D200"}));
}

TEST(NoiseProfiles, TheExcerptMatchesTheFullDarktableDatabase) {
  const fs::path shared = sharedData();
  if (shared.empty() || !fs::exists(shared / "noise_profiles" / "noiseprofiles.json"))
    GTEST_SKIP() << "../shared/data absent";
  for (const auto& camera : io::listNoiseProfileCameras(excerpt())) {
    const auto a = io::readCameraNoiseProfile(excerpt(), camera);
    const auto b = io::readCameraNoiseProfile(shared / "noise_profiles" / "noiseprofiles.json", camera);
    ASSERT_EQ(a.by_iso.size(), b.by_iso.size()) << camera;
    for (size_t i = 0; i < a.by_iso.size(); ++i) {
      EXPECT_EQ(a.by_iso[i].first, b.by_iso[i].first) << camera;
      EXPECT_EQ(a.by_iso[i].second.green.a, b.by_iso[i].second.green.a) << camera;
      EXPECT_EQ(a.by_iso[i].second.red.b, b.by_iso[i].second.red.b) << camera;
    }
  }
}

// A flat grey photo through a linear φ, a 1-px kernel and no motion: each shot's pixels are its irradiance plus
// the planted noise (plus 8-bit rounding, variance 1/12 DN²), so mean and variance can be checked per channel.
TEST(RealRegimeSimulation, SharpShotIsUnderexposedByRAndCarriesThePlantedNoisePerChannel) {
  const cv::Mat photo(256, 256, CV_8UC3, cv::Scalar(128, 128, 128));
  const cv::Mat kernel = cv::Mat::ones(1, 1, CV_64F);
  HandheldPairOptions options;
  options.ratio = 4;
  options.shift_x = options.shift_y = options.rotation_deg = 0;
  options.normally_exposed = HandheldPairOptions::NormallyExposed::Blurred;
  options.sharp_noise = SensorNoise{{2e-3, 4e-5}, {1e-3, 2e-5}, {5e-4, 1e-5}};  // red, green, blue
  options.blurred_noise = SensorNoise{{2e-4, 2e-6}, {1e-4, 1e-6}, {3e-4, 4e-6}};
  const HandheldPair pair = makeHandheldPair(photo, GammaModel{1.0}, kernel, options);
  const double quantisation = 1.0 / (12 * 255.0 * 255.0);
  struct Shot {
    const cv::Mat& image;
    double irradiance;
    const SensorNoise& noise;
  };
  for (const Shot& shot : {Shot{pair.sharp, options.exposure / options.ratio, *options.sharp_noise},
                           Shot{pair.blurred, options.exposure, *options.blurred_noise}}) {
    std::vector<cv::Mat> planes;
    cv::split(shot.image, planes);
    const PoissonGaussian bgr[] = {shot.noise.blue, shot.noise.green, shot.noise.red};
    for (int c = 0; c < 3; ++c) {
      cv::Mat unit;
      planes[static_cast<size_t>(c)].convertTo(unit, CV_64F, 1 / 255.0);
      cv::Scalar mean, stddev;
      cv::meanStdDev(unit, mean, stddev);
      const double expected = bgr[c].variance(shot.irradiance) + quantisation;
      EXPECT_NEAR(mean[0], shot.irradiance, 0.002) << "plane " << c;
      EXPECT_NEAR(stddev[0] * stddev[0] / expected, 1.0, 0.03) << "plane " << c << " at x = " << shot.irradiance;
    }
  }
}

// `bench joint --offset`: an additive irradiance in the blurred shot alone (a flare or black level of that shot),
// before the response: through a linear φ each blurred pixel rises by it, the sharp shot is untouched.
TEST(RealRegimeSimulation, BlurredOffsetRaisesTheBlurredShotAloneByItsIrradiance) {
  const cv::Mat photo(64, 64, CV_8UC1, cv::Scalar(64));
  const cv::Mat kernel = cv::Mat::ones(1, 1, CV_64F);
  HandheldPairOptions options;
  options.ratio = 2;
  options.shift_x = options.shift_y = options.rotation_deg = 0;
  options.noise_gain_sharp = options.noise_gain_blurred = options.read_noise = 0;
  const HandheldPair clean = makeHandheldPair(photo, GammaModel{1.0}, kernel, options);
  options.blurred_offset = 0.04;
  const HandheldPair offset = makeHandheldPair(photo, GammaModel{1.0}, kernel, options);
  EXPECT_EQ(cv::norm(clean.sharp, offset.sharp, cv::NORM_INF), 0);
  EXPECT_NEAR(cv::mean(offset.blurred)[0] - cv::mean(clean.blurred)[0], 0.04 * 255, 0.6);
  options.blurred_offset = 0.6;
  EXPECT_THROW(makeHandheldPair(photo, GammaModel{1.0}, kernel, options), InvalidInput);
}

TEST(RealRegimeSimulation, BenchPairsWritesTheNominalRatioAndTheIsosInExifAndTruth) {
  TempDir dir;
  const auto result = run("'" + crfcalBinary().string() + "' bench pairs --pairs-only --regime real --ratio 8 " +
                          "--image '" + (samples() / "effects" / "window.jpg").string() + "' --max-side 160 " +
                          "--kernel levin:1 --crf gamma:2.2 --noise-profiles '" + excerpt().string() + "' -o '" +
                          (dir / "out").string() + "'");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  std::ifstream in(dir / "out" / "case1" / "truth.json");
  const nlohmann::json truth = nlohmann::json::parse(in);
  EXPECT_EQ(truth.at("regime"), "real");
  EXPECT_EQ(truth.at("noise_camera"), "LGE Nexus 5");
  EXPECT_EQ(truth.at("iso_blurred").get<double>(), 100);
  EXPECT_EQ(truth.at("iso_sharp").get<double>(), 800);
  EXPECT_NEAR(truth.at("exif_ratio").get<double>(), 8 * 1.04, 1e-9);  // the bench's deliberate 4 % EXIF error
  // What a user's calibrate reads back from the files' EXIF (Sec. 4, footnote 4).
  const ExifExposure es = io::readExif(dir / "out" / "case1" / "sharp.jpg");
  const ExifExposure eb = io::readExif(dir / "out" / "case1" / "blurred.jpg");
  EXPECT_EQ(*es.iso, 800);
  EXPECT_NEAR(exposureRatio(es, eb).ratio(), 8 * 1.04, 8 * 1.04 * 0.003);  // EXIF stores the long time to 1 ms
  // The sharp shot is the darker one, by about r where nothing clips.
  const cv::Mat sharp = cv::imread((dir / "out" / "case1" / "sharp.jpg").string());
  const cv::Mat blurred = cv::imread((dir / "out" / "case1" / "blurred.jpg").string());
  EXPECT_LT(cv::mean(sharp)[1] * 1.5, cv::mean(blurred)[1]);
}

// `--sharp-quality` and `--sharp-noise-scale` change the sharp shot alone (one part of the simulation at a time,
// docs/RESULTS.md#black-end): the blurred shot stays byte for byte the same, the sharp one loses its noise.
TEST(RealRegimeSimulation, SharpQualityAndNoiseScaleChangeTheSharpShotAlone) {
  TempDir dir;
  auto pairs = [&](const std::string& name, const std::string& extra) {
    const auto result = run("'" + crfcalBinary().string() + "' bench pairs --pairs-only --regime real --ratio 8 " +
                            "--image '" + (samples() / "effects" / "window.jpg").string() + "' --max-side 160 " +
                            "--kernel levin:1 --crf gamma:2.2 --noise-profiles '" + excerpt().string() + "' " + extra +
                            " -o '" + (dir / name).string() + "'");
    EXPECT_EQ(result.exit_code, 0) << result.output;
    return dir / name / "case1";
  };
  const auto as_simulated = pairs("a", ""), best_jpeg = pairs("b", "--sharp-quality 100"),
             noise_free = pairs("c", "--sharp-quality 100 --sharp-noise-scale 0");
  auto bytes = [](const std::filesystem::path& path) {
    std::ifstream in(path, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  EXPECT_EQ(bytes(as_simulated / "blurred.jpg"), bytes(best_jpeg / "blurred.jpg"));
  EXPECT_EQ(bytes(as_simulated / "blurred.jpg"), bytes(noise_free / "blurred.jpg"));
  EXPECT_NE(bytes(as_simulated / "sharp.jpg"), bytes(best_jpeg / "sharp.jpg"));
  // The same shot with and without its noise, both at quality 100: they differ by the noise, not on average.
  cv::Mat noisy, clean, difference;
  cv::imread((best_jpeg / "sharp.jpg").string(), cv::IMREAD_GRAYSCALE).convertTo(noisy, CV_64F);
  cv::imread((noise_free / "sharp.jpg").string(), cv::IMREAD_GRAYSCALE).convertTo(clean, CV_64F);
  cv::Scalar mean, stddev;
  cv::meanStdDev(noisy - clean, mean, stddev);
  EXPECT_GT(stddev[0], 0.5);           // levels: ISO 800 noise of the bundled phone profile
  EXPECT_LT(std::abs(mean[0]), 0.5);
}

// The blurred frame's handheld motion in the irradiance domain (HandheldPairOptions::warp_irradiance) or on its
// 8-bit intensities (the record): half a pixel across a dark | bright step, no noise, no blur. Away from the step
// the two agree; on the step the intensity warp averages intensities, the irradiance warp averages irradiances and
// then applies the (concave) response — 35 levels apart for gamma 2.2, equal for a linear response.
TEST(HandheldSimulation, IrradianceWarpAveragesIrradiancesAcrossAStepAndTheIntensityWarpIntensities) {
  cv::Mat photo(64, 64, CV_8UC1, cv::Scalar(40));
  photo.colRange(32, 64).setTo(220);
  const cv::Mat kernel = cv::Mat::ones(1, 1, CV_64F);
  auto blurredRow = [&](double gamma, bool warp_irradiance) {
    HandheldPairOptions options;
    options.shift_x = 0.5;
    options.shift_y = options.rotation_deg = 0;
    options.noise_gain_sharp = options.noise_gain_blurred = options.read_noise = 0;
    options.warp_irradiance = warp_irradiance;
    const HandheldPair pair = makeHandheldPair(photo, GammaModel{gamma}, kernel, options);
    cv::Mat row;
    pair.blurred.row(32).convertTo(row, CV_64F, 1 / 255.0);
    cv::Mat sharp_row;
    pair.sharp.row(32).convertTo(sharp_row, CV_64F, 1 / 255.0);
    return std::pair{row, sharp_row};
  };
  const double level = 1 / 255.0;
  for (const double gamma : {2.2, 1.0}) {
    const auto [by_intensity, sharp] = blurredRow(gamma, false);
    const cv::Mat by_irradiance = blurredRow(gamma, true).first;
    const double dark = sharp.at<double>(0, 10), bright = sharp.at<double>(0, 50);
    EXPECT_NEAR(by_intensity.at<double>(0, 10), dark, level);
    EXPECT_NEAR(by_irradiance.at<double>(0, 10), dark, level);
    EXPECT_NEAR(by_intensity.at<double>(0, 50), bright, level);
    EXPECT_NEAR(by_irradiance.at<double>(0, 50), bright, level);
    // dst(x) = src(x − 0.5): column 32 mixes columns 31 (dark) and 32 (bright) half and half
    const double mixed_irradiance = 0.5 * (std::pow(dark, gamma) + std::pow(bright, gamma));
    EXPECT_NEAR(by_intensity.at<double>(0, 32), 0.5 * (dark + bright), 1.5 * level) << "gamma " << gamma;
    EXPECT_NEAR(by_irradiance.at<double>(0, 32), std::pow(mixed_irradiance, 1 / gamma), 1.5 * level)
        << "gamma " << gamma;
    if (gamma > 1) {
      EXPECT_GT(by_irradiance.at<double>(0, 32) - by_intensity.at<double>(0, 32), 30 * level);
    }
  }
}

// The irradiance noise of a shot in its levels (sensor_noise.hpp intensityNoisePerLevel, the `bench pairs
// --noise-oracle`): through a linear response it is √(a·x + b) itself; through φ = x² it is divided by φ' = 2x; where
// φ' vanishes it is capped.
TEST(SensorNoise, IntensityNoisePerLevelIsTheIrradianceNoiseOverTheResponseSlope) {
  const PoissonGaussian noise{4e-4, 1e-6};
  const std::vector<double> linear = intensityNoisePerLevel(noise, GammaModel{1.0});
  ASSERT_EQ(linear.size(), 256u);
  for (const int v : {1, 64, 128, 254}) EXPECT_NEAR(linear[v], std::sqrt(noise.variance(v / 255.0)), 1e-6) << v;
  const std::vector<double> square = intensityNoisePerLevel(noise, GammaModel{2.0});
  for (const int v : {32, 128, 250}) {
    const double x = v / 255.0;
    EXPECT_NEAR(square[v], std::sqrt(noise.variance(x * x)) / (2 * x), 1e-3 * square[v]) << v;
  }
  EXPECT_DOUBLE_EQ(intensityNoisePerLevel(PoissonGaussian{1.0, 1.0}, GammaModel{4.0}, 256, 0.1)[0], 0.1);
  EXPECT_THROW(intensityNoisePerLevel(noise, GammaModel{1.0}, 1), InvalidInput);
}

TEST(RealRegimeSimulation, AutoRegimeKeepsRatiosUpToTwoInTheSharpNormalRegime) {
  TempDir dir;
  const auto result = run("'" + crfcalBinary().string() + "' bench pairs --pairs-only --ratio 2 4 " + "--image '" +
                          (samples() / "effects" / "window.jpg").string() + "' --max-side 160 --kernel levin:1 " +
                          "--crf gamma:2.2 --noise-profiles '" + excerpt().string() + "' -o '" + (dir / "out").string() + "'");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  std::ifstream in2(dir / "out" / "case1" / "truth.json"), in4(dir / "out" / "case2" / "truth.json");
  const nlohmann::json r2 = nlohmann::json::parse(in2), r4 = nlohmann::json::parse(in4);
  EXPECT_FALSE(r2.contains("regime"));  // the r = 1, 2 benches of RESULTS: sharp shot at ISO 800, 1/100 s
  EXPECT_EQ(*io::readExif(dir / "out" / "case1" / "sharp.jpg").iso, 800);
  EXPECT_EQ(r4.at("regime"), "real");
  EXPECT_EQ(r4.at("iso_sharp").get<double>(), 400);
}

}  // namespace
}  // namespace crfcal::test
