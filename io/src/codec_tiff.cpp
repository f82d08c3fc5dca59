// TIFF through libtiff, as OpenCV 4.6's grfmt_tiff.cpp: an 8-bit result through libtiff's RGBA interface (any
// photometric, palette, 16 → 8 bit by libtiff, unassociated alpha premultiplied), then BGR(A) or grey; 16-bit and
// 32-bit float samples (unchanged mode) as stored, RGB(A) reordered to BGR(A). The first image of the file.
#include <algorithm>
#include <cstdarg>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>
#include <tiffio.h>

#include "crfcal/error.hpp"
#include "image_codecs_internal.hpp"

namespace crfcal::io::codec {
namespace {

struct MemoryFile {
  Bytes bytes;
  toff_t offset = 0;
  std::string message;  // libtiff's last error
};

tmsize_t readProc(thandle_t handle, void* out, tmsize_t size) {
  auto* file = static_cast<MemoryFile*>(handle);
  if (file->offset >= file->bytes.size() || size < 0) return 0;
  const auto count = static_cast<tmsize_t>(
      std::min<std::uint64_t>(static_cast<std::uint64_t>(size), file->bytes.size() - file->offset));
  std::memcpy(out, file->bytes.data() + file->offset, static_cast<std::size_t>(count));
  file->offset += static_cast<toff_t>(count);
  return count;
}
tmsize_t writeProc(thandle_t, void*, tmsize_t) { return -1; }
toff_t seekProc(thandle_t handle, toff_t offset, int whence) {
  auto* file = static_cast<MemoryFile*>(handle);
  if (whence == SEEK_CUR) offset += file->offset;
  else if (whence == SEEK_END) offset += file->bytes.size();
  file->offset = offset;
  return offset;
}
int closeProc(thandle_t) { return 0; }
toff_t sizeProc(thandle_t handle) { return static_cast<MemoryFile*>(handle)->bytes.size(); }
int mapProc(thandle_t handle, void** base, toff_t* size) {
  auto* file = static_cast<MemoryFile*>(handle);
  *base = const_cast<unsigned char*>(file->bytes.data());
  *size = file->bytes.size();
  return 1;
}
void unmapProc(thandle_t, void*, toff_t) {}

int onError(TIFF*, void* user, const char* module, const char* format, va_list args) {
  char text[512];
  std::vsnprintf(text, sizeof text, format, args);
  auto* file = static_cast<MemoryFile*>(user);
  if (file->message.empty()) file->message = (module != nullptr ? std::string(module) + ": " : std::string()) + text;
  return 1;  // handled: libtiff's default handler would print it
}
int onWarning(TIFF*, void*, const char*, const char*, va_list) { return 1; }

struct TiffCloser {
  void operator()(TIFF* tif) const { TIFFClose(tif); }
};

// OpenCV's icvCvt_BGRA2Gray_8u_C4C1R on libtiff's RGBA (BT.601 weights in Q14, rounded).
unsigned char greyOf(std::uint32_t abgr) {
  const int r = static_cast<int>(TIFFGetR(abgr)), g = static_cast<int>(TIFFGetG(abgr)), b = static_cast<int>(TIFFGetB(abgr));
  return static_cast<unsigned char>((b * 1868 + g * 9617 + r * 4899 + (1 << 13)) >> 14);
}

void readThroughRgba(TIFF* tif, cv::Mat& image, MemoryFile& file, const std::string& name) {
  char reason[1024] = {};
  if (!TIFFRGBAImageOK(tif, reason)) throw Error(std::string("unsupported TIFF layout (") + reason + ")", name);
  std::vector<std::uint32_t> raster(image.total());
  if (!TIFFReadRGBAImageOriented(tif, static_cast<std::uint32_t>(image.cols), static_cast<std::uint32_t>(image.rows),
                                 raster.data(), ORIENTATION_TOPLEFT, 0))
    throw Error("corrupt TIFF (" + file.message + ")", name);
  const int channels = image.channels();
  for (int y = 0; y < image.rows; ++y) {
    const std::uint32_t* in = raster.data() + static_cast<std::size_t>(y) * image.cols;
    auto* out = image.ptr<unsigned char>(y);
    for (int x = 0; x < image.cols; ++x) {
      if (channels == 1) {
        out[x] = greyOf(in[x]);
        continue;
      }
      out[channels * x] = static_cast<unsigned char>(TIFFGetB(in[x]));
      out[channels * x + 1] = static_cast<unsigned char>(TIFFGetG(in[x]));
      out[channels * x + 2] = static_cast<unsigned char>(TIFFGetR(in[x]));
      if (channels == 4) out[channels * x + 3] = static_cast<unsigned char>(TIFFGetA(in[x]));
    }
  }
}

// Samples as stored (contiguous planes), rows of `image`'s width and channels; RGB(A) → BGR(A) afterwards.
void readSamples(TIFF* tif, cv::Mat& image, MemoryFile& file, const std::string& name, bool xyz) {
  const std::size_t row_bytes = static_cast<std::size_t>(image.cols) * image.elemSize();
  if (TIFFIsTiled(tif)) {
    std::uint32_t tile_width = 0, tile_height = 0;
    TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tile_width);
    TIFFGetField(tif, TIFFTAG_TILELENGTH, &tile_height);
    const tmsize_t tile_size = TIFFTileSize(tif);
    if (tile_width == 0 || tile_height == 0 ||
        static_cast<std::uint64_t>(tile_size) != static_cast<std::uint64_t>(tile_width) * tile_height * image.elemSize())
      throw Error("unsupported TIFF layout (tiles)", name);
    std::vector<unsigned char> tile(static_cast<std::size_t>(tile_size));
    for (std::uint32_t ty = 0; ty < static_cast<std::uint32_t>(image.rows); ty += tile_height)
      for (std::uint32_t tx = 0; tx < static_cast<std::uint32_t>(image.cols); tx += tile_width) {
        if (TIFFReadTile(tif, tile.data(), tx, ty, 0, 0) < 0) throw Error("corrupt TIFF (" + file.message + ")", name);
        const std::uint32_t h = std::min<std::uint32_t>(tile_height, image.rows - ty);
        const std::uint32_t w = std::min<std::uint32_t>(tile_width, image.cols - tx);
        for (std::uint32_t i = 0; i < h; ++i)
          std::memcpy(image.ptr(static_cast<int>(ty + i)) + tx * image.elemSize(),
                      tile.data() + static_cast<std::size_t>(i) * tile_width * image.elemSize(), w * image.elemSize());
      }
  } else {
    if (static_cast<std::size_t>(TIFFScanlineSize(tif)) != row_bytes) throw Error("unsupported TIFF layout (rows)", name);
    for (int y = 0; y < image.rows; ++y)
      if (TIFFReadScanline(tif, image.ptr(y), static_cast<std::uint32_t>(y), 0) < 0)
        throw Error("corrupt TIFF (" + file.message + ")", name);
  }
  if (image.channels() == 3) cv::cvtColor(image, image, xyz ? cv::COLOR_XYZ2BGR : cv::COLOR_RGB2BGR);
  else if (image.channels() == 4) cv::cvtColor(image, image, cv::COLOR_RGBA2BGRA);
}

}  // namespace

cv::Mat decodeTiff(Bytes bytes, ImageReadMode mode, const std::string& name) {
  MemoryFile file;
  file.bytes = bytes;
  std::unique_ptr<TIFFOpenOptions, void (*)(TIFFOpenOptions*)> options(TIFFOpenOptionsAlloc(), TIFFOpenOptionsFree);
  TIFFOpenOptionsSetErrorHandlerExtR(options.get(), onError, &file);
  TIFFOpenOptionsSetWarningHandlerExtR(options.get(), onWarning, &file);
  std::unique_ptr<TIFF, TiffCloser> tif(TIFFClientOpenExt(name.c_str(), "rm", &file, readProc, writeProc, seekProc,
                                                          closeProc, sizeProc, mapProc, unmapProc, options.get()));
  if (!tif) throw Error("corrupt TIFF (" + file.message + ")", name);
  std::uint32_t width = 0, height = 0;
  std::uint16_t photometric = 0, bits = 1, samples = 1, format = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG;
  if (!TIFFGetField(tif.get(), TIFFTAG_IMAGEWIDTH, &width) || !TIFFGetField(tif.get(), TIFFTAG_IMAGELENGTH, &height) ||
      !TIFFGetField(tif.get(), TIFFTAG_PHOTOMETRIC, &photometric))
    throw Error("corrupt TIFF (no size or photometric interpretation)", name);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_BITSPERSAMPLE, &bits);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_SAMPLESPERPIXEL, &samples);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_SAMPLEFORMAT, &format);
  TIFFGetFieldDefaulted(tif.get(), TIFFTAG_PLANARCONFIG, &planar);
  requirePixelBudget(width, height, name);
  // OpenCV's TiffDecoder::readHeader: grey stays one channel, colour keeps up to 4, a palette is BGR.
  // SGI LogLuv (OpenCV's own encoding of CV_32FC3): floats by libtiff, CIE XYZ → BGR as OpenCV does.
  const bool logluv = photometric == PHOTOMETRIC_LOGLUV;
  if (logluv) TIFFSetField(tif.get(), TIFFTAG_SGILOGDATAFMT, SGILOGDATAFMT_FLOAT);
  const bool grey = photometric == PHOTOMETRIC_MINISWHITE || photometric == PHOTOMETRIC_MINISBLACK;
  const int colour_channels = samples > 4 ? 4 : samples;
  int file_type = -1;
  if (logluv)
    file_type = CV_32FC3;
  else if (bits == 1 || bits == 8)
    file_type = photometric == PHOTOMETRIC_PALETTE ? CV_8UC3 : CV_MAKETYPE(CV_8U, grey ? 1 : colour_channels);
  else if (bits == 16)
    file_type = CV_MAKETYPE(CV_16U, grey ? 1 : colour_channels);
  else if (bits == 32 && format == SAMPLEFORMAT_IEEEFP)
    file_type = CV_MAKETYPE(CV_32F, colour_channels);
  if (file_type < 0)
    throw Error("unsupported TIFF sample format (" + std::to_string(bits) + "-bit" +
                    (format == SAMPLEFORMAT_IEEEFP ? " float" : "") + "; 8/16-bit integer or 32-bit float expected)",
                name);
  cv::Mat image(static_cast<int>(height), static_cast<int>(width), targetType(mode, file_type));
  if (image.depth() == CV_8U) {
    readThroughRgba(tif.get(), image, file, name);
  } else {
    if (planar != PLANARCONFIG_CONTIG || (image.channels() != samples && !logluv) || image.channels() == 2)
      throw Error("unsupported TIFF layout (" + std::to_string(samples) + " samples per pixel" +
                      (planar != PLANARCONFIG_CONTIG ? ", separate planes" : "") + ")",
                  name);
    readSamples(tif.get(), image, file, name, logluv);
  }
  return image;
}

}  // namespace crfcal::io::codec
