// JPEG through libjpeg(-turbo), as OpenCV 4.6's grfmt_jpeg.cpp drives it: libjpeg's default DCT (islow) and fancy
// upsampling, colour converted by libjpeg (BGR output), CMYK/YCCK converted with OpenCV's integer formula; the
// encoder with jpeg_set_defaults + jpeg_set_quality(q, TRUE), nothing else.
#include <csetjmp>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <jpeglib.h>
// after jpeglib.h, which it needs
#include <jerror.h>

#include "crfcal/error.hpp"
#include "image_codecs_internal.hpp"
#include "jpeg_error_manager.hpp"

namespace crfcal::io::codec {
namespace {

using ErrorState = detail::JpegErrorManager;

struct Decompressor {
  jpeg_decompress_struct info{};
  ErrorState errors;
  bool created = false;
  Decompressor() {
    errors.install(info);
  }
  ~Decompressor() {
    if (created) jpeg_destroy_decompress(&info);
  }
  Decompressor(const Decompressor&) = delete;
  Decompressor& operator=(const Decompressor&) = delete;
};

// The functions that call setjmp create no C++ object with a destructor between setjmp and libjpeg's calls, so
// longjmp skips nothing; everything they allocate lives in libjpeg's pools (freed by jpeg_destroy_decompress).
bool readHeader(Decompressor& d, Bytes bytes) {
  if (setjmp(d.errors.jump)) return false;
  jpeg_create_decompress(&d.info);
  d.created = true;
  jpeg_mem_src(&d.info, bytes.data(), static_cast<unsigned long>(bytes.size()));
  jpeg_save_markers(&d.info, JPEG_APP0 + 1, 0xFFFF);  // EXIF (OpenCV reads the first APP1's orientation)
  jpeg_read_header(&d.info, TRUE);
  return true;
}

// OpenCV's icvCvt_CMYK2BGR_8u_C4C3R / icvCvt_CMYK2Gray_8u_C4C1R (Adobe's inverted CMYK as libjpeg returns it).
void cmykRow(const JSAMPLE* cmyk, unsigned char* out, int width, int out_channels) {
  for (int x = 0; x < width; ++x, cmyk += 4) {
    const int k = cmyk[3];
    const int c = k - ((255 - cmyk[0]) * k >> 8);
    const int m = k - ((255 - cmyk[1]) * k >> 8);
    const int y = k - ((255 - cmyk[2]) * k >> 8);
    if (out_channels == 3) {
      out[3 * x] = static_cast<unsigned char>(y);
      out[3 * x + 1] = static_cast<unsigned char>(m);
      out[3 * x + 2] = static_cast<unsigned char>(c);
    } else {  // BT.601 weights in Q14, rounded (OpenCV's cB, cG, cR)
      out[x] = static_cast<unsigned char>((y * 1868 + m * 9617 + c * 4899 + (1 << 13)) >> 14);
    }
  }
}

bool readPixels(Decompressor& d, cv::Mat& image) {
  if (setjmp(d.errors.jump)) return false;
  const bool cmyk = d.info.num_components == 4;
  if (cmyk) {
    d.info.out_color_space = JCS_CMYK;
  } else {
    d.info.out_color_space = image.channels() == 3 ? JCS_EXT_BGR : JCS_GRAYSCALE;
  }
  jpeg_start_decompress(&d.info);
  JSAMPARRAY row = (*d.info.mem->alloc_sarray)(reinterpret_cast<j_common_ptr>(&d.info), JPOOL_IMAGE,
                                               d.info.output_width * 4, 1);
  while (d.info.output_scanline < d.info.output_height && !d.errors.premature_end) {
    const int y = static_cast<int>(d.info.output_scanline);
    JSAMPROW target = cmyk ? row[0] : image.ptr<JSAMPLE>(y);
    if (jpeg_read_scanlines(&d.info, &target, 1) != 1) break;
    if (cmyk) cmykRow(row[0], image.ptr<unsigned char>(y), image.cols, image.channels());
  }
  if (!d.errors.premature_end) jpeg_finish_decompress(&d.info);
  return true;
}

int firstApp1Orientation(const jpeg_decompress_struct& info) {
  for (jpeg_saved_marker_ptr marker = info.marker_list; marker != nullptr; marker = marker->next)
    if (marker->marker == JPEG_APP0 + 1) return exifOrientation(marker->data, marker->data_length);
  return 0;
}

}  // namespace

cv::Mat decodeJpeg(Bytes bytes, ImageReadMode mode, const std::string& name, int& orientation) {
  Decompressor d;
  if (!readHeader(d, bytes)) throw Error(std::string("corrupt JPEG (") + d.errors.message + ")", name);
  requirePixelBudget(d.info.image_width, d.info.image_height, name);
  orientation = firstApp1Orientation(d.info);
  const int file_type = d.info.num_components > 1 ? CV_8UC3 : CV_8UC1;
  cv::Mat image(static_cast<int>(d.info.image_height), static_cast<int>(d.info.image_width),
                targetType(mode, file_type));
  if (!readPixels(d, image)) throw Error(std::string("corrupt JPEG (") + d.errors.message + ")", name);
  if (d.errors.premature_end) throw Error("truncated JPEG (premature end of data)", name);
  return image;
}

namespace {

struct Compressor {
  jpeg_compress_struct info{};
  ErrorState errors;
  bool created = false;
  unsigned char* buffer = nullptr;  // jpeg_mem_dest's output, malloc'ed by libjpeg
  unsigned long size = 0;
  Compressor() {
    errors.install(info);
  }
  ~Compressor() {
    if (created) jpeg_destroy_compress(&info);
    std::free(buffer);
  }
  Compressor(const Compressor&) = delete;
  Compressor& operator=(const Compressor&) = delete;
};

bool compress(Compressor& c, const cv::Mat& image, int quality) {
  if (setjmp(c.errors.jump)) return false;
  jpeg_create_compress(&c.info);
  c.created = true;
  jpeg_mem_dest(&c.info, &c.buffer, &c.size);
  c.info.image_width = static_cast<JDIMENSION>(image.cols);
  c.info.image_height = static_cast<JDIMENSION>(image.rows);
  c.info.input_components = image.channels();
  c.info.in_color_space = image.channels() == 3 ? JCS_EXT_BGR : JCS_GRAYSCALE;
  jpeg_set_defaults(&c.info);  // JFIF, YCbCr (BT.601 full range), 4:2:0, standard Huffman tables
  jpeg_set_quality(&c.info, quality, TRUE);
  jpeg_start_compress(&c.info, TRUE);
  while (c.info.next_scanline < c.info.image_height) {
    JSAMPROW row = const_cast<JSAMPROW>(image.ptr<JSAMPLE>(static_cast<int>(c.info.next_scanline)));
    jpeg_write_scanlines(&c.info, &row, 1);
  }
  jpeg_finish_compress(&c.info);
  return true;
}

}  // namespace

}  // namespace crfcal::io::codec

namespace crfcal::io {

std::vector<unsigned char> encodeJpeg(const cv::Mat& image, int quality, const std::string& name) {
  if (image.empty() || image.depth() != CV_8U || image.channels() == 2 || image.channels() > 4)
    throw Error("JPEG needs a non-empty 8-bit grey, BGR or BGRA image", name);
  if (quality < 1 || quality > 100) throw Error("JPEG quality must be 1–100, got " + std::to_string(quality), name);
  cv::Mat input = image;
  if (image.channels() == 4) {  // OpenCV drops the alpha channel
    input.create(image.size(), CV_8UC3);
    cv::mixChannels(image, input, {0, 0, 1, 1, 2, 2});
  }
  codec::Compressor c;
  if (!codec::compress(c, input, quality)) throw Error(std::string("cannot encode JPEG (") + c.errors.message + ")", name);
  return {c.buffer, c.buffer + c.size};
}

}  // namespace crfcal::io
