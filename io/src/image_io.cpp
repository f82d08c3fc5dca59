#include "crfcal/io/image_io.hpp"

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <iterator>
#include <vector>

#include <opencv2/core/utils/logger.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/jpeg_info.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {

std::uint32_t bigEndian32(const uchar* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) | p[3];
}

// A PNG's IHDR gives its size before anything is decoded: refuse a forged header claiming billions of pixels with one
// line instead of OpenCV's two-line size assertion (JPEG: requireCompleteJpeg; other formats: the decoder's message).
void requireDecodableSize(const std::vector<uchar>& bytes, const fs::path& path) {
  static const uchar kPngIhdr[] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n', 0, 0, 0, 13, 'I', 'H', 'D', 'R'};
  if (bytes.size() < 24 || !std::equal(std::begin(kPngIhdr), std::end(kPngIhdr), bytes.begin())) return;
  const std::uint32_t width = bigEndian32(&bytes[16]), height = bigEndian32(&bytes[20]);
  if (static_cast<double>(width) * height > kMaxImagePixels)
    throw Error("image too large (" + std::to_string(width) + "x" + std::to_string(height) + "; at most " +
                    std::to_string(kMaxImagePixels / 1000000) + " megapixels)",
                path.string());
}

// The first line of an OpenCV error, without its source file and line: one line naming our file is the rule.
std::string firstLine(const std::string& text) { return text.substr(0, text.find('\n')); }


// The file's bytes decoded with OpenCV's `flags`; every failure names the file.
cv::Mat decodeFile(const fs::path& path, int flags) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  if (fs::is_directory(path, ec)) throw Error("is a directory, not an image", path.string());
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open (permission denied?)", path.string());
  std::vector<uchar> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.empty()) throw Error("file is empty", path.string());
  if (bytes.size() >= 2 && bytes[0] == 0xFF && bytes[1] == 0xD8) requireCompleteJpeg(bytes.data(), bytes.size(), path);
  requireDecodableSize(bytes, path);
  cv::Mat image;
  try {
    image = cv::imdecode(bytes, flags);
  } catch (const cv::Exception& e) {
    throw Error("cannot decode image: " + firstLine(e.err), path.string());
  }
  if (image.empty()) throw Error("not a readable image (corrupt or unsupported format)", path.string());
  return image;
}

// The image written by OpenCV's encoder for the path's extension, atomically.
void encodeFile(const fs::path& path, const cv::Mat& image, const std::vector<int>& parameters) {
  writeAtomically(path, [&](const fs::path& temporary) {
    bool ok = false;
    try {
      ok = cv::imwrite(temporary.string(), image, parameters);
    } catch (const cv::Exception& e) {
      throw Error("cannot encode image: " + e.msg, path.string());
    }
    if (!ok) throw Error("cannot write image", path.string());
  });
}

}  // namespace

cv::Mat readImage(const fs::path& path) {
  const cv::Mat image = decodeFile(path, cv::IMREAD_UNCHANGED | cv::IMREAD_ANYDEPTH | cv::IMREAD_ANYCOLOR);
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

cv::Mat readColorImage(const fs::path& path) { return decodeFile(path, cv::IMREAD_COLOR); }

void writeImage(const fs::path& path, const cv::Mat& image) { encodeFile(path, image, {}); }

void writeJpeg(const fs::path& path, const cv::Mat& image, int quality) {
  encodeFile(path, image, {cv::IMWRITE_JPEG_QUALITY, quality});
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
