// Hostile input, end to end through the crfcal binary: every case is generated here (truncations, byte flips, wrong
// sizes, NaN, forged headers, empty files, directories, unwritable paths) and must be refused with the documented
// exit code (1 input error, 2 command line) and one line naming the file and the real problem, with no output left.
#include <cmath>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <unistd.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "test_support.hpp"

namespace fs = std::filesystem;
using crfcal::test::TempDir;

namespace {

std::string command(const std::string& arguments) { return crfcal::test::crfcalBinary().string() + " " + arguments; }

std::string quoted(const fs::path& p) { return "'" + p.string() + "'"; }

std::vector<char> bytesOf(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void writeBytes(const fs::path& path, const std::vector<char>& bytes) {
  std::ofstream(path, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

void writeText(const fs::path& path, const std::string& text) { std::ofstream(path) << text; }

// Runs the command and checks the exit code, that stderr+stdout mention `reason`, that the error is one line and
// carries no raw non-ASCII byte, and that `output` (if given) was not created.
void expectRefused(const std::string& command, int exit_code, const std::string& reason, const fs::path& output = {}) {
  const auto result = crfcal::test::run(command);
  EXPECT_EQ(result.exit_code, exit_code) << command << "\n" << result.output;
  EXPECT_NE(result.output.find(reason), std::string::npos) << command << "\n" << result.output;
  int error_lines = 0;
  std::size_t at = 0;
  while ((at = result.output.find("error:", at)) != std::string::npos) {
    ++error_lines;
    ++at;
  }
  EXPECT_EQ(error_lines, 1) << result.output;
  for (const unsigned char c : result.output) EXPECT_LT(c, 0x80) << "raw byte in: " << result.output;
  if (!output.empty()) {
    EXPECT_FALSE(fs::exists(output)) << output;
  }
}

// A textured 8-bit colour image (edges everywhere), deterministic.
cv::Mat texture(int width, int height, double gain = 1.0) {
  cv::Mat image(height, width, CV_8UC3);
  cv::RNG rng(7);
  rng.fill(image, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(image, image, cv::Size(5, 5), 1.5);
  image.convertTo(image, CV_8U, gain);
  return image;
}

// 1024 samples of φ(x) = x^2.2, or `phi` as given.
std::string reportJson(const std::vector<double>& phi = {}) {
  std::vector<double> curve = phi;
  if (curve.empty())
    for (int i = 0; i < 1024; ++i) curve.push_back(std::pow(i / 1023.0, 2.2));
  nlohmann::json json;
  json["inverse_crf"] = {{"G", curve}};
  return json.dump();
}

const fs::path kSharp = crfcal::test::samples() / "pairs" / "sharp.jpg";
const fs::path kBlurred = crfcal::test::samples() / "pairs" / "blurred.jpg";

}  // namespace

// ---- calibrate: images -------------------------------------------------------------------------------------------

TEST(HostileCalibrate, TruncatedCameraJpegAt31000BytesIsRefusedAsTruncated) {
  TempDir dir;
  auto bytes = bytesOf(kSharp);
  ASSERT_GT(bytes.size(), 31000u);
  bytes.resize(31000);
  writeBytes(dir / "cut.jpg", bytes);
  expectRefused(command("calibrate -q " + quoted(dir / "cut.jpg") + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                1, "cut.jpg: truncated JPEG (premature end of data)", dir / "out");
}

TEST(HostileCalibrate, JpegCutAtHalfIsRefusedAsTruncated) {
  TempDir dir;
  auto bytes = bytesOf(kBlurred);
  bytes.resize(bytes.size() / 2);
  writeBytes(dir / "half.jpg", bytes);
  expectRefused(command("calibrate -q " + quoted(kSharp) + " " + quoted(dir / "half.jpg") + " -o " + quoted(dir / "out")),
                1, "half.jpg: truncated JPEG", dir / "out");
}

TEST(HostileCalibrate, SameFileTwiceIsRefusedAsIdentical) {
  TempDir dir;
  expectRefused(command("calibrate -q " + quoted(kSharp) + " " + quoted(kSharp) + " -o " + quoted(dir / "out")), 1,
                "the two images are identical", dir / "out");
}

TEST(HostileCalibrate, TwoIdenticalCopiesAreRefusedAsIdentical) {
  TempDir dir;
  fs::copy_file(kSharp, dir / "a.jpg");
  fs::copy_file(kSharp, dir / "b.jpg");
  expectRefused(command("calibrate -q " + quoted(dir / "a.jpg") + " " + quoted(dir / "b.jpg") + " -o " + quoted(dir / "out")),
                1, "the two images are identical", dir / "out");
}

TEST(HostileCalibrate, BlackSharpShotIsRefusedAsBlackNotAsNoOverlap) {
  TempDir dir;
  cv::imwrite((dir / "black.png").string(), cv::Mat::zeros(240, 320, CV_8UC3));
  cv::imwrite((dir / "blurred.png").string(), texture(320, 240));
  expectRefused(command("calibrate -q --blurred second --ratio 4 " + quoted(dir / "black.png") + " " +
                       quoted(dir / "blurred.png") + " -o " + quoted(dir / "out")),
                1, "black.png: the sharp image is black", dir / "out");
}

TEST(HostileCalibrate, UniformBlurredShotIsRefusedAsUniform) {
  TempDir dir;
  cv::imwrite((dir / "sharp.png").string(), texture(320, 240));
  cv::imwrite((dir / "grey.png").string(), cv::Mat(240, 320, CV_8UC3, cv::Scalar::all(128)));
  expectRefused(command("calibrate -q --blurred second --ratio 4 " + quoted(dir / "sharp.png") + " " +
                       quoted(dir / "grey.png") + " -o " + quoted(dir / "out")),
                1, "grey.png: the blurred image is uniform", dir / "out");
}

TEST(HostileCalibrate, PngHeaderClaiming60000SquaredIsRefusedAsTooLarge) {
  TempDir dir;
  cv::imwrite((dir / "small.png").string(), texture(16, 16));
  auto bytes = bytesOf(dir / "small.png");
  const unsigned char size[] = {0, 0, 0xEA, 0x60};  // 60000, big-endian
  for (int i = 0; i < 4; ++i) bytes[16 + i] = bytes[20 + i] = static_cast<char>(size[i]);
  writeBytes(dir / "huge.png", bytes);
  expectRefused(command("calibrate -q " + quoted(dir / "huge.png") + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                1, "huge.png: image too large (60000x60000", dir / "out");
}

TEST(HostileCalibrate, EmptyFileIsRefused) {
  TempDir dir;
  writeText(dir / "empty.jpg", "");
  expectRefused(command("calibrate -q " + quoted(dir / "empty.jpg") + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                1, "empty.jpg: file is empty", dir / "out");
}

TEST(HostileCalibrate, DirectoryGivenAsImageIsRefused) {
  TempDir dir;
  fs::create_directory(dir / "folder.jpg");
  expectRefused(command("calibrate -q " + quoted(dir / "folder.jpg") + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                1, "folder.jpg: is a directory", dir / "out");
}

TEST(HostileCalibrate, TextFileNamedJpgIsRefusedAsNotAnImage) {
  TempDir dir;
  writeText(dir / "notes.jpg", "these are not pixels\n");
  expectRefused(command("calibrate -q " + quoted(dir / "notes.jpg") + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                1, "notes.jpg: not a readable image", dir / "out");
}

TEST(HostileCalibrate, ImagesOfDifferentSizesAreRefused) {
  TempDir dir;
  cv::imwrite((dir / "a.png").string(), texture(320, 240));
  cv::imwrite((dir / "b.png").string(), texture(300, 200));
  expectRefused(command("calibrate -q " + quoted(dir / "a.png") + " " + quoted(dir / "b.png") + " -o " + quoted(dir / "out")),
                1, "the images differ in size", dir / "out");
}

TEST(HostileCalibrate, UnreadableImageIsRefusedWhenNotRoot) {
  if (geteuid() == 0) GTEST_SKIP() << "root reads files whatever their mode";
  TempDir dir;
  fs::copy_file(kSharp, dir / "locked.jpg");
  fs::permissions(dir / "locked.jpg", fs::perms::none);
  expectRefused(command("calibrate -q " + quoted(dir / "locked.jpg") + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                1, "locked.jpg", dir / "out");
}

// ---- calibrate: options ------------------------------------------------------------------------------------------

TEST(HostileCalibrate, HugeThreadCountIsACommandLineError) {
  TempDir dir;
  expectRefused(command("calibrate --threads 100000 " + quoted(kSharp) + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                2, "--threads", dir / "out");
}

TEST(HostileCalibrate, HugeExposureRatioIsACommandLineErrorWithTheRange) {
  TempDir dir;
  expectRefused(command("calibrate --ratio 1e9 " + quoted(kSharp) + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                2, "0.001 .. 1000", dir / "out");
}

TEST(HostileCalibrate, NegativeExposureRatioIsACommandLineError) {
  TempDir dir;
  expectRefused(command("calibrate --ratio -1 " + quoted(kSharp) + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                2, "0.001 .. 1000", dir / "out");
}

TEST(HostileCalibrate, NanExposureRatioIsACommandLineError) {
  TempDir dir;
  expectRefused(command("calibrate --ratio nan " + quoted(kSharp) + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                2, "--ratio", dir / "out");
}

TEST(HostileCalibrate, EvenKernelSizeIsACommandLineError) {
  TempDir dir;
  expectRefused(command("calibrate --kernel-size 4 " + quoted(kSharp) + " " + quoted(kBlurred) + " -o " + quoted(dir / "out")),
                2, "odd", dir / "out");
}

TEST(HostileCalibrate, ThreadsOnBenchAreBounded) {
  const auto result = crfcal::test::run(command("bench --threads 100000"));
  EXPECT_EQ(result.exit_code, 2) << result.output;
}

TEST(HostileSimulate, ExposureRatioOutOfRangeIsACommandLineError) {
  TempDir dir;
  expectRefused(command("simulate --image " + quoted(crfcal::test::samples() / "levin09" / "im1.png") +
                       " --crf gamma:2.2 --kernel levin:1 --ratio 1e9 -o " + quoted(dir / "out")),
                2, "0.001 .. 1000", dir / "out");
}

// ---- chart ---------------------------------------------------------------------------------------------------------

namespace {
// A rectified chart (6x4 patches of 65 px): a grey ramp per column, brighter with `gain`.
fs::path writeChart(const fs::path& path, double gain) {
  cv::Mat chart(4 * 65, 6 * 65, CV_8UC3);
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 6; ++c)
      chart(cv::Rect(c * 65, r * 65, 65, 65)).setTo(cv::Scalar::all(std::min(250.0, gain * (20 + 9 * (r * 6 + c)))));
  cv::imwrite(path.string(), chart);
  return path;
}
}  // namespace

TEST(HostileChart, NegativeAndNanExposuresAreRefused) {
  TempDir dir;
  std::string images;
  for (int i = 0; i < 4; ++i) images += quoted(writeChart(dir / ("c" + std::to_string(i) + ".png"), 0.3 + 0.2 * i)) + " ";
  expectRefused(command("chart -q " + images + "--exposures 1,-2,4,nan -o " + quoted(dir / "out")), 1,
                "positive finite", dir / "out");
}

TEST(HostileChart, ExposuresThatContradictTheImagesAreRefused) {
  TempDir dir;
  std::string images;
  for (int i = 0; i < 4; ++i) images += quoted(writeChart(dir / ("c" + std::to_string(i) + ".png"), 0.3 + 0.2 * i)) + " ";
  expectRefused(command("chart -q " + images + "--exposures 8,4,2,1 -o " + quoted(dir / "out")), 1,
                "must follow the order of the images", dir / "out");
}

TEST(HostileChart, CornersOutsideTheImageAreRefused) {
  TempDir dir;
  const fs::path chart = writeChart(dir / "chart.png", 1.0);
  expectRefused(command("chart -q " + quoted(chart) + " --corners 0,0,5000,0,5000,4000,0,4000 -o " + quoted(dir / "out")),
                1, "lies outside the image", dir / "out");
}

TEST(HostileChart, NanTruthTableIsRefused) {
  TempDir dir;
  const fs::path chart = writeChart(dir / "chart.png", 1.0);
  writeText(dir / "truth.csv", "0\n0.2\nnan\n1\n");
  expectRefused(command("chart -q " + quoted(chart) + " --truth " + quoted(dir / "truth.csv") + " -o " + quoted(dir / "out")),
                1, "truth.csv: not a valid inverse response", dir / "out");
}

TEST(HostileChart, NonMonotoneTruthTableIsRefused) {
  TempDir dir;
  const fs::path chart = writeChart(dir / "chart.png", 1.0);
  writeText(dir / "truth.csv", "0\n0.6\n0.3\n1\n");
  expectRefused(command("chart -q " + quoted(chart) + " --truth " + quoted(dir / "truth.csv") + " -o " + quoted(dir / "out")),
                1, "curve decreases", dir / "out");
}

// ---- multi-file input (several chart shots) ----------------------------------------------------------------------

TEST(HostileMultiFile, OneTruncatedShotAmongSeveralIsNamed) {
  TempDir dir;
  const fs::path a = writeChart(dir / "a.png", 0.5);
  cv::imwrite((dir / "b.jpg").string(), cv::imread(writeChart(dir / "b.png", 1.0).string()));
  auto bytes = bytesOf(dir / "b.jpg");
  bytes.resize(bytes.size() * 2 / 3);
  writeBytes(dir / "b_cut.jpg", bytes);
  expectRefused(command("chart -q " + quoted(a) + " " + quoted(dir / "b_cut.jpg") + " -o " + quoted(dir / "out")), 1,
                "b_cut.jpg: truncated JPEG", dir / "out");
}

TEST(HostileMultiFile, WrongNumberOfExposuresIsRefused) {
  TempDir dir;
  const fs::path a = writeChart(dir / "a.png", 0.5), b = writeChart(dir / "b.png", 1.0);
  expectRefused(command("chart -q " + quoted(a) + " " + quoted(b) + " --exposures 1,2,4 -o " + quoted(dir / "out")), 1,
                "one value per IMAGE", dir / "out");
}

TEST(HostileMultiFile, ByteFlippedPngAmongShotsIsRefused) {
  TempDir dir;
  const fs::path a = writeChart(dir / "a.png", 0.5), b = writeChart(dir / "b.png", 1.0);
  auto bytes = bytesOf(b);
  for (std::size_t i = 40; i < bytes.size(); i += 7) bytes[i] = static_cast<char>(bytes[i] ^ 0x5A);
  writeBytes(dir / "b_flipped.png", bytes);
  const auto result = crfcal::test::run(command("chart -q " + quoted(a) + " " + quoted(dir / "b_flipped.png") + " -o " +
                                               quoted(dir / "out")));
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_NE(result.output.find("b_flipped.png"), std::string::npos) << result.output;
  EXPECT_FALSE(fs::exists(dir / "out"));
}

// ---- compare -------------------------------------------------------------------------------------------------------

TEST(HostileCompare, ReportWithOutOfRangeCurveIsRefusedLikeExportDoes) {
  TempDir dir;
  std::vector<double> phi(1024);
  for (int i = 0; i < 1024; ++i) phi[static_cast<size_t>(i)] = i / 1023.0;
  phi[100] = 5;
  phi[200] = -3;
  writeText(dir / "bad.json", reportJson(phi));
  writeText(dir / "good.json", reportJson());
  expectRefused(command("compare " + quoted(dir / "good.json") + " " + quoted(dir / "bad.json")), 1,
                "bad.json: \"inverse_crf\".G is not a valid inverse response");
  expectRefused(command("export " + quoted(dir / "bad.json") + " -f csv -o " + quoted(dir / "x.csv")), 1,
                "bad.json: \"inverse_crf\".G is not a valid inverse response", dir / "x.csv");
}

TEST(HostileCompare, BinaryJsonErrorIsPrintable) {
  TempDir dir;
  writeBytes(dir / "binary.json", {'{', '"', 'a', '"', ':', static_cast<char>(0xFF), static_cast<char>(0xFE), '}'});
  writeText(dir / "good.json", reportJson());
  expectRefused(command("compare " + quoted(dir / "binary.json") + " " + quoted(dir / "good.json")), 1,
                "binary.json: invalid JSON at byte");
}

TEST(HostileCompare, TruncatedReportIsRefused) {
  TempDir dir;
  const std::string json = reportJson();
  writeText(dir / "cut.json", json.substr(0, json.size() / 2));
  writeText(dir / "good.json", reportJson());
  expectRefused(command("compare " + quoted(dir / "cut.json") + " " + quoted(dir / "good.json")), 1,
                "cut.json: invalid JSON");
}

TEST(HostileCompare, AlignedToleranceDoesNotPassACurveThatIsZeroOnTheCoveredRange) {
  TempDir dir;
  // A: φ = 0 up to x = 0.6, then a ramp to 1; B: φ = x. Covered range [0, 0.5]: the unbounded best factor was 0.
  std::vector<double> a(1024), b(1024);
  for (int i = 0; i < 1024; ++i) {
    const double x = i / 1023.0;
    a[static_cast<size_t>(i)] = x < 0.6 ? 0.0 : (x - 0.6) / 0.4;
    b[static_cast<size_t>(i)] = x;
  }
  nlohmann::json ja = nlohmann::json::parse(reportJson(a)), jb = nlohmann::json::parse(reportJson(b));
  ja["covered_range"] = {{"G", {0.0, 0.5}}};
  jb["covered_range"] = {{"G", {0.0, 0.5}}};
  writeText(dir / "a.json", ja.dump());
  writeText(dir / "b.json", jb.dump());
  const auto result = crfcal::test::run(command("compare " + quoted(dir / "a.json") + " " + quoted(dir / "b.json") +
                                               " --tolerance 0.01 --tolerance-range aligned"));
  EXPECT_EQ(result.exit_code, 3) << result.output;
}

TEST(HostileCompare, DirectoryGivenAsReportIsRefused) {
  TempDir dir;
  fs::create_directory(dir / "report.json");
  writeText(dir / "good.json", reportJson());
  expectRefused(command("compare " + quoted(dir / "report.json") + " " + quoted(dir / "good.json")), 1,
                "report.json: is a directory");
}

TEST(HostileCompare, EmptyReportFileIsRefused) {
  TempDir dir;
  writeText(dir / "empty.json", "");
  writeText(dir / "good.json", reportJson());
  expectRefused(command("compare " + quoted(dir / "empty.json") + " " + quoted(dir / "good.json")), 1,
                "empty.json: invalid JSON");
}

// ---- export --------------------------------------------------------------------------------------------------------

TEST(HostileExport, NanInReportCurveIsRefused) {
  TempDir dir;
  std::string json = reportJson();
  const auto comma = json.find(',', json.find('[') + 1);
  json.replace(comma + 1, json.find(',', comma + 1) - comma - 1, "NaN");  // not even JSON: NaN is no JSON number
  writeText(dir / "nan.json", json);
  expectRefused(command("export " + quoted(dir / "nan.json") + " -f csv -o " + quoted(dir / "x.csv")), 1,
                "nan.json: invalid JSON", dir / "x.csv");
}

TEST(HostileExport, CurveAsStringsIsRefused) {
  TempDir dir;
  writeText(dir / "strings.json", R"({"inverse_crf": {"G": ["0", "1"]}})");
  expectRefused(command("export " + quoted(dir / "strings.json") + " -f csv -o " + quoted(dir / "x.csv")), 1,
                "strings.json: malformed report", dir / "x.csv");
}

TEST(HostileExport, ReportWithoutCurveIsRefused) {
  TempDir dir;
  writeText(dir / "nocurve.json", R"({"command": "calibrate"})");
  expectRefused(command("export " + quoted(dir / "nocurve.json") + " -f csv -o " + quoted(dir / "x.csv")), 1,
                "no \"inverse_crf\"", dir / "x.csv");
}

TEST(HostileExport, OutputInsideAFileIsRefused) {
  TempDir dir;
  writeText(dir / "good.json", reportJson());
  writeText(dir / "plain", "a file, not a directory");
  const auto result = crfcal::test::run(command("export " + quoted(dir / "good.json") + " -f csv -o " +
                                               quoted(dir / "plain" / "x.csv")));
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_NE(result.output.find("x.csv"), std::string::npos) << result.output;
}

TEST(HostileExport, UnwritableDirectoryIsRefusedWhenNotRoot) {
  if (geteuid() == 0) GTEST_SKIP() << "root writes whatever the mode";
  TempDir dir;
  writeText(dir / "good.json", reportJson());
  fs::create_directory(dir / "ro");
  fs::permissions(dir / "ro", fs::perms::owner_read | fs::perms::owner_exec);
  const auto result =
      crfcal::test::run(command("export " + quoted(dir / "good.json") + " -f csv -o " + quoted(dir / "ro" / "x.csv")));
  fs::permissions(dir / "ro", fs::perms::owner_all);
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_FALSE(fs::exists(dir / "ro" / "x.csv"));
}
