#pragma once
// Loading a sharp/blurred pair for `crfcal calibrate`: the format is decided by content (JPEG/PNG/TIFF through
// OpenCV, camera RAW through LibRaw, linear 16-bit), EXIF is read (Exiv2, LibRaw as fallback), and which image is
// the blurred one is FOUND: the longer exposure when the EXIF says so, else the lower normalised gradient
// energy E|∇I|² / Var(I) (blur removes high frequencies; normalising removes the exposure difference).
#include <filesystem>
#include <optional>
#include <string>

#include <opencv2/core.hpp>

#include "crfcal/exposure_ratio.hpp"
#include "crfcal/io/raw_image.hpp"

namespace crfcal::io {

struct LoadedImage {
  std::filesystem::path path;
  cv::Mat image;          // grey or BGR, CV_8U or CV_16U
  std::string format;     // "jpeg", "png", "tiff", "raw", "image"
  bool linear = false;    // RAW: proportional to irradiance
  double black_level = 0, white_level = 0;  // RAW only
  ExifExposure exposure;
  double sharpness = 0;   // normalised gradient energy
  std::string chroma_subsampling;  // JPEG: "4:2:0", "4:4:4", … (jpeg_info.hpp); empty for other formats
  bool chroma_subsampled = false;
  int chroma_block_h = 1, chroma_block_v = 1;  // JPEG: luma pixels per chroma sample (2×2 for 4:2:0); else 1×1  // JPEG with chroma stored below full resolution (JpegInfo::chroma_subsampled)
};

// Reads one image (RAW decoded linearly). Throws crfcal::Error naming the file.
LoadedImage loadImage(const std::filesystem::path& path, const RawDecodeOptions& raw = {});

enum class BlurredChoice { automatic, first, second };

struct LoadedPair {
  LoadedImage sharp, blurred;
  bool swapped = false;         // the first argument turned out to be the blurred image
  bool transposed = false;      // portrait vs landscape (W×H vs H×W): calibratePair turns the sharp shot
  std::string blurred_reason;   // why this one is the blurred image
  std::optional<ExposureRatioFactors> exif_ratio;  // footnote 4, when both EXIFs are usable
  std::string exif_problem;     // why there is no EXIF ratio
};

// Loads both, checks they can form a pair (same size — or transposed, portrait vs landscape —, same camera when
// both say, same kind), decides the blurred one. Throws crfcal::Error with a one-line reason naming the file(s).
LoadedPair loadPair(const std::filesystem::path& first, const std::filesystem::path& second,
                    BlurredChoice choice = BlurredChoice::automatic, const RawDecodeOptions& raw = {});

// E|∇I|² / Var(I) on a grey copy downscaled to ≤ 1024 px (higher = sharper).
double normalisedGradientEnergy(const cv::Mat& image);

}  // namespace crfcal::io
