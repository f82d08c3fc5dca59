#include "crfcal/io/pair_input.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/jpeg_info.hpp"
#include "crfcal/io/image_io.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;
namespace {

std::string sniff(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[4] = {};
  in.read(reinterpret_cast<char*>(b), 4);
  if (b[0] == 0xFF && b[1] == 0xD8) return "jpeg";
  if (b[0] == 0x89 && b[1] == 'P') return "png";
  if ((b[0] == 'I' && b[1] == 'I' && b[2] == 42) || (b[0] == 'M' && b[1] == 'M' && b[3] == 42)) return "tiff";
  return "image";
}

std::string sizeText(const cv::Mat& m) { return std::to_string(m.cols) + "x" + std::to_string(m.rows); }

}  // namespace

double normalisedGradientEnergy(const cv::Mat& image) {
  cv::Mat gray = toUnitGray(image);
  const double s = std::min(1.0, 1024.0 / std::max(gray.cols, gray.rows));
  if (s < 1) cv::resize(gray, gray, cv::Size(), s, s, cv::INTER_AREA);
  cv::Mat gx, gy;
  cv::Sobel(gray, gx, CV_64F, 1, 0, 3);
  cv::Sobel(gray, gy, CV_64F, 0, 1, 3);
  cv::Scalar mean, stddev;
  cv::meanStdDev(gray, mean, stddev);
  const double var = stddev[0] * stddev[0];
  return var > 1e-12 ? (cv::mean(gx.mul(gx))[0] + cv::mean(gy.mul(gy))[0]) / var : 0;
}

LoadedImage loadImage(const fs::path& path, const RawDecodeOptions& raw_options) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  if (fs::is_directory(path, ec)) throw Error("is a directory, not an image", path.string());
  if (fs::file_size(path, ec) == 0) throw Error("file is empty", path.string());
  LoadedImage loaded;
  loaded.path = path;
  loaded.format = sniff(path);
  if ((loaded.format == "tiff" || loaded.format == "image") && isRawFile(path)) {
    const RawImage raw = readRaw(path, raw_options);
    loaded.image = raw.image;
    loaded.format = "raw";
    loaded.linear = true;
    loaded.black_level = raw.black_level;
    loaded.white_level = raw.white_level;
    loaded.exposure = readExif(path);
    if (!loaded.exposure.usable()) loaded.exposure = raw.exposure;  // e.g. no ISO tag: LibRaw's value
  } else {
    loaded.image = readImage(path);
    if (loaded.image.depth() == CV_32F) throw Error("floating-point images are not supported (8 or 16 bit)", path.string());
    if (loaded.image.channels() == 4) cv::cvtColor(loaded.image, loaded.image, cv::COLOR_BGRA2BGR);
    loaded.exposure = readExif(path);
    if (loaded.format == "jpeg") {
      const JpegInfo info = readJpegInfo(path);
      loaded.chroma_subsampling = info.subsampling;
      loaded.chroma_subsampled = info.chroma_subsampled();
      if (loaded.chroma_subsampled) {
        loaded.chroma_block_h = info.luma_h;
        loaded.chroma_block_v = info.luma_v;
      }
    }
  }
  loaded.sharpness = normalisedGradientEnergy(loaded.image);
  return loaded;
}

LoadedPair loadPair(const fs::path& first, const fs::path& second, BlurredChoice choice, const RawDecodeOptions& raw) {
  LoadedImage a = loadImage(first, raw), b = loadImage(second, raw);
  const std::string both = first.string() + ", " + second.string();
  // Transposed sizes (one shot portrait, the other landscape) are a pair: calibratePair turns the sharp shot.
  const bool transposed = a.image.size() == cv::Size(b.image.rows, b.image.cols);
  if (a.image.size() != b.image.size() && !transposed)
    throw Error("the images differ in size (" + sizeText(a.image) + " vs " + sizeText(b.image) + ")", both);
  if (a.linear != b.linear)
    throw Error("one image is camera RAW and the other is not; give two RAWs or two rendered images", both);
  if (a.image.channels() != b.image.channels()) throw Error("one image is grey and the other colour", both);
  if (a.image.depth() != b.image.depth()) throw Error("the images differ in bit depth", both);
  const bool known = !a.exposure.model.empty() && !b.exposure.model.empty();
  if (known && (a.exposure.make != b.exposure.make || a.exposure.model != b.exposure.model))
    throw Error("the images come from different cameras (" + a.exposure.camera() + " vs " + b.exposure.camera() + ")",
                both);
  LoadedPair pair;
  pair.transposed = transposed && a.image.size() != b.image.size();
  bool second_is_blurred = true;
  if (choice != BlurredChoice::automatic) {
    second_is_blurred = choice == BlurredChoice::second;
    pair.blurred_reason = "given on the command line";
  } else if (a.exposure.exposure_time && b.exposure.exposure_time &&
             std::abs(std::log(*a.exposure.exposure_time / *b.exposure.exposure_time)) > std::log(1.05)) {
    second_is_blurred = *b.exposure.exposure_time > *a.exposure.exposure_time;
    pair.blurred_reason = "longer exposure (" + formatExposureTime(std::max(*a.exposure.exposure_time, *b.exposure.exposure_time)) +
                          " vs " + formatExposureTime(std::min(*a.exposure.exposure_time, *b.exposure.exposure_time)) + ")";
  } else {
    second_is_blurred = b.sharpness < a.sharpness;
    char buffer[160];
    std::snprintf(buffer, sizeof buffer, "lower normalised gradient energy (%.4g vs %.4g)",
                  std::min(a.sharpness, b.sharpness), std::max(a.sharpness, b.sharpness));
    pair.blurred_reason = buffer;
  }
  pair.swapped = !second_is_blurred;
  pair.sharp = second_is_blurred ? std::move(a) : std::move(b);
  pair.blurred = second_is_blurred ? std::move(b) : std::move(a);
  try {
    pair.exif_ratio = exposureRatio(pair.sharp.exposure, pair.blurred.exposure);
  } catch (const InvalidInput& e) {
    pair.exif_problem = e.what();
  }
  return pair;
}

}  // namespace crfcal::io
