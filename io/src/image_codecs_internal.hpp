#pragma once
// The per-format decoders behind decodeImage (image_codecs.hpp), and what they share.
#include <cstddef>
#include <span>
#include <string>

#include <opencv2/core.hpp>

#include "crfcal/io/image_codecs.hpp"

namespace crfcal::io::codec {

using Bytes = std::span<const unsigned char>;

// Throws "NAME: image too large (WxH; at most N megapixels)" when width × height exceeds kMaxImagePixels, or a
// corrupt-header error when a side is zero. Every decoder calls it before allocating pixels.
void requirePixelBudget(double width, double height, const std::string& name);

// OpenCV's rule for the decoded type (loadsave.cpp): unchanged keeps the file's type, color is CV_8UC3, grey CV_8UC1.
int targetType(ImageReadMode mode, int file_type);

// `orientation` receives the EXIF orientation tag of the JPEG's first APP1 segment (1–8), or 0 when absent.
cv::Mat decodeJpeg(Bytes bytes, ImageReadMode mode, const std::string& name, int& orientation);
cv::Mat decodePng(Bytes bytes, ImageReadMode mode, const std::string& name);
cv::Mat decodeTiff(Bytes bytes, ImageReadMode mode, const std::string& name);
cv::Mat decodePnm(Bytes bytes, ImageReadMode mode, const std::string& name);

// The EXIF orientation (1–8) of a JPEG APP1 segment's payload ("Exif\0\0" + TIFF structure), 0 when it has none.
int exifOrientation(const unsigned char* data, std::size_t size);

}  // namespace crfcal::io::codec
