#include "crfcal/io/raw_image.hpp"

#include <cstdio>
#include <fstream>
#include <memory>

#include <libraw/libraw.h>
#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/image_codecs.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;
namespace {

bool hasPlainImageMagic(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  unsigned char b[8] = {};
  in.read(reinterpret_cast<char*>(b), 8);
  if (in.gcount() < 4) return false;
  if (b[0] == 0xFF && b[1] == 0xD8) return true;                            // JPEG
  if (b[0] == 0x89 && b[1] == 'P' && b[2] == 'N' && b[3] == 'G') return true;  // PNG
  if ((b[0] == 'B' && b[1] == 'M') || (b[0] == 'P' && b[1] >= '1' && b[1] <= '6')) return true;  // BMP, PNM
  return false;
}

ExifExposure exposureFrom(const LibRaw& raw) {
  ExifExposure e;
  const auto& other = raw.imgdata.other;
  if (other.iso_speed > 0) {
    e.iso = other.iso_speed;
    e.iso_source = "LibRaw";
  }
  if (other.shutter > 0) {
    e.exposure_time = other.shutter;
    e.exposure_time_source = "LibRaw";
  }
  if (other.aperture > 0) {
    e.f_number = other.aperture;
    e.f_number_source = "LibRaw";
  }
  if (other.focal_len > 0) e.focal_length = other.focal_len;
  e.make = raw.imgdata.idata.make;
  e.model = raw.imgdata.idata.model;
  return e;
}

std::string librawError(int code) { return libraw_strerror(code); }

}  // namespace

std::string RawImage::summary() const {
  char buffer[256];
  std::snprintf(buffer, sizeof buffer, "%s %s, %dx%d, black %g, white %g, linear 16-bit", make.c_str(), model.c_str(),
                image.cols, image.rows, black_level, white_level);
  return buffer;
}

bool isRawFile(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec) || hasPlainImageMagic(path)) return false;
  auto raw = std::make_unique<LibRaw>();
  const bool ok = raw->open_file(path.string().c_str()) == LIBRAW_SUCCESS;
  return ok && raw->imgdata.idata.raw_count > 0;
}

std::optional<ExifExposure> readRawExposure(const fs::path& path) {
  auto raw = std::make_unique<LibRaw>();
  if (raw->open_file(path.string().c_str()) != LIBRAW_SUCCESS) return std::nullopt;
  return exposureFrom(*raw);
}

RawImage readRaw(const fs::path& path, const RawDecodeOptions& options) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  auto raw = std::make_unique<LibRaw>();  // LibRaw is large: keep it off the stack
  auto& params = raw->imgdata.params;
  params.output_bps = 16;
  params.gamm[0] = 1.0;
  params.gamm[1] = 1.0;
  params.no_auto_bright = 1;
  params.use_camera_wb = options.camera_white_balance ? 1 : 0;
  params.use_auto_wb = 0;
  if (!options.camera_white_balance)
    for (int c = 0; c < 4; ++c) params.user_mul[c] = 1.0f;
  params.user_qual = options.quality;
  params.output_color = options.camera_color_space ? 0 : 1;
  params.half_size = options.half_size ? 1 : 0;
  params.highlight = 0;  // clip highlights (keep linearity below the white level)

  int code = raw->open_file(path.string().c_str());
  if (code != LIBRAW_SUCCESS) throw Error("not a readable camera RAW (" + librawError(code) + ")", path.string());
  code = raw->unpack();
  if (code != LIBRAW_SUCCESS) throw Error("corrupt or truncated RAW data (" + librawError(code) + ")", path.string());
  code = raw->dcraw_process();
  if (code != LIBRAW_SUCCESS) throw Error("cannot process RAW data (" + librawError(code) + ")", path.string());
  int error = 0;
  libraw_processed_image_t* processed = raw->dcraw_make_mem_image(&error);
  if (processed == nullptr) throw Error("cannot render RAW image (" + librawError(error) + ")", path.string());
  std::unique_ptr<libraw_processed_image_t, void (*)(libraw_processed_image_t*)> guard(processed,
                                                                                     LibRaw::dcraw_clear_mem);
  if (processed->type != LIBRAW_IMAGE_BITMAP || processed->bits != 16 || (processed->colors != 3 && processed->colors != 1))
    throw Error("unexpected RAW rendering (not a 16-bit bitmap)", path.string());
  const int type = processed->colors == 3 ? CV_16UC3 : CV_16UC1;
  cv::Mat view(processed->height, processed->width, type, processed->data);
  RawImage result;
  if (processed->colors == 3) cv::cvtColor(view, result.image, cv::COLOR_RGB2BGR);
  else result.image = view.clone();
  double max_value = 0;
  cv::minMaxLoc(result.image.reshape(1), nullptr, &max_value);
  if (max_value <= 0)
    throw Error("the RAW file has no image data (all pixels are zero; pruned or placeholder sample?)", path.string());
  result.black_level = raw->imgdata.color.black;
  result.white_level = raw->imgdata.color.maximum;
  result.make = raw->imgdata.idata.make;
  result.model = raw->imgdata.idata.model;
  result.exposure = exposureFrom(*raw);
  return result;
}

cv::Mat readRawThumbnail(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  auto raw = std::make_unique<LibRaw>();
  int code = raw->open_file(path.string().c_str());
  if (code != LIBRAW_SUCCESS) throw Error("not a readable camera RAW (" + librawError(code) + ")", path.string());
  code = raw->unpack_thumb();
  if (code != LIBRAW_SUCCESS) throw Error("no usable embedded preview (" + librawError(code) + ")", path.string());
  int error = 0;
  libraw_processed_image_t* thumb = raw->dcraw_make_mem_thumb(&error);
  if (thumb == nullptr) throw Error("cannot extract the embedded preview (" + librawError(error) + ")", path.string());
  std::unique_ptr<libraw_processed_image_t, void (*)(libraw_processed_image_t*)> guard(thumb, LibRaw::dcraw_clear_mem);
  cv::Mat image;
  if (thumb->type == LIBRAW_IMAGE_JPEG) {
    try {
      image = decodeImage({thumb->data, thumb->data_size}, ImageReadMode::color, path.string());
    } catch (const Error&) {
      image.release();  // refused below with the preview's own message
    }
  } else if (thumb->type == LIBRAW_IMAGE_BITMAP && thumb->bits == 8 && (thumb->colors == 3 || thumb->colors == 1)) {
    const cv::Mat view(thumb->height, thumb->width, thumb->colors == 3 ? CV_8UC3 : CV_8UC1, thumb->data);
    if (thumb->colors == 3) cv::cvtColor(view, image, cv::COLOR_RGB2BGR);
    else cv::cvtColor(view, image, cv::COLOR_GRAY2BGR);
  }
  if (image.empty()) throw Error("the embedded preview is not a decodable JPEG or 8-bit bitmap", path.string());
  return image;
}

}  // namespace crfcal::io
