#pragma once
// What a JPEG file's frame header says about how its colour was stored (libjpeg, header only, no decoding).
// Camera and libjpeg JPEGs usually store the two chroma planes at half resolution (4:2:0 or 4:2:2): the decoder
// rebuilds R and B from full-resolution luma plus chroma averaged over 2×2 (or 2×1) pixels of the gamma-encoded
// image, so at edges — exactly where the seed's method takes its information — R and B mix with their neighbours
// after the tone curve. crfcal reports it and warns (docs/RESULTS.md#calibrate, "chroma subsampling").
#include <cstddef>
#include <filesystem>
#include <string>

#include <opencv2/core.hpp>

namespace crfcal::io {

struct JpegInfo {
  int components = 0;           // 1 grey, 3 YCbCr
  int luma_h = 1, luma_v = 1;   // sampling factors of the first component (chroma are 1×1 relative to them)
  std::string subsampling;      // "4:4:4", "4:2:2", "4:4:0", "4:2:0", "4:1:1", "grey", or "h×v" otherwise
  bool chroma_subsampled() const { return components >= 3 && (luma_h > 1 || luma_v > 1); }
};

// Chroma sampling of a JPEG written by crfcal (bench pairs --jpeg-sampling): 4:2:0 is what OpenCV and most cameras
// write, 4:2:2 what many DSLRs write, 4:4:4 full-resolution chroma.
enum class JpegSampling { s420, s422, s444 };
JpegSampling jpegSamplingFromString(const std::string& name);  // "4:2:0"/"420", …; throws InvalidInput otherwise
const char* toString(JpegSampling sampling);                    // "4:2:0", "4:2:2", "4:4:4"

// Writes an 8-bit grey or BGR image as a baseline JFIF JPEG of `quality` (1–100) with the given chroma sampling,
// through libjpeg (the same library and defaults OpenCV uses: standard tables, integer DCT, no optimised Huffman),
// atomically. Throws crfcal::Error naming the file.
void writeJpegSampled(const std::filesystem::path& path, const cv::Mat& image, int quality, JpegSampling sampling);

// Reads the frame header. Throws crfcal::Error naming the file when it is not a readable JPEG.
JpegInfo readJpegInfo(const std::filesystem::path& path);

// The largest image crfcal decodes (pixels): far above any camera sensor (≤ 400 MP), below OpenCV's own limit
// (2^30) whose assertion would otherwise be the message, and a bound on the memory a forged header can claim.
constexpr std::size_t kMaxImagePixels = 500'000'000;

// Decodes the whole entropy-coded stream of an in-memory JPEG (libjpeg, at 1/8 scale: DC coefficients only, fast)
// and throws crfcal::Error naming `path` when its header claims more than kMaxImagePixels or when it ends early: "truncated JPEG (premature end of data)". OpenCV's
// decoder only warns about it (libjpeg's JWRN_JPEG_EOF) and fills the missing rows with grey, which would silently
// enter the fit as real pixels.
void requireCompleteJpeg(const unsigned char* data, std::size_t size, const std::filesystem::path& path);

}  // namespace crfcal::io
