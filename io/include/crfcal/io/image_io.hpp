#pragma once
// Reading and writing raster image files (JPEG, PNG, TIFF, PNM through image_codecs.hpp: libjpeg, libpng, libtiff).
#include <filesystem>

#include <opencv2/core.hpp>

namespace crfcal::io {

// Reads an image unchanged (8 or 16 bit or float TIFF; grey, BGR or BGRA; no EXIF rotation), as OpenCV's
// IMREAD_UNCHANGED. Throws crfcal::Error naming the file when it is missing, unreadable, not a decodable image or
// of a format crfcal does not read.
cv::Mat readImage(const std::filesystem::path& path);

// Reads an image as 8-bit BGR (OpenCV's IMREAD_COLOR: grey expanded, 16 bit reduced to 8 as OpenCV does, alpha
// dropped, EXIF orientation applied). Errors as readImage.
cv::Mat readColorImage(const std::filesystem::path& path);

// Reads an image as single-channel CV_64F in [0,1] (colour converted to grey).
cv::Mat readGrayUnit(const std::filesystem::path& path);

// Writes a CV_64F/CV_32F image in [0,1] (values clamped) as 8- or 16-bit, atomically.
void writeUnitImage(const std::filesystem::path& path, const cv::Mat& image, int bits = 8);

// Writes an 8/16-bit image as is, atomically: PNG for ".png", JPEG of quality 95 for ".jpg"/".jpeg" (8-bit);
// any other extension is refused.
void writeImage(const std::filesystem::path& path, const cv::Mat& image);

// Writes an 8-bit image as JPEG of the given quality (1–100), atomically.
void writeJpeg(const std::filesystem::path& path, const cv::Mat& image, int quality);

// A signed map (e.g. Γ) as a colour PNG: blue for negative, red for positive, white for 0, scaled to ±limit
// (limit ≤ 0: the map's largest magnitude).
void writeSignedMap(const std::filesystem::path& path, const cv::Mat& map, double limit = 0);

}  // namespace crfcal::io
