#include "crfcal/io/image_io.hpp"

#include <algorithm>
#include <cctype>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_codecs.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {

// The file's bytes decoded in `mode`; every failure names the file.
cv::Mat decodeFile(const fs::path& path, ImageReadMode mode) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  if (fs::is_directory(path, ec)) throw Error("is a directory, not an image", path.string());
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open (permission denied?)", path.string());
  const std::vector<unsigned char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.empty()) throw Error("file is empty", path.string());
  return decodeImage(bytes, mode, path.string());
}

std::string lowerExtension(const fs::path& path) {
  std::string ext = path.extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

// The image encoded for the path's extension (PNG, or JPEG at `jpeg_quality`), written atomically.
void encodeFile(const fs::path& path, const cv::Mat& image, int jpeg_quality) {
  const std::string ext = lowerExtension(path);
  std::vector<unsigned char> bytes;
  if (ext == ".png") bytes = encodePng(image, path.string());
  else if (ext == ".jpg" || ext == ".jpeg" || ext == ".jpe") bytes = encodeJpeg(image, jpeg_quality, path.string());
  else throw Error("cannot write image: unsupported extension (crfcal writes .png and .jpg)", path.string());
  writeTextFile(path, std::string(bytes.begin(), bytes.end()));
}

}  // namespace

cv::Mat readImage(const fs::path& path) {
  const cv::Mat image = decodeFile(path, ImageReadMode::unchanged);
  if (image.depth() != CV_8U && image.depth() != CV_16U && image.depth() != CV_32F)
    throw Error("unsupported pixel depth (8 or 16 bit integer or 32-bit float expected)", path.string());
  return image;
}

cv::Mat readGrayUnit(const fs::path& path) {
  try {
    return toUnitGray(readImage(path));
  } catch (const InvalidInput& e) {
    throw Error(e.reason(), path.string());
  }
}

cv::Mat readColorImage(const fs::path& path) { return decodeFile(path, ImageReadMode::color); }

void writeImage(const fs::path& path, const cv::Mat& image) { encodeFile(path, image, 95); }  // 95: OpenCV's default JPEG quality

void writeJpeg(const fs::path& path, const cv::Mat& image, int quality) {
  encodeFile(path, image, quality);
}

void writeUnitImage(const fs::path& path, const cv::Mat& image, int bits) {
  if (bits != 8 && bits != 16) throw Error("images are written with 8 or 16 bits", path.string());
  cv::Mat clamped, out;
  image.convertTo(clamped, CV_64F);
  cv::max(cv::min(clamped, 1.0), 0.0, clamped);
  clamped.convertTo(out, bits == 8 ? CV_8U : CV_16U, bits == 8 ? 255.0 : 65535.0);
  writeImage(path, out);
}

void writeSignedMap(const fs::path& path, const cv::Mat& map, double limit) {
  cv::Mat m;
  map.convertTo(m, CV_64F);
  if (limit <= 0) {
    double lo = 0, hi = 0;
    cv::minMaxLoc(m, &lo, &hi);
    limit = std::max({std::abs(lo), std::abs(hi), 1e-12});
  }
  cv::Mat out(m.size(), CV_8UC3);
  for (int y = 0; y < m.rows; ++y)
    for (int x = 0; x < m.cols; ++x) {
      const double t = std::clamp(m.at<double>(y, x) / limit, -1.0, 1.0);
      const auto fade = static_cast<uchar>(255 * (1 - std::abs(t)));
      out.at<cv::Vec3b>(y, x) = t >= 0 ? cv::Vec3b(fade, fade, 255) : cv::Vec3b(255, fade, fade);
    }
  writeImage(path, out);
}

}  // namespace crfcal::io
