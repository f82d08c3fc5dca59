#pragma once
// Camera RAW (CR2, CR3, NEF, ARW, DNG, RAF, ORF, KDC, …) through LibRaw, decoded to LINEAR 16-bit data:
// no auto-brightness (no_auto_bright = 1), no gamma (gamm = {1, 1}), black level subtracted and the white level
// mapped to 65535 by LibRaw's scaling, camera white balance or none (unity multipliers) by option.
// The result is proportional to irradiance (φ = identity up to saturation), which is why a RAW pair needs no
// CRF and a RAW of the same shot is the truth for a JPEG (calibrate --raw-truth).
#include <filesystem>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "crfcal/exposure_ratio.hpp"

namespace crfcal::io {

struct RawDecodeOptions {
  bool camera_white_balance = true;  // false: no white balance (unity multipliers) — sensor RGB
  int quality = 3;                   // LibRaw user_qual (demosaic): 0 linear, 1 VNG, 2 PPG, 3 AHD
  bool camera_color_space = false;   // true: output_color = 0 (camera RGB); false: linear sRGB primaries
  bool half_size = false;            // 2× downscaled decode (fast)
};

struct RawImage {
  cv::Mat image;           // CV_16UC3 BGR (OpenCV order), linear, black-subtracted, white level → 65535
  double black_level = 0;  // in raw units, as reported by LibRaw
  double white_level = 0;  // raw units (LibRaw's `maximum`)
  std::string make, model;
  ExifExposure exposure;   // LibRaw's own ISO / shutter / aperture (fallback when Exiv2 cannot read the file)
  std::string summary() const;  // "Kodak DC50, 768x512, black 0, white 255"
};

// True when the file's bytes are a camera RAW LibRaw recognises (not a plain TIFF/JPEG/PNG).
bool isRawFile(const std::filesystem::path& path);

// Decodes a RAW file. Throws crfcal::Error naming the file: missing, unsupported/corrupt, truncated, or without
// real pixel data (e.g. a pruned sample that decodes to an all-zero frame).
RawImage readRaw(const std::filesystem::path& path, const RawDecodeOptions& options = {});

// The camera's own rendering embedded in the RAW (the largest thumbnail/preview LibRaw exposes: JPEG or 8-bit
// bitmap), as 8-bit BGR: a JPEG of the very same shot, e.g. for `calibrate --raw-truth` experiments. Throws
// crfcal::Error naming the file when there is none or it cannot be decoded.
cv::Mat readRawThumbnail(const std::filesystem::path& path);

// LibRaw's metadata only (no decoding): ISO, shutter, aperture, make, model; std::nullopt if LibRaw cannot open it.
std::optional<ExifExposure> readRawExposure(const std::filesystem::path& path);

}  // namespace crfcal::io
