// Camera RAW through LibRaw: linear 16-bit output, levels, and clear errors for unusable files.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "crfcal/error.hpp"
#include "crfcal/io/raw_image.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {
namespace fs = std::filesystem;

fs::path rawSamples() {
  const fs::path shared = test::sharedData();
  return shared.empty() ? fs::path() : shared / "raw_samples";
}

TEST(RawDecode, KodakKdcIsLinearSixteenBit) {
  const fs::path file = rawSamples() / "RAW_KODAK_DC50.KDC";
  if (rawSamples().empty() || !fs::exists(file)) GTEST_SKIP() << "../shared/data absent";
  EXPECT_TRUE(io::isRawFile(file));
  io::RawDecodeOptions options;
  options.half_size = false;
  const io::RawImage raw = io::readRaw(file, options);
  EXPECT_EQ(raw.image.type(), CV_16UC3);
  EXPECT_EQ(raw.image.cols, 768);
  EXPECT_EQ(raw.image.rows, 512);
  EXPECT_GT(raw.white_level, raw.black_level);
  ASSERT_TRUE(raw.exposure.exposure_time.has_value());
  EXPECT_NEAR(*raw.exposure.exposure_time, 1.0 / 230, 1e-4);
  EXPECT_NE(raw.summary().find("Kodak"), std::string::npos) << raw.summary();
  // Linear output: no auto-brightening, so the mean of a daylight scene stays well below the top.
  const cv::Scalar mean = cv::mean(raw.image);
  EXPECT_LT(mean[1], 40000);
  EXPECT_GT(mean[1], 200);
  // Without white balance the green channel is unchanged and red/blue differ.
  io::RawDecodeOptions no_wb;
  no_wb.camera_white_balance = false;
  const io::RawImage plain = io::readRaw(file, no_wb);
  EXPECT_EQ(plain.image.size(), raw.image.size());
}

TEST(RawDecode, PrunedAndTruncatedFilesFailClearly) {
  if (rawSamples().empty()) GTEST_SKIP() << "../shared/data absent";
  for (const char* name : {"IMG_1361.dng", "Canon-R6-pruned.CR3", "sony_alpha_a7iii_raw_image.ARW",
                           "nikon_z_9_high_efficiency_compressed_dx_cropped_max_overexposed.dng"}) {
    const fs::path file = rawSamples() / name;
    if (!fs::exists(file)) continue;
    try {
      io::readRaw(file);
      ADD_FAILURE() << name << " decoded";
    } catch (const Error& e) {
      EXPECT_EQ(e.file(), file.string());
      EXPECT_FALSE(e.reason().empty());
    }
  }
}

TEST(RawDecode, GarbageAndPlainImagesAreNotRaw) {
  test::TempDir dir;
  const fs::path garbage = dir / "garbage.nef";
  {
    std::ofstream out(garbage, std::ios::binary);
    for (int i = 0; i < 5000; ++i) out.put(static_cast<char>((i * 7919) & 0xFF));
  }
  EXPECT_FALSE(io::isRawFile(garbage));
  EXPECT_THROW(io::readRaw(garbage), Error);
  EXPECT_THROW(io::readRaw(dir / "missing.cr2"), Error);
  EXPECT_FALSE(io::isRawFile(test::samples() / "levin09" / "im1.png"));
}

}  // namespace
}  // namespace crfcal
