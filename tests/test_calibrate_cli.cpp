// crfcal calibrate: end-to-end on the bundled pair, and bad input → one clear line, non-zero exit, no DIR.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/io/exif.hpp"
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
void writeShot(const fs::path& path, const cv::Mat& image, double iso, double t) {
  cv::imwrite(path.string(), image);
  ExifExposure e;
  e.iso = iso;
  e.exposure_time = t;
  e.f_number = 4;
  e.make = "crfcal";
  e.model = "test";
  io::writeExif(path, e);
}

TEST(CalibrateCli, BundledPairWithKnownKernel) {
  if (!fs::exists(pairDir() / "sharp.jpg")) GTEST_SKIP();
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
  EXPECT_TRUE(report["effects"].is_array());
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

TEST(CalibrateCli, CorruptRaw) {
  test::TempDir dir;
  {
    std::ofstream out(dir / "bad.nef", std::ios::binary);
    out << "II*\0garbage garbage garbage";
  }
  const auto r = test::run(bin() + " calibrate " + (dir / "bad.nef").string() + " " + (dir / "bad.nef").string() +
                           " -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "bad.nef");
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
  cv::imwrite((dir / "b.png").string(), test::levinImage(1) * 255);
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

TEST(CalibrateCli, EdgelessPair) {
  test::TempDir dir;
  cv::Mat flat(200, 200, CV_8UC3, cv::Scalar(120, 120, 120));
  writeShot(dir / "a.jpg", flat, 800, 0.01);
  writeShot(dir / "b.jpg", flat, 100, 0.08);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.jpg").string() + " " + (dir / "b.jpg").string() +
                           " --no-register -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "edges");
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

TEST(CalibrateCli, KernelHitsSizeLimit) {
  test::TempDir dir;
  const cv::Mat sharp = test::levinImage(2);
  cv::Mat blurred;
  cv::GaussianBlur(sharp, blurred, cv::Size(0, 0), 6.0);
  writeShot(dir / "a.png", sharp * 255, 100, 0.01);
  writeShot(dir / "b.png", blurred * 255, 100, 0.01);
  const auto r = test::run(bin() + " calibrate " + (dir / "a.png").string() + " " + (dir / "b.png").string() +
                           " --blurred second --no-register --kernel-size 7 -o " + (dir / "out").string());
  expectCleanFailure(r, dir / "out", "--kernel-size");
}

}  // namespace
}  // namespace crfcal
