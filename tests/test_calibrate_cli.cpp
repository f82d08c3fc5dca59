// crfcal calibrate: end-to-end on the bundled pair, and bad input → one clear line, non-zero exit, no DIR.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/simulation.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {
namespace fs = std::filesystem;

std::string bin() { return test::crfcalBinary().string(); }
fs::path pairDir() { return test::samples() / "pairs"; }

void expectCleanFailure(const test::CommandResult& r, const fs::path& out, const std::string& needle) {
  EXPECT_NE(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("crfcal: error:"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find(needle), std::string::npos) << r.output;
  EXPECT_FALSE(fs::exists(out)) << "partial output left behind";
}

// Writes a JPEG with EXIF.
void writeShot(const fs::path& path, const cv::Mat& image, double iso, double t, const std::string& model = "test") {
  cv::imwrite(path.string(), image);
  ExifExposure e;
  e.iso = iso;
  e.exposure_time = t;
  e.f_number = 4;
  e.make = "crfcal";
  e.model = model;
  io::writeExif(path, e);
}

std::vector<double> truthCurve() {
  std::ifstream in(pairDir() / "truth.json");
  return nlohmann::json::parse(in)["inverse_crf"].get<std::vector<double>>();
}

double rmse(const std::vector<double>& a, const std::vector<double>& b) {
  double s = 0;
  for (size_t i = 0; i < a.size(); ++i) s += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(s / a.size());
}

TEST(CalibrateCli, BundledPairWithKnownKernel) {
  ASSERT_TRUE(fs::exists(pairDir() / "sharp.jpg")) << "bundled pair missing";
  test::TempDir dir;
  const auto r = test::run(bin() + " calibrate -q " + (pairDir() / "sharp.jpg").string() + " " +
                           (pairDir() / "blurred.jpg").string() + " --channels g --rounds 0 --kernel " +
                           (test::samples() / "levin09" / "kernel03.txt").string() + " -o " + (dir / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* f : {"report.json", "inverse_crf.csv", "kernel.png", "curve.png", "gamma_map.png", "weights.png"})
    EXPECT_TRUE(fs::exists(dir / "out" / f)) << f;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  EXPECT_EQ(report["inverse_crf"]["G"].size(), 1024u);
  EXPECT_FALSE(report["inverse_crf"].contains("R"));
  EXPECT_NEAR(report["exposure_ratio"]["exif"].get<double>(), 1.0375, 0.01);
  EXPECT_EQ(report["exposure_ratio"]["nominal"], report["exposure_ratio"]["exif"]);
  EXPECT_EQ(report["exposure_ratio"]["nominal_source"], "exif");
  EXPECT_TRUE(report["effects"].is_array());
  // OpenCV wrote the pair with 4:2:0 chroma: recorded; no warning about R and B when only G is fitted.
  EXPECT_EQ(report["input"]["chroma_subsampling"]["sharp"].get<std::string>(), "4:2:0");
  EXPECT_EQ(report["input"]["chroma_subsampling"]["blurred"].get<std::string>(), "4:2:0");
  for (const auto& w : report["warnings"]) EXPECT_EQ(w.get<std::string>().find("chroma"), std::string::npos) << w;
}

// The main job end to end on the bundled semi-real pair (real photo, measured curve, Levin kernel, handheld shift
// and rotation, noise, JPEG, EXIF): the kernel AND the registration unknown.
TEST(CalibrateCli, BundledPairEstimatedKernel) {
  ASSERT_TRUE(fs::exists(pairDir() / "sharp.jpg")) << "bundled pair missing";
  test::TempDir dir;
  const auto r = test::run(bin() + " calibrate " + (pairDir() / "sharp.jpg").string() + " " +
                           (pairDir() / "blurred.jpg").string() + " --channels g -o " + (dir / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  for (const char* stage : {"decode", "register", "kernel", "fit", "write"})
    EXPECT_NE(r.output.find(std::string(stage) + " done in"), std::string::npos) << stage << "\n" << r.output;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  const auto phi = report["inverse_crf"]["G"].get<std::vector<double>>();
  ASSERT_EQ(phi.size(), 1024u);
  EXPECT_LT(rmse(phi, truthCurve()), 0.02);
  EXPECT_NEAR(report["exposure_ratio"]["fitted"].get<double>(), 1.0, 0.03);  // truth 1.0, EXIF 1.04
  EXPECT_TRUE(report["kernel"]["estimated"].get<bool>());
  EXPECT_LT(report["kernel"]["border_mass"].get<double>(), 0.04);
  EXPECT_GE(report["rounds"].size(), 2u);
  for (const char* key : {"models", "pixels_used", "timings", "warnings", "effects", "registration", "covered_range"})
    EXPECT_TRUE(report.contains(key)) << key;
  EXPECT_TRUE(report["timings"].contains("register") && report["timings"].contains("kernel") &&
              report["timings"].contains("fit"));
}

// One shot held in portrait, the other in landscape: the sharp one is turned, not rejected.
TEST(CalibrateCli, PortraitAgainstLandscapeIsTurned) {
  ASSERT_TRUE(fs::exists(pairDir() / "sharp.jpg")) << "bundled pair missing";
  test::TempDir dir;
  cv::Mat sharp = cv::imread((pairDir() / "sharp.jpg").string());
  cv::rotate(sharp, sharp, cv::ROTATE_90_COUNTERCLOCKWISE);
  cv::imwrite((dir / "portrait.png").string(), sharp);
  cv::Mat blurred = cv::imread((pairDir() / "blurred.jpg").string());
  cv::imwrite((dir / "landscape.png").string(), blurred);
  const auto r = test::run(bin() + " calibrate -q " + (dir / "portrait.png").string() + " " +
                           (dir / "landscape.png").string() + " --ratio 1.04 --blurred second --channels g --rounds 0 -o " +
                           (dir / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("was turned by"), std::string::npos) << r.output;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  EXPECT_LT(rmse(report["inverse_crf"]["G"].get<std::vector<double>>(), truthCurve()), 0.03);
}

TEST(CalibrateCli, FixRatioKeepsTheGivenRatio) {
  ASSERT_TRUE(fs::exists(pairDir() / "sharp.jpg")) << "bundled pair missing";
  test::TempDir dir;
  const auto r = test::run(bin() + " calibrate -q " + (pairDir() / "sharp.jpg").string() + " " +
                           (pairDir() / "blurred.jpg").string() + " --channels g --rounds 0 --ratio 1.2 --fix-ratio -o " +
                           (dir / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  EXPECT_DOUBLE_EQ(report["exposure_ratio_per_channel"]["G"].get<double>(), 1.2);
  // r given on the command line: the nominal ratio says so, and "exif" (EXIF's r) is not written.
  EXPECT_DOUBLE_EQ(report["exposure_ratio"]["nominal"].get<double>(), 1.2);
  EXPECT_EQ(report["exposure_ratio"]["nominal_source"], "--ratio");
  EXPECT_FALSE(report["exposure_ratio"].contains("exif"));
  EXPECT_NE(r.output.find("exposure ratio: given 1.2"), std::string::npos) << r.output;
}

// The irradiance-domain kernel rounds' ablation flags reach the pipeline (the weights and λ change the round's kernel),
// and a negative λ is a command-line error.
TEST(CalibrateCli, KernelRoundAblationFlags) {
  ASSERT_TRUE(fs::exists(pairDir() / "sharp.jpg")) << "bundled pair missing";
  test::TempDir dir;
  const std::string pair = (pairDir() / "sharp.jpg").string() + " " + (pairDir() / "blurred.jpg").string();
  auto roundKernel = [&](const std::string& flags, const std::string& name) {
    const auto r = test::run(bin() + " calibrate -q " + pair + " --channels g --rounds 1 --no-effects " + flags +
                             " -o " + (dir / name).string());
    EXPECT_EQ(r.exit_code, 0) << r.output;
    std::ifstream in(dir / name / "kernel.txt");
    std::vector<double> k{std::istream_iterator<double>(in), std::istream_iterator<double>()};
    return k;
  };
  const auto weighted = roundKernel("", "weighted");
  const auto unweighted = roundKernel("--unweighted-irradiance-kernel --irradiance-kernel-lambda 0.03", "unweighted");
  ASSERT_EQ(weighted.size(), unweighted.size());
  ASSERT_FALSE(weighted.empty());
  double difference = 0;
  for (std::size_t i = 0; i < weighted.size(); ++i) difference += std::abs(weighted[i] - unweighted[i]);
  EXPECT_GT(difference, 0.01);  // L1 distance of two kernels that each sum to 1
  const auto bad = test::run(bin() + " calibrate -q " + pair + " --irradiance-kernel-lambda -1 -o " + (dir / "bad").string());
  EXPECT_EQ(bad.exit_code, 2) << bad.output;
  EXPECT_FALSE(fs::exists(dir / "bad"));
  PairCalibrationOptions options;
  options.irradiance_kernel_lambda = -0.1;
  EXPECT_THROW(options.check(), InvalidInput);
}

TEST(CalibrateCli, MissingFile) {
  test::TempDir dir;
  const auto r = test::run(bin() + " calibrate /nonexistent/a.jpg /nonexistent/b.jpg -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "/nonexistent/a.jpg");
}

TEST(CalibrateCli, CorruptJpeg) {
  test::TempDir dir;
  {
    std::ofstream out(dir / "bad.jpg", std::ios::binary);
    out << "\xFF\xD8\xFF\xE0 this is not really a jpeg";
  }
  cv::imwrite((dir / "ok.jpg").string(), cv::Mat(64, 64, CV_8UC3, cv::Scalar(1, 2, 3)));
  const auto r = test::run(bin() + " calibrate " + (dir / "bad.jpg").string() + " " + (dir / "ok.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "bad.jpg");
}

TEST(CalibrateCli, DirectoryInsteadOfImage) {
  test::TempDir dir;
  fs::create_directories(dir / "notanimage.jpg");
  cv::imwrite((dir / "ok.jpg").string(), cv::Mat(64, 64, CV_8UC3, cv::Scalar(1, 2, 3)));
  const auto r = test::run(bin() + " calibrate " + (dir / "notanimage.jpg").string() + " " + (dir / "ok.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "notanimage.jpg");
}

TEST(CalibrateCli, EmptyFile) {
  test::TempDir dir;
  { std::ofstream out(dir / "empty.jpg"); }
  cv::imwrite((dir / "ok.jpg").string(), cv::Mat(64, 64, CV_8UC3, cv::Scalar(1, 2, 3)));
  const auto r = test::run(bin() + " calibrate " + (dir / "ok.jpg").string() + " " + (dir / "empty.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "empty.jpg");
}

TEST(CalibrateCli, DifferentCameras) {
  test::TempDir dir;
  writeShot(dir / "a.jpg", test::levinImage(1) * 255, 800, 0.01, "body one");
  writeShot(dir / "b.jpg", test::levinImage(1) * 255, 100, 0.08, "body two");
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "different cameras");
}

TEST(CalibrateCli, CorruptRaw) {
  test::TempDir dir;
  {
    std::ofstream out(dir / "bad.nef", std::ios::binary);
    out << "II*\0garbage garbage garbage";
  }
  const auto r = test::run(bin() + " calibrate " + (dir / "bad.nef").string() + " " + (dir / "bad.nef").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "bad.nef");
  // An existing output directory is left as it was (replaced only by a complete result).
  fs::create_directories(dir / "previous");
  { std::ofstream(dir / "previous" / "keep.txt") << "old"; }
  const auto again = test::run(bin() + " calibrate " + (dir / "bad.nef").string() + " " + (dir / "bad.nef").string() +
                               " -o " + (dir / "previous").string());
  EXPECT_NE(again.exit_code, 0);
  EXPECT_TRUE(fs::exists(dir / "previous" / "keep.txt"));
  EXPECT_FALSE(fs::exists(dir / "previous" / "report.json"));
}

TEST(CalibrateCli, DifferentSizes) {
  test::TempDir dir;
  const cv::Mat a = test::levinImage(1) * 255, b = test::levinImage(2) * 255;
  cv::Mat small;
  cv::resize(b, small, cv::Size(200, 150));
  writeShot(dir / "a.jpg", a, 800, 0.01);
  writeShot(dir / "b.jpg", small, 100, 0.08);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "differ in size");
}

TEST(CalibrateCli, NoExifWithoutRatio) {
  test::TempDir dir;
  cv::imwrite((dir / "a.png").string(), test::levinImage(1) * 255);
  cv::imwrite((dir / "b.png").string(), test::levinImage(1) * 127);  // not pixel-identical (pair_checks.hpp)
  const auto r = test::run(bin() + " calibrate " + (dir / "a.png").string() + " " + (dir / "b.png").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "--ratio");
}

TEST(CalibrateCli, NonOverlappingPair) {
  test::TempDir dir;
  writeShot(dir / "a.jpg", test::levinImage(1) * 255, 800, 0.01);
  writeShot(dir / "b.jpg", test::levinImage(3) * 255, 100, 0.08);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "does not overlap");
}

// Two unrelated scenes: refused as such after the alignment (issue 15), not sent on to a kernel that grows to its
// size limit. --no-register: Levin's images do not even register, and the test must reach the scene check.
TEST(CalibrateCli, DifferentScenesAreRefused) {
  test::TempDir dir;
  cv::Mat blurred;
  cv::filter2D(test::levinImage(3), blurred, -1, test::levinKernel(2), cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  writeShot(dir / "a.jpg", test::levinImage(1) * 255, 800, 0.01);
  writeShot(dir / "b.jpg", blurred * 255, 100, 0.08);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " --no-register -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "the two images do not show the same scene");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  // A pair problem names both files.
  EXPECT_NE(r.output.find((dir / "a.jpg").string() + ", " + (dir / "b.jpg").string() + ":"), std::string::npos)
      << r.output;
}

TEST(CalibrateCli, AMaxKernelSizeBelowTheKernelSizeIsRefusedAndWritesNothing) {
  test::TempDir dir;
  const fs::path pairs = test::samples() / "pairs";
  const auto r = test::run(bin() + " calibrate " + (pairs / "sharp.jpg").string() + " " +
                           (pairs / "blurred.jpg").string() + " --kernel-size 41 --max-kernel-size 35 -o " +
                           (dir / "out").string());
  expectCleanFailure(r, dir / "out", "--max-kernel-size 35 must be 0 (automatic) or odd and at least --kernel-size");
}

// A grey pair given as aligned, one kernel estimate, no rounds, no effects: the pair checks and the kernel stage only.
PairCalibrationOptions quickGreyPairOptions() {
  PairCalibrationOptions options;
  options.register_pair = false;
  options.rgb = false;
  options.rounds = 0;
  options.effects.enabled = false;
  return options;
}

// The same scene, blurred: the same-scene correlation stays far above its threshold (the refusal above is not a
// refusal of every --no-register pair).
TEST(CalibratePairChecks, SameSceneBlurredPasses) {
  cv::Mat blurred;
  cv::filter2D(test::levinImage(1), blurred, -1, test::levinKernel(2), cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  cv::Mat sharp8, blurred8;
  test::levinImage(1).convertTo(sharp8, CV_8U, 255);
  blurred.convertTo(blurred8, CV_8U, 255);
  EXPECT_NO_THROW(calibratePair(sharp8, blurred8, quickGreyPairOptions()));
}

TEST(CalibrateCli, EdgelessPair) {
  test::TempDir dir;
  cv::Mat flat(200, 200, CV_8UC3, cv::Scalar(120, 120, 120));
  writeShot(dir / "a.jpg", flat, 800, 0.01);
  writeShot(dir / "b.jpg", flat * 0.5, 100, 0.08);  // not pixel-identical: that is refused first
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " --no-register -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "edges");
  // With registration too: "no edges", not "does not overlap".
  const auto registered = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                                    " -o " + (dir / "out").string());
  expectCleanFailure(registered, dir / "out", "no edges");
}

// A night scene: the short exposure black over most of the frame leaves the kernel no edges, and the message says
// where the pixels went (the sharp shot's black share), not only "too little texture".
TEST(CalibratePairChecks, KernelFailureNamesTheSharpShotsBlackShare) {
  cv::Mat sharp = test::levinImage(1).clone();
  cv::Mat night = cv::Mat::zeros(sharp.size(), sharp.type());
  const cv::Rect lit(sharp.cols / 2 - 12, sharp.rows / 2 - 12, 24, 24);  // one small lit window
  sharp(lit).copyTo(night(lit));
  cv::Mat blurred;
  cv::filter2D(night, blurred, -1, test::levinKernel(2), cv::Point(-1, -1), 0, cv::BORDER_CONSTANT);
  cv::Mat sharp8, blurred8;
  night.convertTo(sharp8, CV_8U, 255);
  blurred.convertTo(blurred8, CV_8U, 255);
  PairCalibrationOptions options = quickGreyPairOptions();
  options.fit.nominal_ratio = 1;
  try {
    calibratePair(sharp8, blurred8, options);
    FAIL() << "a frame black but for a 24 px window has no edges for a 35 px kernel";
  } catch (const InvalidInput& e) {
    const std::string message = e.what();
    const std::size_t at = message.find("the sharp shot is black over ");
    ASSERT_NE(at, std::string::npos) << message;
    const int black = std::stoi(message.substr(at + std::string("the sharp shot is black over ").size()));
    EXPECT_GE(black, 90) << message;  // 99.4 % of the frame is outside the lit window
    EXPECT_NE(message.find("usable: "), std::string::npos) << message;
  }
}

// Levin's image 1 blurred by Levin's kernel 8 scaled 2.2× (a 32 x 42 px trajectory, wider than the default 35 px
// kernel), both 8-bit.
void largeBlurPair(cv::Mat& sharp8, cv::Mat& blurred8) {
  cv::Mat kernel;
  cv::resize(test::levinKernel(8), kernel, cv::Size(), 2.2, 2.2, cv::INTER_LINEAR);
  kernel /= cv::sum(kernel)[0];
  cv::Mat blurred;
  cv::filter2D(test::levinImage(1), blurred, -1, kernel, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  test::levinImage(1).convertTo(sharp8, CV_8U, 255);
  blurred.convertTo(blurred8, CV_8U, 255);
}

// A blur wider than the default 35 px limit: the first estimate reaches the limit and is made again 1.5× larger, so
// the pair calibrates and says so; with no growth allowed (max_kernel_size = kernel_size) it stops at the limit as
// before.
TEST(CalibratePairChecks, AKernelAtItsSizeLimitGrowsUntilTheBlurFits) {
  cv::Mat sharp8, blurred8;
  largeBlurPair(sharp8, blurred8);
  PairCalibrationOptions options = quickGreyPairOptions();
  options.fit.nominal_ratio = 1;
  options.rounds = 2;  // the kernel <-> phi rounds settle r at the grown size
  const PairCalibrationResult grown = calibratePair(sharp8, blurred8, options);
  EXPECT_EQ(grown.kernel.kernel.cols, 53);  // 35 → 53 (a quarter of the 255 px side is 63)
  bool said = false;
  for (const auto& w : grown.warnings) said |= w.find("the blur is large") != std::string::npos;
  EXPECT_TRUE(said);
  EXPECT_NEAR(grown.fits.at("G").ratio, 1, 0.05);
  EXPECT_EQ(grown.kernel_grown_to, 53);
  const ChannelVerdict& verdict = grown.verdicts.at("G");
  EXPECT_NE(verdict.level, VerdictLevel::ok) << verdict.summary();  // at most weak: measured, RESULTS#kernel-growth
  bool named = false;
  for (const auto& reason : verdict.reasons)
    named |= reason.find("outgrew the kernel's 35 px limit") != std::string::npos;
  EXPECT_TRUE(named) << verdict.summary();
  options.rounds = 0;
  options.max_kernel_size = options.kernel.kernel_size;
  try {
    calibratePair(sharp8, blurred8, options);
    FAIL() << "a 42 px blur fitted a 35 px kernel";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("size limit"), std::string::npos) << e.what();
  }
  options.max_kernel_size = 34;  // even
  EXPECT_THROW(options.check(), InvalidInput);
}

// A growth capped below the blur (35 → 37 px for a 42 px trajectory) stops, and the stop names the size the
// kernel reached, not the size it started at.
TEST(CalibratePairChecks, AGrowthThatReachesItsCapStopsNamingTheSizeReached) {
  cv::Mat sharp8, blurred8;
  largeBlurPair(sharp8, blurred8);
  PairCalibrationOptions options = quickGreyPairOptions();
  options.fit.nominal_ratio = 1;
  options.rounds = 0;
  options.max_kernel_size = 37;
  try {
    calibratePair(sharp8, blurred8, options);
    FAIL() << "a 42 px blur fitted a 37 px kernel";
  } catch (const InvalidInput& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find("size limit (37x37 px"), std::string::npos) << message;
    EXPECT_EQ(message.find("35x35"), std::string::npos) << message;
  }
}

// A night pair in the real regime (samples/pairs/night: St. Louis at night, r = 8, see its PROVENANCE): the short
// exposure is black over 66 % of the overlap and the long one clipped over 9 %, which left the kernel no window whose
// pixels were all usable. The estimate works on gradients, where a black region is flat (the estimator drops flat
// windows) and an edge into black loses only the black threshold of its step: with the black admitted the kernel
// comes out, r is right, and the verdict says what the kernel rests on (weak, never ok).
TEST(CalibratePairChecks, NightPairsKernelIsEstimatedWithTheSharpShotsBlackAdmitted) {
  const fs::path dir = test::samples() / "pairs" / "night";
  const io::LoadedPair pair = io::loadPair(dir / "sharp.jpg", dir / "blurred.jpg");
  ASSERT_TRUE(pair.exif_ratio.has_value());
  std::ifstream truth_file(dir / "truth.json");
  const nlohmann::json truth = nlohmann::json::parse(truth_file);
  PairCalibrationOptions options;
  options.band.replicates = 0;
  options.effects.enabled = false;
  options.fit.nominal_ratio = pair.exif_ratio->ratio();
  const PairCalibrationResult result = calibratePair(pair.sharp.image, pair.blurred.image, options);
  ASSERT_TRUE(result.kernel_estimated);
  EXPECT_GT(result.kernel_sharp_black_admitted, 0.5);
  EXPECT_NEAR(result.fits.at("G").ratio / truth.at("exposure_ratio").get<double>(), 1, 0.05);
  for (const auto& [name, verdict] : result.verdicts) {
    EXPECT_NE(verdict.level, VerdictLevel::ok) << name;
    bool named = false;
    for (const auto& reason : verdict.reasons) named |= reason.find("black areas admitted") != std::string::npos;
    EXPECT_TRUE(named) << name << ": " << verdict.summary();
  }
}

TEST(CalibrateCli, SaturatedFrames) {
  test::TempDir dir;
  const cv::Mat sharp = test::levinImage(1) * 255;
  const cv::Mat white(sharp.size(), CV_8U, cv::Scalar(255));
  writeShot(dir / "a.jpg", sharp, 800, 0.01);
  writeShot(dir / "b.jpg", white, 100, 0.08);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "saturated");
}

// The typed error subject: a saturated blurred shot is blamed on its own file, not on the pair.
TEST(CalibrateCli, SaturatedBlurredShotNamesItsFile) {
  test::TempDir dir;
  const cv::Mat white(test::levinImage(1).size(), CV_8U, cv::Scalar(255));
  writeShot(dir / "a.jpg", test::levinImage(1) * 255, 800, 0.01);
  writeShot(dir / "b.jpg", white, 100, 0.08);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "crfcal: error: " + (dir / "b.jpg").string() + ": the blurred image is saturated");
}

TEST(CalibrateCli, KernelHitsSizeLimit) {
  test::TempDir dir;
  const cv::Mat sharp = test::levinImage(2);
  cv::Mat blurred;
  cv::GaussianBlur(sharp, blurred, cv::Size(0, 0), 6.0);
  writeShot(dir / "a.png", sharp * 255, 100, 0.01);
  writeShot(dir / "b.png", blurred * 255, 100, 0.01);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.png").string() + " " + (dir / "b.png").string() +
                           " --blurred second --no-register --kernel-size 7 --max-kernel-size 7 -o " +
                           (dir / "out").string());
  expectCleanFailure(r, dir / "out", "size limit (7x7 px");
  EXPECT_NE(r.output.find("try a larger --max-kernel-size"), std::string::npos) << r.output;
}


// ---- --raw-truth: the RAW (linear data) of one shot of the pair -------------------------------------------------

// A small colour pair with a known response φ = x^2.2 (ψ = e^(1/2.2)), r = 1, Levin kernel 3, and the linear
// irradiance of both shots as 16-bit PNGs framed like LibRaw output against a camera JPEG (1.25x larger, offset).
struct TruthPair {
  fs::path sharp, blurred, sharp_linear, blurred_linear;
};

cv::Mat framedLikeRaw(const cv::Mat& linear) {
  // 1.25x the JPEG's size, shifted by (7, 5) px, in a 16-bit frame with a margin (sensor border).
  cv::Mat A = (cv::Mat_<double>(2, 3) << 1.25, 0, 7, 0, 1.25, 5);
  cv::Mat out;
  cv::warpAffine(linear, out, A, cv::Size(int(linear.cols * 1.25) + 14, int(linear.rows * 1.25) + 10), cv::INTER_CUBIC,
                 cv::BORDER_REFLECT);
  cv::Mat out16;
  out.convertTo(out16, CV_16U, 65535.0);
  return out16;
}

TruthPair makeTruthPair(const fs::path& dir) {
  const cv::Mat grey = test::levinImage(1);
  cv::Mat base;
  cv::pow(grey, 2.2, base);
  base = 0.03 + 0.8 * base;
  std::vector<cv::Mat> planes{0.75 * base, 0.95 * base, 1.0 * base};  // B, G, R gains: a warm, non-grey scene
  cv::Mat E;
  cv::merge(planes, E);
  const cv::Mat EB = crfcal::convolve(E, test::levinKernel(3));  // crfcal's convention: convolution, not filter2D's correlation
  std::mt19937 rng(7);
  std::normal_distribution<double> unit(0.0, 1.0);
  auto render = [&](const cv::Mat& e, double noise) {
    cv::Mat out(e.size(), CV_8UC3);
    for (int y = 0; y < e.rows; ++y)
      for (int x = 0; x < e.cols; ++x)
        for (int c = 0; c < 3; ++c) {
          const double v = std::clamp(e.at<cv::Vec3d>(y, x)[c] + noise * unit(rng), 0.0, 1.0);
          out.at<cv::Vec3b>(y, x)[c] = cv::saturate_cast<uchar>(255 * std::pow(v, 1 / 2.2));
        }
    return out;
  };
  TruthPair p{dir / "sharp.jpg", dir / "blurred.jpg", dir / "sharp_linear.png", dir / "blurred_linear.png"};
  writeShot(p.sharp, render(E, 0.004), 800, 0.01);
  writeShot(p.blurred, render(EB, 0.001), 100, 0.08);
  cv::imwrite(p.sharp_linear.string(), framedLikeRaw(E));
  cv::imwrite(p.blurred_linear.string(), framedLikeRaw(EB));
  return p;
}

std::string truthCommand(const TruthPair& p, const fs::path& out, const std::string& extra) {
  return bin() + " calibrate -q " + p.sharp.string() + " " + p.blurred.string() + " --kernel " +
         (test::samples() / "levin09" / "kernel03.txt").string() + " --rounds 0 " + extra + " -o " + out.string();
}

// φ against x^2.2 over the truth's covered range. The shape (scale-aligned RMSE) is what one shot's pixels determine;
// the normalisation φ(1) = 1 rests on the EMoR extrapolation above the brightest flat level (chart_calibration.hpp).
ChannelComparison againstGamma(const std::vector<double>& phi, const std::vector<double>& range) {
  std::vector<double> truth(phi.size());
  for (size_t i = 0; i < truth.size(); ++i) truth[i] = std::pow(double(i) / (truth.size() - 1), 2.2);
  return compareCurves(phi, truth, IntensityRange{range.at(0), range.at(1)});
}

TEST(CalibrateCli, RawTruthOfTheSharpShotIsReportedAndCompared) {
  test::TempDir dir;
  const TruthPair p = makeTruthPair(dir.path());
  const auto r = test::run(truthCommand(p, dir / "out", "--raw-truth " + p.sharp_linear.string()));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("pair phi vs RAW truth"), std::string::npos) << r.output;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  ASSERT_TRUE(report.contains("raw_truth")) << report.dump(1);
  const auto& truth = report["raw_truth"];
  EXPECT_EQ(truth["file"].get<std::string>(), p.sharp_linear.string());
  EXPECT_EQ(truth["shot"].get<std::string>(), "sharp");  // the linear PNG has no EXIF: the default
  bool chroma_warning = false;  // OpenCV's JPEGs are 4:2:0: R and B are flagged
  for (const auto& w : report["warnings"]) chroma_warning |= w.get<std::string>().find("(4:2:0): JPEG chroma subsampled") != std::string::npos;
  EXPECT_TRUE(chroma_warning) << report["warnings"].dump();
  EXPECT_FALSE(truth["camera_raw"].get<bool>());
  for (const char* c : {"R", "G", "B"}) {
    const auto phi = truth["inverse_crf"][c].get<std::vector<double>>();
    ASSERT_EQ(phi.size(), 1024u) << c;
    const auto range = truth["covered_range"][c].get<std::vector<double>>();
    ASSERT_EQ(range.size(), 2u);
    EXPECT_LT(range[0], 0.3) << c;
    EXPECT_GT(range[1], 0.65) << c;
    // The truth recovers the response that made the JPEG, through the geometric difference and the noise.
    const ChannelComparison shape = againstGamma(phi, range);
    EXPECT_LT(shape.rmse_covered_aligned, 0.005) << c;
    EXPECT_LT(shape.rmse_covered, 0.04) << c;
    EXPECT_GT(truth["channels"][c]["explained_variance"].get<double>(), 0.98) << c;
    const auto& cmp = truth["comparison"][c];
    for (const char* key : {"rmse", "rmse_covered", "rmse_covered_aligned", "max_error"})
      EXPECT_TRUE(cmp[key].is_number() && std::isfinite(cmp[key].get<double>())) << c << " " << key;
    // The comparison is the pair's φ against this truth: recompute one number from the report itself.
    const auto pair_phi = report["inverse_crf"][c].get<std::vector<double>>();
    EXPECT_NEAR(cmp["rmse"].get<double>(), rmse(pair_phi, phi), 1e-6) << c;
    // And the pair itself, blurred by the kernel it was given, recovers the same response.
    const ChannelComparison pair_shape = againstGamma(pair_phi, range);
    // (r = 1 leaves an affine freedom on the covered levels, fixed by extrapolation: a looser bound than the truth's.)
    EXPECT_LT(pair_shape.rmse_covered_aligned, 0.02) << c;
    EXPECT_LT(pair_shape.rmse_covered, 0.04) << c;
  }
  // 1.25x larger frame, offset: the registration found the scale.
  const auto H = truth["registration"]["matrix"].get<std::vector<double>>();
  ASSERT_EQ(H.size(), 9u);
  EXPECT_NEAR(H[0] * truth["registration"]["linear_scale"].get<double>(), 0.8, 0.02);
  EXPECT_TRUE(fs::exists(dir / "out" / "curve.png"));
}

TEST(CalibrateCli, RawTruthShotIsFoundByExif) {
  test::TempDir dir;
  const TruthPair p = makeTruthPair(dir.path());
  ExifExposure e;  // the blurred shot's settings
  e.iso = 100;
  e.exposure_time = 0.08;
  e.f_number = 4;
  e.make = "crfcal";
  e.model = "test";
  io::writeExif(p.blurred_linear, e);
  const auto r = test::run(truthCommand(p, dir / "out", "--channels g --raw-truth " + p.blurred_linear.string()));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  std::ifstream in(dir / "out" / "report.json");
  const auto report = nlohmann::json::parse(in);
  const auto& truth = report["raw_truth"];
  EXPECT_EQ(truth["shot"].get<std::string>(), "blurred") << truth["shot_reason"];
  EXPECT_FALSE(truth["inverse_crf"].contains("R"));  // --channels g: G only, like the pair
  const auto range = truth["covered_range"]["G"].get<std::vector<double>>();
  const ChannelComparison shape = againstGamma(truth["inverse_crf"]["G"].get<std::vector<double>>(), range);
  EXPECT_LT(shape.rmse_covered_aligned, 0.005);
  EXPECT_LT(shape.rmse_covered, 0.04);
  // A settings mismatch with both shots is an error naming the file.
  e.iso = 200;
  e.exposure_time = 0.02;
  io::writeExif(p.blurred_linear, e);
  const auto mismatch = test::run(truthCommand(p, dir / "out2", "--raw-truth " + p.blurred_linear.string()));
  expectCleanFailure(mismatch, dir / "out2", "matches neither shot");
  EXPECT_NE(mismatch.output.find(p.blurred_linear.string()), std::string::npos) << mismatch.output;
}

TEST(CalibrateCli, RawTruthBadInput) {
  test::TempDir dir;
  const TruthPair p = makeTruthPair(dir.path());
  const fs::path out = dir / "out";
  // Missing file.
  expectCleanFailure(test::run(truthCommand(p, out, "--raw-truth " + (dir / "missing.cr2").string())), out,
                     "missing.cr2: file not found");
  // Corrupt RAW.
  {
    std::ofstream bad(dir / "bad.nef", std::ios::binary);
    bad << "II*\0garbage garbage garbage";
  }
  expectCleanFailure(test::run(truthCommand(p, out, "--raw-truth " + (dir / "bad.nef").string())), out, "bad.nef");
  // A JPEG is not linear data.
  expectCleanFailure(test::run(truthCommand(p, out, "--raw-truth " + p.sharp.string())), out, "is a JPEG");
  // A rendered image taken for linear: the JPEG's own pixels as a PNG.
  cv::imwrite((dir / "rendered.png").string(), cv::imread(p.sharp.string()));
  expectCleanFailure(test::run(truthCommand(p, out, "--raw-truth " + (dir / "rendered.png").string())), out,
                     "looks non-linear");
  // Linear data of another scene.
  cv::Mat other;
  cv::pow(test::levinImage(3), 2.2, other);
  other.convertTo(other, CV_16U, 65535.0);
  cv::imwrite((dir / "other.png").string(), other);
  const auto r = test::run(truthCommand(p, out, "--raw-truth " + (dir / "other.png").string()));
  expectCleanFailure(r, out, "does not register with the JPEG");
  EXPECT_NE(r.output.find("other.png"), std::string::npos) << r.output;
}

// A 3-px blur (RMS radius 0.82 px) cannot separate φ^γ, r^γ from φ, r: when the images' r then disagrees with EXIF,
// r is held at the EXIF value unless asked.
TEST(CalibrateSmallBlur, RatioIsHeldAtExifUnlessAlwaysFitted) {
  SimulationOptions sim;
  sim.ratio = 2;
  sim.noise_variance = 1e-4;
  const SimulationResult pair = simulatePair(0.45 * test::levinImage(1), GammaModel{2.2}, boxKernel(3), sim);
  cv::Mat sharp, blurred;
  pair.sharp.convertTo(sharp, CV_8U, 255);
  pair.blurred.convertTo(blurred, CV_8U, 255);
  PairCalibrationOptions options;
  options.register_pair = false;
  options.rgb = false;
  options.effects.enabled = false;
  options.fit.nominal_ratio = 2.1;  // EXIF 5 % off
  const PairCalibrationResult held = calibratePair(sharp, blurred, options);
  EXPECT_TRUE(held.ratio_fixed_by_small_blur);
  EXPECT_GT(std::abs(held.ratio_images_small_blur / 2.1 - 1), options.small_blur_ratio_tolerance);
  EXPECT_DOUBLE_EQ(held.fits.at("G").ratio, 2.1);
  bool warned = false;
  for (const auto& w : held.warnings) warned |= w.find("held at 2.1") != std::string::npos;
  EXPECT_TRUE(warned);
  options.fix_ratio_when_blur_is_small = false;
  const PairCalibrationResult fitted = calibratePair(sharp, blurred, options);
  EXPECT_FALSE(fitted.ratio_fixed_by_small_blur);
  EXPECT_NE(fitted.fits.at("G").ratio, 2.1);
  // at r ≈ 1 the images give r by brightness alone (1^γ = 1): it agrees with EXIF and stays fitted
  SimulationOptions equal = sim;
  equal.ratio = 1;
  const SimulationResult same = simulatePair(0.9 * test::levinImage(1), GammaModel{2.2}, boxKernel(3), equal);
  same.sharp.convertTo(sharp, CV_8U, 255);
  same.blurred.convertTo(blurred, CV_8U, 255);
  options.fix_ratio_when_blur_is_small = true;
  options.fit.nominal_ratio = 1.04;
  const PairCalibrationResult unit = calibratePair(sharp, blurred, options);
  EXPECT_FALSE(unit.ratio_fixed_by_small_blur);
  EXPECT_NEAR(unit.fits.at("G").ratio, 1, 0.02);
  options.fit.nominal_ratio = 2.1;
  // a real blur keeps r free
  const SimulationResult big = simulatePair(0.45 * test::levinImage(1), GammaModel{2.2}, test::levinKernel(3), sim);
  big.sharp.convertTo(sharp, CV_8U, 255);
  big.blurred.convertTo(blurred, CV_8U, 255);
  options.fix_ratio_when_blur_is_small = true;
  const PairCalibrationResult free_r = calibratePair(sharp, blurred, options);
  EXPECT_GT(free_r.blur_radius, options.min_blur_radius);
  EXPECT_FALSE(free_r.ratio_fixed_by_small_blur);
  EXPECT_NE(free_r.fits.at("G").ratio, 2.1);
}

// vivo X6S pair i (noisy_i.jpg, blurred_i.jpg in dir) calibrated with default options but no band, r nominal from EXIF.
PairCalibrationResult calibrateVivoPairWithoutBand(const fs::path& dir, int i) {
  const std::string n = std::to_string(i);
  const io::LoadedPair pair = io::loadPair(dir / ("noisy_" + n + ".jpg"), dir / ("blurred_" + n + ".jpg"));
  if (!pair.exif_ratio) throw std::runtime_error("vivo pair " + n + " has no EXIF ratio");
  PairCalibrationOptions options;
  options.band.replicates = 0;
  options.fit.nominal_ratio = pair.exif_ratio->ratio();
  return calibratePair(pair.sharp.image, pair.blurred.image, options);
}

// The effect search's free exposure ratio is linearised at the pair's r; on the vivo X6S pair 3 (EXIF 6.25, the
// images' own r 1.96) it ran away to 0.0027 and the report named an exposure-ratio mismatch "r 0.0027". A ratio the
// fitter itself would not consider (crf_fitter.hpp) is not named; a named mismatch always carries one it would.
// (Since stop 50 no pair's free ratio runs away: the runaways followed the settle rounds of an offset named from a
// flattened φ re-fit, which the next test checks is no longer considered.)
TEST(CalibrateRealPairs, EffectSearchNamesNoExposureRatioOutsideTheFittersRange) {
  const fs::path dir = test::sharedData() / "pairs" / "vivo_x6s";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  for (int i = 1; i <= 3; ++i) {
    const std::string n = std::to_string(i);
    const PairCalibrationResult result = calibrateVivoPairWithoutBand(dir, i);
    const EffectEntry* entry = result.effects.find("exposure_ratio_mismatch");
    ASSERT_NE(entry, nullptr) << "pair " << n;
    const double free_ratio = entry->parameters.at("fitted_ratio");
    const bool in_range = free_ratio >= kMinExposureRatio && free_ratio <= kMaxExposureRatio;
    if (entry->detected) {
      EXPECT_TRUE(in_range) << "pair " << n << ": " << entry->detail;
    }
    if (!in_range) {
      EXPECT_FALSE(entry->detected) << "pair " << n << ": " << entry->detail;
      EXPECT_NE(entry->detail.find("not a ratio"), std::string::npos) << entry->detail;
    }
  }
}

// On the three vivo X6S pairs the effect search's linearised φ re-fits (four EMoR terms) go flat over the data:
// measured before stop 50, every level model's re-fit was nearly constant over 75–100 % of B's levels in some
// channel where the base fit's φ is not, and black_level_offset was named at z 53, 11 and 6 with a re-fitted φ equal
// to 0 up to x = 0.5 (its corrected refit then failed on every pair: "every pixel is saturated or censored"). A
// re-fit flat over the data shrinks the floored residuals with it: no explanation. With such re-fits not considered
// (the verdict's flat rule, flattenedChannel), no level effect and no ratio mismatch is named on these pairs; pairs
// 2 and 3's free r (2.0 and 1.8 against EXIF 6.25, the shots' brightness siding with EXIF) says why it is not one.
TEST(CalibrateRealPairs, PhonePairsNameNoEffectFromAPhiRefitFlatOverTheData) {
  const fs::path dir = test::sharedData() / "pairs" / "vivo_x6s";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  int ratio_flat = 0;
  for (int i = 1; i <= 3; ++i) {
    const std::string n = std::to_string(i);
    const PairCalibrationResult result = calibrateVivoPairWithoutBand(dir, i);
    for (const EffectEntry& e : result.effects.entries) {
      // Not level models: the noise law is on I itself, the varying blur a check of the kernel.
      if (e.name == "signal_dependent_noise" || e.name == "spatially_varying_blur") continue;
      EXPECT_FALSE(e.detected) << "pair " << n << ": " << e.name << ": " << e.detail;
    }
    const EffectEntry* ratio = result.effects.find("exposure_ratio_mismatch");
    ASSERT_NE(ratio, nullptr);
    ratio_flat += ratio->detail.find("phi re-fit is nearly constant over the data") != std::string::npos;
  }
  EXPECT_EQ(ratio_flat, 2) << "pairs 2 and 3's free r is no longer set aside for a flat re-fit";
}

// vivo X6S pair 1 (a 0.84 px blur): r is held at EXIF (3.125) by the small-blur rule, since the blur cannot separate
// φ^γ, r^γ from φ, r. The effect diagnostics' free r meets the same ambiguity (1.85 here, while the shots' brightness
// gives 3.7): it must not be named a mismatch, and its entry says why.
TEST(CalibrateRealPairs, RatioHeldForASmallBlurIsNotNamedAMismatch) {
  const fs::path dir = test::sharedData() / "pairs" / "vivo_x6s";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  const PairCalibrationResult result = calibrateVivoPairWithoutBand(dir, 1);
  ASSERT_TRUE(result.ratio_fixed_by_small_blur);
  const EffectEntry* ratio = result.effects.find("exposure_ratio_mismatch");
  ASSERT_NE(ratio, nullptr);
  EXPECT_FALSE(ratio->detected) << ratio->detail;
  EXPECT_NE(ratio->detail.find("blur is too small"), std::string::npos) << ratio->detail;
  const std::vector<std::string> named = result.effects.detected();
  EXPECT_EQ(std::count(named.begin(), named.end(), "exposure_ratio_mismatch"), 0);
}

// The effect table a user reads on the phone pairs: the noise contrast is a variance ratio the bins' σ can carry (it
// was extrapolated to 4.9e13 on pair 2's dark sharp shot), and a runaway vignetting or colour mix says so instead of
// printing a corner gain of 30 or a mix of "inf" as if measured.
TEST(CalibrateRealPairs, EffectTableNumbersAreMeasuredOrMarkedAsRunaways) {
  const fs::path dir = test::sharedData() / "pairs" / "vivo_x6s";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  for (int i = 1; i <= 3; ++i) {
    const std::string n = std::to_string(i);
    const PairCalibrationResult result = calibrateVivoPairWithoutBand(dir, i);
    const EffectEntry* noise = result.effects.find("signal_dependent_noise");
    ASSERT_TRUE(noise != nullptr && noise->tested) << "pair " << n;
    double lowest = 1e300, highest = 0;
    for (const auto& [key, value] : noise->parameters)
      if (key.rfind("sigma_", 0) == 0 && value > 0) lowest = std::min(lowest, value), highest = std::max(highest, value);
    ASSERT_GT(highest, 0) << "pair " << n;
    EXPECT_LE(noise->parameters.at("contrast"), 4 * (highest / lowest) * (highest / lowest))
        << "pair " << n << ": " << noise->detail;
    const EffectEntry* vignetting = result.effects.find("vignetting");
    ASSERT_NE(vignetting, nullptr);
    const double corner = vignetting->parameters.count("corner_gain") ? vignetting->parameters.at("corner_gain") : 1;
    if (vignetting->tested && !(corner > 0.1 && corner < 10)) {
      EXPECT_NE(vignetting->detail.find("not physical"), std::string::npos) << "pair " << n << ": " << vignetting->detail;
    }
    const EffectEntry* mixing = result.effects.find("channel_mixing");
    ASSERT_NE(mixing, nullptr);
    EXPECT_EQ(mixing->detail.find("inf"), std::string::npos) << "pair " << n << ": " << mixing->detail;
  }
}

// Real handheld pairs of one phone (../shared/data/pairs/vivo_x6s; skipped without it): the RMS spread of the three
// green curves over [0, 1] stays below 0.1. A regression guard, not the target (the three agreeing over [0, 1]),
// which is not met: docs/RESULTS.md#vivo.
// The three vivo pairs' green curves in SHAPE over the intensities all three cover (φ → bφ leaves Eq. 4 unchanged, so
// each curve is divided by its value at the top of that range): measured 0.035 with r from the evidence
// (ratio_evidence.hpp), 0.100 with the images' r alone (pairs 2 and 3 fitted r ≈ 2 against EXIF 6.25); the phone's
// own two-frame brackets (noisy + g_truth) spread 0.043 in the same measure (docs/RESULTS.md#ratio-evidence).
TEST(CalibrateRealPairs, PhonePairsGreenShapesAgreeOverTheCommonCoveredRange) {
  const fs::path dir = test::sharedData() / "pairs" / "vivo_x6s";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  std::vector<std::vector<double>> curves;
  double lo = 0, hi = 1;
  for (int i = 1; i <= 3; ++i) {
    const std::string n = std::to_string(i);
    const io::LoadedPair pair = io::loadPair(dir / ("noisy_" + n + ".jpg"), dir / ("blurred_" + n + ".jpg"));
    ASSERT_TRUE(pair.exif_ratio.has_value());
    PairCalibrationOptions options;
    options.rgb = false;
    options.band.replicates = 0;
    options.fit.nominal_ratio = pair.exif_ratio->ratio();
    const PairCalibrationResult result = calibratePair(pair.sharp.image, pair.blurred.image, options);
    curves.push_back(result.fits.at("G").inverse_crf);
    ASSERT_TRUE(result.covered_range.count("G"));
    lo = std::max(lo, result.covered_range.at("G").first);
    hi = std::min(hi, result.covered_range.at("G").second);
  }
  const int n = static_cast<int>(curves[0].size());
  const int i0 = static_cast<int>(std::ceil(lo * (n - 1))), i1 = static_cast<int>(hi * (n - 1));
  ASSERT_GT(i1 - i0, n / 4) << "the pairs share too little of the range";
  double spread = 0;
  for (int k = i0; k <= i1; ++k) {
    double v[3], mean = 0;
    for (int c = 0; c < 3; ++c) mean += (v[c] = curves[c][k] / curves[c][i1]) / 3;
    for (const double x : v) spread += (x - mean) * (x - mean) / 3;
  }
  spread = std::sqrt(spread / (i1 - i0 + 1));
  EXPECT_LT(spread, 0.06) << "common covered range " << lo << "-" << hi;
}

}  // namespace
}  // namespace crfcal
