// crfcal's own image codecs (io/image_codecs.hpp: libjpeg, libpng, libtiff directly) against OpenCV 4.6's
// imgcodecs, which crfcal no longer links: the same pixels for every file and mode, the same JPEG bytes.
#include <algorithm>
#include <csetjmp>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <exiv2/exiv2.hpp>
#include <gtest/gtest.h>
#include <jpeglib.h>
#include <png.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/image_codecs.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/jpeg_roundtrip.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace crfcal;
using Bytes = std::vector<unsigned char>;

namespace {

Bytes bytesOf(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return Bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

bool identical(const cv::Mat& a, const cv::Mat& b) {
  if (a.type() != b.type() || a.size() != b.size()) return false;
  const std::size_t row = static_cast<std::size_t>(a.cols) * a.elemSize();
  for (int y = 0; y < a.rows; ++y)
    if (std::memcmp(a.ptr(y), b.ptr(y), row) != 0) return false;
  return true;
}

std::string describe(const cv::Mat& m) {
  return std::to_string(m.cols) + "x" + std::to_string(m.rows) + " type " + std::to_string(m.type());
}

// crfcal's decode == cv::imdecode for the three modes crfcal uses, pixel for pixel.
void expectSameAsOpenCV(const Bytes& bytes, const std::string& name) {
  const std::pair<io::ImageReadMode, int> modes[] = {{io::ImageReadMode::unchanged, cv::IMREAD_UNCHANGED},
                                                     {io::ImageReadMode::color, cv::IMREAD_COLOR},
                                                     {io::ImageReadMode::grey, cv::IMREAD_GRAYSCALE}};
  for (const auto& [mode, flags] : modes) {
    const cv::Mat expected = cv::imdecode(bytes, flags);
    ASSERT_FALSE(expected.empty()) << name << " flags " << flags;
    cv::Mat ours;
    try {
      ours = io::decodeImage(bytes, mode, name);
    } catch (const Error& e) {
      ADD_FAILURE() << name << " flags " << flags << ": " << e.what();
      continue;
    }
    if (!identical(ours, expected)) {
      std::string diff;
      if (ours.type() == expected.type() && ours.size() == expected.size())
        diff = ", max |difference| " + std::to_string(cv::norm(ours, expected, cv::NORM_INF));
      ADD_FAILURE() << name << " flags " << flags << ": ours " << describe(ours) << ", OpenCV " << describe(expected)
                    << diff;
    }
  }
}

Bytes encodeWithOpenCV(const std::string& ext, const cv::Mat& image, const std::vector<int>& params = {}) {
  Bytes out;
  EXPECT_TRUE(cv::imencode(ext, image, out, params)) << ext;
  return out;
}

cv::Mat texture(int width, int height, int type) {
  cv::Mat noise(height, width, CV_MAKETYPE(CV_32F, CV_MAT_CN(type)));
  cv::RNG rng(7);
  rng.fill(noise, cv::RNG::UNIFORM, 0.0, 1.0);
  cv::GaussianBlur(noise, noise, cv::Size(5, 5), 1.5);
  cv::Mat ramp(height, width, CV_32F);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) ramp.at<float>(y, x) = static_cast<float>(x + 2 * y) / (width + 2 * height);
  std::vector<cv::Mat> planes;
  cv::split(noise, planes);
  for (auto& p : planes) p = 0.6 * p + 0.4 * ramp;
  cv::merge(planes, noise);
  cv::Mat out;
  const double scale = CV_MAT_DEPTH(type) == CV_16U ? 65535 : CV_MAT_DEPTH(type) == CV_8U ? 255 : 1;
  noise.convertTo(out, type, scale);
  return out;
}

// A PNG libpng writes with the given colour type and depth (OpenCV's encoder writes neither palettes, grey+alpha,
// tRNS, low bit depths nor interlacing).
Bytes pngWithLibpng(int width, int height, int color_type, int bit_depth, bool interlace, bool with_trns) {
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png_create_info_struct(png);
  Bytes out;
  png_set_write_fn(
      png, &out,
      [](png_structp p, png_bytep data, png_size_t n) {
        auto* o = static_cast<Bytes*>(png_get_io_ptr(p));
        o->insert(o->end(), data, data + n);
      },
      [](png_structp) {});
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), bit_depth, color_type,
               interlace ? PNG_INTERLACE_ADAM7 : PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  std::vector<png_color> palette(16);
  std::vector<png_byte> alphas(16);
  for (int i = 0; i < 16; ++i) {
    palette[static_cast<std::size_t>(i)] = {static_cast<png_byte>(i * 16), static_cast<png_byte>(255 - i * 9),
                                            static_cast<png_byte>((i * 37) % 256)};
    alphas[static_cast<std::size_t>(i)] = static_cast<png_byte>(255 - i * 13);
  }
  if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_PLTE(png, info, palette.data(), 16);
  png_color_16 trans_colour{};
  trans_colour.gray = 3;
  trans_colour.red = 40;
  if (with_trns) {
    if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_tRNS(png, info, alphas.data(), 16, nullptr);
    else png_set_tRNS(png, info, nullptr, 0, &trans_colour);
  }
  png_color_8 significant{};
  significant.alpha = significant.gray = significant.red = significant.green = significant.blue = static_cast<png_byte>(std::min(bit_depth, 8) - 1);
  if (color_type != PNG_COLOR_TYPE_PALETTE && bit_depth >= 8) png_set_sBIT(png, info, &significant);
  png_set_gAMA(png, info, 0.6);  // must not be applied (OpenCV does not)
  png_write_info(png, info);
  const int samples = (color_type & PNG_COLOR_MASK_PALETTE)  ? 1
                      : (color_type & PNG_COLOR_MASK_COLOR) ? ((color_type & PNG_COLOR_MASK_ALPHA) ? 4 : 3)
                                                            : ((color_type & PNG_COLOR_MASK_ALPHA) ? 2 : 1);
  const int max_value = color_type == PNG_COLOR_TYPE_PALETTE ? 15 : (1 << bit_depth) - 1;
  const std::size_t row_bytes = (static_cast<std::size_t>(width) * samples * bit_depth + 7) / 8;
  std::vector<Bytes> rows(static_cast<std::size_t>(height), Bytes(row_bytes, 0));
  std::vector<png_bytep> pointers;
  for (int y = 0; y < height; ++y) {
    Bytes& row = rows[static_cast<std::size_t>(y)];
    for (int i = 0; i < width * samples; ++i) {
      const int value = (i * 7 + y * 13 + (i * y) % 11) % (max_value + 1);
      if (bit_depth == 16) {
        row[2 * i] = static_cast<unsigned char>(value >> 8 ^ (i * 3 & 0xFF));
        row[2 * i + 1] = static_cast<unsigned char>(value);
      } else if (bit_depth == 8) {
        row[i] = static_cast<unsigned char>(value);
      } else {
        const int per_byte = 8 / bit_depth, shift = 8 - bit_depth * (i % per_byte + 1);
        row[static_cast<std::size_t>(i / per_byte)] |= static_cast<unsigned char>(value << shift);
      }
    }
    pointers.push_back(row.data());
  }
  png_write_image(png, pointers.data());
  png_write_end(png, info);
  png_destroy_write_struct(&png, &info);
  return out;
}

// A CMYK (Adobe) JPEG libjpeg writes; OpenCV cannot write one.
Bytes cmykJpeg(int width, int height) {
  jpeg_compress_struct info{};
  jpeg_error_mgr errors{};
  info.err = jpeg_std_error(&errors);
  jpeg_create_compress(&info);
  unsigned char* buffer = nullptr;
  unsigned long size = 0;
  jpeg_mem_dest(&info, &buffer, &size);
  info.image_width = static_cast<JDIMENSION>(width);
  info.image_height = static_cast<JDIMENSION>(height);
  info.input_components = 4;
  info.in_color_space = JCS_CMYK;
  jpeg_set_defaults(&info);
  jpeg_set_quality(&info, 90, TRUE);
  jpeg_start_compress(&info, TRUE);
  const cv::Mat pixels = texture(width, height, CV_8UC4);
  while (info.next_scanline < info.image_height) {
    JSAMPROW row = const_cast<JSAMPROW>(pixels.ptr<JSAMPLE>(static_cast<int>(info.next_scanline)));
    jpeg_write_scanlines(&info, &row, 1);
  }
  jpeg_finish_compress(&info);
  jpeg_destroy_compress(&info);
  Bytes out(buffer, buffer + size);
  std::free(buffer);
  return out;
}

// `jpeg` with an APP1 EXIF segment (built by Exiv2) carrying `orientation`, right after SOI.
Bytes withExifOrientation(const Bytes& jpeg, int orientation) {
  Exiv2::ExifData exif;
  exif["Exif.Image.Orientation"] = static_cast<uint16_t>(orientation);
  exif["Exif.Image.Make"] = "crfcal test";
  Exiv2::Blob blob;
  Exiv2::ExifParser::encode(blob, Exiv2::littleEndian, exif);
  const std::size_t length = blob.size() + 6 + 2;
  const unsigned char head[] = {0xFF, 0xD8, 0xFF, 0xE1, static_cast<unsigned char>(length >> 8),
                                static_cast<unsigned char>(length & 0xFF), 'E', 'x', 'i', 'f', 0, 0};
  Bytes out(sizeof head + blob.size() + jpeg.size() - 2);
  std::memcpy(out.data(), head, sizeof head);
  std::memcpy(out.data() + sizeof head, blob.data(), blob.size());
  std::memcpy(out.data() + sizeof head + blob.size(), jpeg.data() + 2, jpeg.size() - 2);
  return out;
}

std::vector<fs::path> imagesUnder(const fs::path& dir, std::size_t per_directory) {
  std::vector<fs::path> out;
  if (!fs::is_directory(dir)) return out;
  std::vector<fs::path> all;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    std::string ext = entry.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".tif" || ext == ".tiff" || ext == ".pgm" ||
        ext == ".ppm")
      all.push_back(entry.path());
  }
  std::sort(all.begin(), all.end());
  std::map<fs::path, std::size_t> taken;
  for (const auto& p : all)
    if (taken[p.parent_path()]++ < per_directory) out.push_back(p);
  return out;
}

std::string errorOf(const Bytes& bytes, const std::string& name) {
  try {
    io::decodeImage(bytes, io::ImageReadMode::unchanged, name);
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace

TEST(ImageCodecs, EverySampleImageDecodesAsOpenCVDoes) {
  const auto files = imagesUnder(test::samples(), 1000);
  ASSERT_GE(files.size(), 20u);
  for (const auto& file : files) expectSameAsOpenCV(bytesOf(file), file.string());
}

TEST(ImageCodecs, SharedDataImagesDecodeAsOpenCVDoes) {
  const fs::path data = test::sharedData();
  if (data.empty()) GTEST_SKIP() << "no ../shared/data";
  std::vector<fs::path> files;
  for (const auto& [dir, count] : std::vector<std::pair<std::string, std::size_t>>{
           {"pairs/vivo_x6s", 20}, {"brackets", 3}, {"middlebury", 2}, {"levin09/levin09_images", 3}}) {
    const auto some = imagesUnder(data / dir, count);
    files.insert(files.end(), some.begin(), some.end());
  }
  ASSERT_GE(files.size(), 20u);
  for (const auto& file : files) expectSameAsOpenCV(bytesOf(file), file.string());
}

TEST(ImageCodecs, PngOfEveryLayoutDecodesAsOpenCVDoes) {
  for (int type : {CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_16UC3, CV_16UC4})
    expectSameAsOpenCV(encodeWithOpenCV(".png", texture(37, 23, type)), "opencv png type " + std::to_string(type));
  struct Layout {
    int color_type, bit_depth;
    bool interlace, trns;
  };
  const Layout layouts[] = {
      {PNG_COLOR_TYPE_PALETTE, 4, false, false}, {PNG_COLOR_TYPE_PALETTE, 8, false, true},
      {PNG_COLOR_TYPE_GRAY, 1, false, false},    {PNG_COLOR_TYPE_GRAY, 2, true, false},
      {PNG_COLOR_TYPE_GRAY, 4, false, false},    {PNG_COLOR_TYPE_GRAY, 8, false, true},
      {PNG_COLOR_TYPE_GRAY, 16, true, false},    {PNG_COLOR_TYPE_GRAY_ALPHA, 8, false, false},
      {PNG_COLOR_TYPE_GRAY_ALPHA, 16, false, false}, {PNG_COLOR_TYPE_RGB, 8, true, true},
      {PNG_COLOR_TYPE_RGB, 16, false, true},     {PNG_COLOR_TYPE_RGB_ALPHA, 16, true, false},
  };
  for (const auto& l : layouts)
    expectSameAsOpenCV(pngWithLibpng(29, 17, l.color_type, l.bit_depth, l.interlace, l.trns),
                       "libpng colour type " + std::to_string(l.color_type) + ", " + std::to_string(l.bit_depth) +
                           " bit" + (l.interlace ? ", interlaced" : "") + (l.trns ? ", tRNS" : ""));
}

TEST(ImageCodecs, JpegGreyColourCmykAndExifOrientationDecodeAsOpenCVDoes) {
  expectSameAsOpenCV(encodeWithOpenCV(".jpg", texture(41, 27, CV_8UC1)), "grey jpeg");
  expectSameAsOpenCV(encodeWithOpenCV(".jpg", texture(41, 27, CV_8UC3), {cv::IMWRITE_JPEG_QUALITY, 80}), "colour jpeg");
  expectSameAsOpenCV(encodeWithOpenCV(".jpg", texture(41, 27, CV_8UC3), {cv::IMWRITE_JPEG_PROGRESSIVE, 1}),
                     "progressive jpeg");
  expectSameAsOpenCV(cmykJpeg(33, 21), "cmyk jpeg");
  const Bytes plain = encodeWithOpenCV(".jpg", texture(41, 27, CV_8UC3));
  for (int orientation = 1; orientation <= 8; ++orientation) {
    const Bytes rotated = withExifOrientation(plain, orientation);
    expectSameAsOpenCV(rotated, "jpeg with EXIF orientation " + std::to_string(orientation));
    const cv::Mat colour = io::decodeImage(rotated, io::ImageReadMode::color, "rotated");
    EXPECT_EQ(colour.cols, orientation >= 5 ? 27 : 41) << "orientation " << orientation << " applied for colour";
    EXPECT_EQ(io::decodeImage(rotated, io::ImageReadMode::unchanged, "rotated").cols, 41) << "and not for unchanged";
  }
}

TEST(ImageCodecs, TiffAndPnmDecodeAsOpenCVDoes) {
  for (int type : {CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_16UC3, CV_16UC4, CV_32FC1, CV_32FC3}) {
    const cv::Mat image = texture(31, 19, type);
    const Bytes tiff = encodeWithOpenCV(".tiff", image);
    if (CV_MAT_DEPTH(type) == CV_32F) {  // OpenCV reads a float TIFF only unchanged (libtiff's RGBA refuses floats)
      EXPECT_TRUE(identical(io::decodeImage(tiff, io::ImageReadMode::unchanged, "float tiff"),
                            cv::imdecode(tiff, cv::IMREAD_UNCHANGED)));
      if (type == CV_32FC1) {  // (OpenCV writes CV_32FC3 as SGI LogLuv, lossy)
        EXPECT_TRUE(identical(io::decodeImage(tiff, io::ImageReadMode::unchanged, "float tiff"), image));
      }
      continue;
    }
    expectSameAsOpenCV(tiff, "tiff type " + std::to_string(type));
    if (CV_MAT_CN(type) != 4)
      expectSameAsOpenCV(encodeWithOpenCV(CV_MAT_CN(type) == 1 ? ".pgm" : ".ppm", image),
                         "pnm type " + std::to_string(type));
  }
}

TEST(ImageCodecs, JpegEncoderWritesOpenCVsBytesAndTheRoundTripIsUnchanged) {
  for (int type : {CV_8UC1, CV_8UC3, CV_8UC4}) {
    const cv::Mat image = texture(53, 35, type);
    for (int quality : {30, 75, 90, 95, 100}) {
      const Bytes ours = io::encodeJpeg(image, quality, "test");
      EXPECT_EQ(ours, encodeWithOpenCV(".jpg", image, {cv::IMWRITE_JPEG_QUALITY, quality}))
          << "type " << type << " quality " << quality;
      if (CV_MAT_CN(type) == 4) continue;
      Bytes theirs;
      cv::imencode(".jpg", image, theirs, {cv::IMWRITE_JPEG_QUALITY, quality});
      EXPECT_TRUE(identical(io::jpegRoundTrip(image, quality),
                            cv::imdecode(theirs, CV_MAT_CN(type) == 1 ? cv::IMREAD_GRAYSCALE : cv::IMREAD_COLOR)));
    }
  }
}

TEST(ImageCodecs, WrittenImagesReadBackUnchanged) {
  test::TempDir dir;
  for (int type : {CV_8UC1, CV_8UC3, CV_8UC4, CV_16UC1, CV_16UC3, CV_16UC4}) {
    const cv::Mat image = texture(27, 15, type);
    const fs::path png = dir / ("image" + std::to_string(type) + ".png");
    io::writeImage(png, image);
    EXPECT_TRUE(identical(cv::imread(png.string(), cv::IMREAD_UNCHANGED), image)) << "OpenCV reads ours, " << type;
    EXPECT_TRUE(identical(io::readImage(png), image)) << type;
  }
  const cv::Mat colour = texture(27, 15, CV_8UC3);
  io::writeJpeg(dir / "q70.jpg", colour, 70);
  EXPECT_EQ(bytesOf(dir / "q70.jpg"), encodeWithOpenCV(".jpg", colour, {cv::IMWRITE_JPEG_QUALITY, 70}));
  io::writeImage(dir / "default.JPG", colour);
  EXPECT_EQ(bytesOf(dir / "default.JPG"), encodeWithOpenCV(".jpg", colour));  // OpenCV's default quality, 95
  cv::Mat unit(15, 27, CV_64F);
  cv::randu(unit, -0.2, 1.2);
  io::writeUnitImage(dir / "unit16.png", unit, 16);
  cv::Mat expected;
  cv::Mat clamped = cv::max(cv::min(unit, 1.0), 0.0);
  clamped.convertTo(expected, CV_16U, 65535.0);
  EXPECT_TRUE(identical(io::readImage(dir / "unit16.png"), expected));
  EXPECT_THROW(io::writeImage(dir / "image.bmp", colour), Error);
  EXPECT_FALSE(fs::exists(dir / "image.bmp"));
}

TEST(ImageCodecs, UnsupportedAndBrokenFilesAreRefusedNamingTheFile) {
  const cv::Mat image = texture(40, 30, CV_8UC3);
  EXPECT_NE(errorOf(encodeWithOpenCV(".bmp", image), "x.bmp")
                .find("x.bmp: unsupported image format (crfcal reads JPEG, PNG, TIFF, PNM)"),
            std::string::npos);
  EXPECT_NE(errorOf(Bytes{'h', 'e', 'l', 'l', 'o'}, "t.png").find("t.png: not a readable image"), std::string::npos);
  Bytes png = encodeWithOpenCV(".png", image);
  png.resize(png.size() / 2);
  EXPECT_NE(errorOf(png, "half.png").find("half.png: corrupt PNG"), std::string::npos) << errorOf(png, "half.png");
  Bytes jpeg = encodeWithOpenCV(".jpg", texture(400, 300, CV_8UC3));
  jpeg.resize(jpeg.size() / 2);
  EXPECT_NE(errorOf(jpeg, "half.jpg").find("half.jpg: truncated JPEG (premature end of data)"), std::string::npos)
      << errorOf(jpeg, "half.jpg");
  Bytes tiff = encodeWithOpenCV(".tiff", image);
  tiff.resize(tiff.size() / 2);
  EXPECT_NE(errorOf(tiff, "half.tif").find("half.tif: "), std::string::npos) << errorOf(tiff, "half.tif");
  const std::string pnm_header = "P6\n60000 60000\n255\n";
  Bytes pnm(pnm_header.begin(), pnm_header.end());
  pnm.resize(pnm.size() + 100, 7);
  EXPECT_NE(errorOf(pnm, "huge.ppm").find("huge.ppm: image too large (60000x60000"), std::string::npos)
      << errorOf(pnm, "huge.ppm");
  EXPECT_NE(errorOf(Bytes{'P', '6', '\n', '4', ' ', '4', '\n', '2', '5', '5', '\n', 1, 2}, "short.ppm")
                .find("short.ppm: truncated PNM"),
            std::string::npos);
  EXPECT_NE(errorOf(Bytes{}, "empty.png").find("empty.png: file is empty"), std::string::npos);
}
