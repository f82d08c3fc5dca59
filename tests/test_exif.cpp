// EXIF exposure settings (Exiv2) and the footnote-4 exposure ratio.
#include <cmath>
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "crfcal/error.hpp"
#include "crfcal/exposure_ratio.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/raw_image.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {
namespace fs = std::filesystem;

ExifExposure settings(double iso, double t, double f) {
  ExifExposure e;
  e.iso = iso;
  e.exposure_time = t;
  e.f_number = f;
  return e;
}

TEST(ExifRatio, FootnoteFourFormulaAndFactors) {
  // The vivo pairs: blurred ISO 100, 2 s; sharp ISO 3200, 1/100 s, both f/2.2 → 6.25.
  const auto f = exposureRatio(settings(3200, 0.01, 2.2), settings(100, 2, 2.2));
  EXPECT_NEAR(f.iso, 100.0 / 3200.0, 1e-12);
  EXPECT_NEAR(f.time, 200.0, 1e-9);
  EXPECT_NEAR(f.aperture, 1.0, 1e-12);
  EXPECT_NEAR(f.ratio(), 6.25, 1e-9);
  // One stop more aperture on the blurred shot (f/4 vs f/5.6) doubles r.
  EXPECT_NEAR(exposureRatio(settings(100, 0.1, 5.6), settings(100, 0.1, 4.0)).ratio(), 1.96, 1e-9);
  EXPECT_NE(f.summary().find("6.25"), std::string::npos);
}

TEST(ExifRatio, MissingValuesSuggestRatioOption) {
  ExifExposure none;
  try {
    exposureRatio(none, settings(100, 1, 2));
    FAIL() << "expected InvalidInput";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("--ratio"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("sharp"), std::string::npos) << e.what();
  }
  // A missing F-number is tolerated (assumed equal) and flagged.
  ExifExposure no_f = settings(200, 0.5, 2);
  no_f.f_number.reset();
  const auto f = exposureRatio(settings(100, 0.5, 2), no_f);
  EXPECT_FALSE(f.aperture_known);
  EXPECT_NEAR(f.ratio(), 2.0, 1e-12);
}

TEST(ExifRead, WriteThenReadRoundTrip) {
  test::TempDir dir;
  const fs::path jpeg = dir / "shot.jpg";
  cv::imwrite(jpeg.string(), cv::Mat(32, 48, CV_8UC3, cv::Scalar(40, 90, 200)));
  EXPECT_FALSE(io::readExif(jpeg).usable());  // OpenCV writes no EXIF
  ExifExposure e = settings(800, 1.0 / 60, 2.8);
  e.make = "TestMake";
  e.model = "TestMake Model 1";
  io::writeExif(jpeg, e);
  const ExifExposure back = io::readExif(jpeg);
  ASSERT_TRUE(back.usable());
  EXPECT_NEAR(*back.iso, 800, 1e-9);
  EXPECT_NEAR(*back.exposure_time, 1.0 / 60, 1e-9);
  EXPECT_NEAR(*back.f_number, 2.8, 1e-9);
  EXPECT_EQ(back.make, "TestMake");
  EXPECT_EQ(back.camera(), "TestMake Model 1");
}

TEST(ExifRead, MissingFileNamesIt) {
  try {
    io::readExif("/nonexistent/x.jpg");
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/x.jpg"), std::string::npos);
  }
}

TEST(ExifRead, BundledSamplePair) {
  const fs::path dir = test::samples() / "pairs";
  ASSERT_TRUE(fs::exists(dir / "sharp.jpg")) << "bundled pair missing";
  const ExifExposure sharp = io::readExif(dir / "sharp.jpg");
  const ExifExposure blurred = io::readExif(dir / "blurred.jpg");
  ASSERT_TRUE(sharp.usable());
  ASSERT_TRUE(blurred.usable());
  EXPECT_GT(exposureRatio(sharp, blurred).ratio(), 0.5);
}

TEST(ExifRead, VivoPhonePairsGiveSixPointTwoFive) {
  const fs::path dir = test::sharedData() / "pairs" / "vivo_x6s";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  for (int n = 1; n <= 3; ++n) {
    const ExifExposure sharp = io::readExif(dir / ("noisy_" + std::to_string(n) + ".jpg"));
    const ExifExposure blurred = io::readExif(dir / ("blurred_" + std::to_string(n) + ".jpg"));
    ASSERT_TRUE(sharp.usable()) << n;
    EXPECT_EQ(sharp.make, "vivo");
    EXPECT_NEAR(*sharp.iso, 3200, 1e-9);
    EXPECT_NEAR(*blurred.exposure_time, 2.0, 1e-9);
    EXPECT_NEAR(exposureRatio(sharp, blurred).ratio(), n == 1 ? 3.125 : 6.25, 1e-9);
  }
}

TEST(ExifRead, BracketsOneStopSteps) {
  const fs::path dir = test::sharedData() / "brackets" / "nikon_e995_window";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  const ExifExposure a = io::readExif(dir / "HDRI_Sample_Scene_Window_-_05.jpg");
  const ExifExposure b = io::readExif(dir / "HDRI_Sample_Scene_Window_-_06.jpg");
  ASSERT_TRUE(a.usable());
  EXPECT_NEAR(*a.iso, 100, 1e-9);
  EXPECT_NEAR(exposureRatio(a, b).ratio(), 2.0, 0.15);  // 1/60 → 1/30 (nominal 1/64 rounding)
}

TEST(ExifRead, RawFilesThroughExiv2OrLibRaw) {
  const fs::path dir = test::sharedData() / "raw_samples";
  if (test::sharedData().empty() || !fs::exists(dir)) GTEST_SKIP() << "../shared/data absent";
  struct Case {
    const char* file;
    double iso, time;
  };
  for (const Case& c : {Case{"Canon-R6-pruned.CR3", 100, 0.25}, Case{"IMG_1361.dng", 32, 1.0 / 5556},
                        Case{"sony_alpha_a7iii_raw_image.ARW", 6400, 1.0 / 400}}) {
    ExifExposure e = io::readExif(dir / c.file);
    if (!e.usable()) {
      auto fallback = io::readRawExposure(dir / c.file);
      if (fallback) e = *fallback;
    }
    ASSERT_TRUE(e.usable()) << c.file;
    EXPECT_NEAR(*e.iso, c.iso, 1e-6) << c.file << " " << e.iso_source;
    EXPECT_NEAR(*e.exposure_time, c.time, c.time * 0.01) << c.file << " " << e.exposure_time_source;
  }
}

}  // namespace
}  // namespace crfcal
