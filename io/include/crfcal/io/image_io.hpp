#pragma once
// Reading and writing raster images (JPEG, PNG, TIFF, … through OpenCV's codecs).
#include <filesystem>

#include <opencv2/core.hpp>

namespace crfcal::io {

// Reads an image unchanged (8 or 16 bit, grey or BGR). Throws crfcal::Error naming the file when it is
// missing, unreadable or not a decodable image.
cv::Mat readImage(const std::filesystem::path& path);

// Reads an image as 8-bit BGR (OpenCV's IMREAD_COLOR: grey expanded, 16 bit scaled down). Errors as readImage.
cv::Mat readColorImage(const std::filesystem::path& path);

// Reads an image as single-channel CV_64F in [0,1] (colour converted to grey).
cv::Mat readGrayUnit(const std::filesystem::path& path);

// Writes a CV_64F/CV_32F image in [0,1] (values clamped) as 8- or 16-bit, atomically.
void writeUnitImage(const std::filesystem::path& path, const cv::Mat& image, int bits = 8);

// Writes an 8/16-bit image as is, atomically.
void writeImage(const std::filesystem::path& path, const cv::Mat& image);

// Writes an 8-bit image as JPEG of the given quality (1–100), atomically.
void writeJpeg(const std::filesystem::path& path, const cv::Mat& image, int quality);

// A signed map (e.g. Γ) as a colour PNG: blue for negative, red for positive, white for 0, scaled to ±limit
// (limit ≤ 0: the map's largest magnitude).
void writeSignedMap(const std::filesystem::path& path, const cv::Mat& map, double limit = 0);

}  // namespace crfcal::io
