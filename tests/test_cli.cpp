// The crfcal command line: --help/--version, simulate round trip, one-line errors and no partial output.
#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal::test {
namespace {
namespace fs = std::filesystem;

TEST(Cli, VersionAndHelp) {
  const auto version = run(quote(crfcalBinary()) + " --version");
  EXPECT_EQ(version.exit_code, 0);
  EXPECT_NE(version.output.find("crfcal "), std::string::npos);
  const auto help = run(quote(crfcalBinary()) + " --help");
  EXPECT_EQ(help.exit_code, 0);
  EXPECT_NE(help.output.find("simulate"), std::string::npos);
  const auto sim_help = run(quote(crfcalBinary()) + " simulate --help");
  EXPECT_EQ(sim_help.exit_code, 0);
  // every option is listed with its default
  EXPECT_NE(sim_help.output.find("--noise-var"), std::string::npos);
  EXPECT_NE(sim_help.output.find("gamma:2.2"), std::string::npos);
  const auto none = run(quote(crfcalBinary()));
  EXPECT_NE(none.exit_code, 0);
}

// The synthetic benchmark end to end on three of its cases (one per noise level): the JSON carries the seed's
// published means, one entry per case, and the error grows with the noise: the same cases with the variances
// read in 8-bit levels² (practically noise-free) come out more accurate, within 0.015 (240 cases: 0.006–0.008).
TEST(Cli, BenchSyntheticWritesItsTableAndNoiseHurts) {
  TempDir dir;
  double mean_error[2] = {0, 0};
  const char* units[2] = {"unit", "8bit"};
  for (int u = 0; u < 2; ++u) {
    const fs::path json_path = dir / (std::string(units[u]) + ".json");
    const auto result = run(quote(crfcalBinary()) + " bench synthetic -q --no-timing --method default --cases-limit 3 " +
                            "--threads 1 --noise-units " + units[u] + " --json " + quote(json_path));
    ASSERT_EQ(result.exit_code, 0) << result.output;
    EXPECT_NE(result.output.find("seed mean"), std::string::npos) << result.output;
    const auto json = readJson(json_path);
    EXPECT_EQ(json["noise_units"], units[u]);
    ASSERT_EQ(json["per_case"].size(), 3u);
    ASSERT_EQ(json["levels"].size(), 3u);
    EXPECT_DOUBLE_EQ(json["seed_published_mean_rmse"][0].get<double>(), 0.0155);
    for (const auto& level : json["levels"]) {
      const double e = level["mean_rmse"].get<double>();
      EXPECT_GT(e, 0.0);
      EXPECT_LT(e, 0.2);
      mean_error[u] += e / 3;
    }
  }
  EXPECT_LT(mean_error[1], mean_error[0]) << "[0,1] variances " << mean_error[0] << ", 8-bit " << mean_error[1];
  EXPECT_LT(mean_error[1], 0.015);
}

struct RoundTripCase {
  std::string crf;
  ResponseModel model;
};

TEST(Cli, SimulateRoundTripsTheRequestedCurve) {
  TempDir dir;
  const std::vector<RoundTripCase> cases = {
      {"gamma:2.2", GammaModel{2.2}},
      {"ggcm:0.42,0.15,-0.1,0.05,0.02", GgcmModel{{0.42, 0.15, -0.1, 0.05, 0.02}}},
      {"emor:0.5,-0.3,0.1", EmorModel{{0.5, -0.3, 0.1}}},
  };
  for (size_t i = 0; i < cases.size(); ++i) {
    const fs::path out = dir / ("sim" + std::to_string(i));
    const auto result = run(quote(crfcalBinary()) + " simulate -q --image " + quote(samples() / "levin09/im2.png") +
                            " --crf " + cases[i].crf + " --kernel levin:3 --ratio 0.9 -o " + quote(out));
    ASSERT_EQ(result.exit_code, 0) << result.output;
    for (const char* name : {"sharp.png", "blurred.png", "kernel.png", "truth.json"}) EXPECT_TRUE(fs::exists(out / name)) << name;
    const auto truth = readJson(out / "truth.json");
    const auto phi = truth["inverse_crf"].get<std::vector<double>>();
    ASSERT_EQ(phi.size(), 1024u);
    const auto expected = sampleInverse(cases[i].model);
    for (size_t j = 0; j < phi.size(); ++j) ASSERT_NEAR(phi[j], expected[j], 1e-6) << cases[i].crf << " at " << j;
    EXPECT_DOUBLE_EQ(truth["exposure_ratio"].get<double>(), 0.9);

    // The table form of the truth file round-trips too.
    const fs::path again = dir / ("again" + std::to_string(i));
    const auto second = run(quote(crfcalBinary()) + " simulate -q --image " + quote(samples() / "levin09/im2.png") +
                            " --crf table:" + quote(out / "truth.json") + " --kernel levin:3 -o " + quote(again));
    ASSERT_EQ(second.exit_code, 0) << second.output;
    const auto phi2 = readJson(again / "truth.json")["inverse_crf"].get<std::vector<double>>();
    for (size_t j = 0; j < phi2.size(); ++j) ASSERT_NEAR(phi2[j], expected[j], 1e-6);
  }
}

TEST(Cli, SimulatedBlurredImageFollowsTheIrradianceModel) {
  TempDir dir;
  const fs::path out = dir / "sim";
  const auto result = run(quote(crfcalBinary()) + " simulate -q --image " + quote(samples() / "levin09/im1.png") +
                          " --crf gamma:2.2 --kernel levin:2 --bits 16 -o " + quote(out));
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const cv::Mat sharp = io::readGrayUnit(out / "sharp.png");
  const cv::Mat blurred = io::readGrayUnit(out / "blurred.png");
  const cv::Mat kernel = io::kernelFromSpec("levin:2");
  const ResponseCurve curve(GammaModel{2.2});
  // Eq. 4 with r = 1 from the written sharp image: equal up to the 16-bit quantisation of both images
  const cv::Mat predicted = irradianceBlur(sharp, curve, kernel, 1.0);
  double max_error = 0;
  cv::minMaxLoc(cv::abs(predicted - blurred), nullptr, &max_error);
  EXPECT_LT(max_error, 2e-3);
  // ... while the intensity model is far off near edges
  double intensity_error = 0;
  cv::minMaxLoc(cv::abs(intensityBlur(sharp, kernel) - blurred), nullptr, &intensity_error);
  EXPECT_GT(intensity_error, 0.05);
}

// levin:N@S: Levin's kernel N scaled by S (a longer exposure's shake), odd-sided, normalised, its trajectory S× as
// long (the spread of its mass about its centroid); a scale outside 0.25 … 8 is refused naming the spec.
TEST(KernelSpec, ScaledLevinKernelKeepsItsShapeAtSTimesTheSize) {
  const cv::Mat base = io::kernelFromSpec("levin:8");
  const cv::Mat scaled = io::kernelFromSpec("levin:8@2.2");
  EXPECT_EQ(scaled.rows % 2, 1);
  EXPECT_EQ(scaled.cols % 2, 1);
  EXPECT_NEAR(scaled.cols, 2.2 * base.cols, 1.5);
  EXPECT_NEAR(cv::sum(scaled)[0], 1.0, 1e-9);
  const auto spread = [](const cv::Mat& k) {
    const cv::Point2d c = kernelCentroid(k);
    double s = 0;
    for (int y = 0; y < k.rows; ++y)
      for (int x = 0; x < k.cols; ++x) s += k.at<double>(y, x) * ((x - c.x) * (x - c.x) + (y - c.y) * (y - c.y));
    return std::sqrt(s);
  };
  EXPECT_NEAR(spread(scaled) / spread(base), 2.2, 0.15);
  EXPECT_THROW(io::kernelFromSpec("levin:8@9"), Error);
  EXPECT_THROW(io::kernelFromSpec("levin:8@x"), Error);
  EXPECT_THROW(io::kernelFromSpec("levin:9@2"), Error);
}

TEST(Cli, BadInputGivesOneLineAndNoOutput) {
  TempDir dir;
  const fs::path out = dir / "never";
  const std::string base = quote(crfcalBinary()) + " simulate -q -o " + quote(out);
  struct Case {
    std::string args;
    std::string needle;
  };
  std::ofstream(dir / "garbage.png") << "this is not a PNG file";
  std::ofstream(dir / "bad_kernel.txt") << "1 2\n3\n";
  std::ofstream(dir / "negative_kernel.txt") << "1 -2\n3 1\n";
  const std::vector<Case> cases = {
      {" --image " + quote(dir / "missing.png"), "missing.png"},
      {" --image " + quote(dir / "garbage.png"), "garbage.png"},
      {" --image " + quote(samples() / "levin09/im1.png") + " --crf ggcm:-1,0", "ggcm:-1,0"},
      {" --image " + quote(samples() / "levin09/im1.png") + " --crf banana:1", "banana"},
      {" --image " + quote(samples() / "levin09/im1.png") + " --kernel " + quote(dir / "bad_kernel.txt"), "bad_kernel.txt"},
      {" --image " + quote(samples() / "levin09/im1.png") + " --kernel " + quote(dir / "negative_kernel.txt"), "negative"},
      {" --image " + quote(samples() / "levin09/im1.png") + " --kernel levin:9", "levin:9"},
  };
  for (const auto& c : cases) {
    const auto result = run(base + c.args);
    EXPECT_NE(result.exit_code, 0) << c.args;
    EXPECT_NE(result.output.find(c.needle), std::string::npos) << c.args << " -> " << result.output;
    // one line (ignoring a trailing newline)
    std::string text = result.output;
    while (!text.empty() && text.back() == '\n') text.pop_back();
    EXPECT_EQ(text.find('\n'), std::string::npos) << result.output;
    EXPECT_FALSE(fs::exists(out)) << c.args;
  }
  // nothing half-written beside the output either
  for (const auto& entry : fs::directory_iterator(dir.path()))
    EXPECT_EQ(entry.path().filename().string().find("partial"), std::string::npos) << entry.path();
}

}  // namespace
}  // namespace crfcal::test
