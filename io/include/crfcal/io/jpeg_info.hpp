#pragma once
// What a JPEG file's frame header says about how its colour was stored (libjpeg, header only, no decoding).
// Camera and libjpeg JPEGs usually store the two chroma planes at half resolution (4:2:0 or 4:2:2): the decoder
// rebuilds R and B from full-resolution luma plus chroma averaged over 2×2 (or 2×1) pixels of the gamma-encoded
// image, so at edges — exactly where the seed's method takes its information — R and B mix with their neighbours
// after the tone curve. crfcal reports it and warns (docs/RESULTS.md#calibrate, "chroma subsampling").
#include <filesystem>
#include <string>

namespace crfcal::io {

struct JpegInfo {
  int components = 0;           // 1 grey, 3 YCbCr
  int luma_h = 1, luma_v = 1;   // sampling factors of the first component (chroma are 1×1 relative to them)
  std::string subsampling;      // "4:4:4", "4:2:2", "4:4:0", "4:2:0", "4:1:1", "grey", or "h×v" otherwise
  bool chroma_subsampled() const { return components >= 3 && (luma_h > 1 || luma_v > 1); }
};

// Reads the frame header. Throws crfcal::Error naming the file when it is not a readable JPEG.
JpegInfo readJpegInfo(const std::filesystem::path& path);

}  // namespace crfcal::io
