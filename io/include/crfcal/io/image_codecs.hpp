#pragma once
// Image codecs on bytes in memory, through the codec libraries themselves (libjpeg, libpng, libtiff) instead of
// OpenCV's imgcodecs module, whose Debian build loads ~140 shared libraries (GDAL, poppler, x265, …) at every
// process start. The decoded pixels are those OpenCV 4.6's cv::imdecode gives for the same mode
// (tests/test_image_codecs.cpp compares them pixel for pixel); the JPEG encoder writes the bytes of cv::imencode.
// Formats read: JPEG, PNG, TIFF, binary PNM (P5/P6). Any other format is refused naming the file.
#include <cstddef>
#include <span>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal::io {

// How an image is decoded, after OpenCV's imread flags.
enum class ImageReadMode {
  unchanged,  // IMREAD_UNCHANGED: the file's depth (8/16-bit, float TIFF) and channels (grey, BGR, BGRA); EXIF
              // orientation NOT applied
  color,      // IMREAD_COLOR: 8-bit BGR (grey expanded, 16 bit reduced, alpha dropped); EXIF orientation applied
  grey,       // IMREAD_GRAYSCALE: 8-bit single channel; EXIF orientation applied
};

// Decodes `bytes` (the whole file). `name` (the file, or a description) is the subject of every error: a
// crfcal::Error "NAME: reason" for an unsupported format, a corrupt or truncated stream ("truncated JPEG (premature
// end of data)": libjpeg only warns and fills with grey), or a header claiming more than kMaxImagePixels
// (jpeg_info.hpp), refused before any pixel memory is allocated.
cv::Mat decodeImage(std::span<const unsigned char> bytes, ImageReadMode mode, const std::string& name);

// JPEG of an 8-bit grey, BGR or BGRA (alpha dropped) image at quality 1–100: libjpeg's defaults (JFIF, YCbCr,
// 4:2:0, baseline Huffman tables, not optimised, not progressive), the bytes of OpenCV 4.6's imencode(".jpg").
std::vector<unsigned char> encodeJpeg(const cv::Mat& image, int quality, const std::string& name);

// PNG of an 8/16-bit grey, BGR or BGRA image (zlib level 1 with the filtered strategy, as OpenCV's default; only the
// size depends on it).
std::vector<unsigned char> encodePng(const cv::Mat& image, const std::string& name);

}  // namespace crfcal::io
