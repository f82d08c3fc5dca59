// The JPEG frame header reader (io/jpeg_info.hpp) and the warning `calibrate` derives from it.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/jpeg_info.hpp"
#include "crfcal/io/pair_input.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace crfcal;

TEST(JpegInfo, ReadsTheChromaSubsamplingOfRealEncoders) {
  const auto opencv = io::readJpegInfo(test::samples() / "pairs" / "sharp.jpg");  // libjpeg via OpenCV: 4:2:0
  EXPECT_EQ(opencv.components, 3);
  EXPECT_EQ(opencv.subsampling, "4:2:0");
  EXPECT_TRUE(opencv.chroma_subsampled());
  const auto full = io::readJpegInfo(test::samples() / "jpeg" / "crop_444.jpg");  // Pillow subsampling=0
  EXPECT_EQ(full.subsampling, "4:4:4");
  EXPECT_FALSE(full.chroma_subsampled());
  EXPECT_EQ(io::readJpegInfo(test::samples() / "jpeg" / "crop_422.jpg").subsampling, "4:2:2");
}

TEST(JpegInfo, GreyAndBrokenFiles) {
  test::TempDir dir;
  const fs::path grey = dir / "grey.jpg";
  ASSERT_TRUE(cv::imwrite(grey.string(), cv::Mat(32, 32, CV_8UC1, cv::Scalar(90))));
  const auto info = io::readJpegInfo(grey);
  EXPECT_EQ(info.subsampling, "grey");
  EXPECT_FALSE(info.chroma_subsampled());
  const fs::path broken = dir / "broken.jpg";
  std::ofstream(broken) << "\xFF\xD8 not really a jpeg";
  try {
    io::readJpegInfo(broken);
    FAIL() << "a broken header must throw";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("broken.jpg"), std::string::npos) << e.what();
  }
}

TEST(JpegInfo, LoadImageRecordsItOnlyForJpeg) {
  const io::LoadedImage jpeg = io::loadImage(test::samples() / "pairs" / "blurred.jpg");
  EXPECT_EQ(jpeg.chroma_subsampling, "4:2:0");
  EXPECT_TRUE(jpeg.chroma_subsampled);
  EXPECT_FALSE(io::loadImage(test::samples() / "jpeg" / "crop_444.jpg").chroma_subsampled);
  test::TempDir dir;
  const fs::path png = dir / "a.png";
  ASSERT_TRUE(cv::imwrite(png.string(), cv::Mat(32, 32, CV_8UC3, cv::Scalar(10, 90, 200))));
  EXPECT_TRUE(io::loadImage(png).chroma_subsampling.empty());
  EXPECT_FALSE(io::loadImage(png).chroma_subsampled);
}
