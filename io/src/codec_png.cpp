// PNG through libpng, with OpenCV 4.6's transformations (grfmt_png.cpp): no gamma, no sBIT shift; 16 → 8 bit by
// png_set_strip_16 (the high byte); palette expanded; alpha kept only for a 4-channel result (tRNS as alpha);
// grey expanded to BGR by copying, colour to grey with libpng's 0.299/0.587/0.114.
#include <algorithm>
#include <bit>
#include <csetjmp>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include <png.h>

#include "crfcal/error.hpp"
#include "image_codecs_internal.hpp"

namespace crfcal::io::codec {
namespace {

struct ReadState {
  Bytes bytes;
  std::size_t offset = 0;
  char message[200] = {};
};

void onError(png_structp png, png_const_charp message) {
  auto* state = static_cast<ReadState*>(png_get_error_ptr(png));
  std::snprintf(state->message, sizeof state->message, "%s", message);
  png_longjmp(png, 1);
}

void onWarning(png_structp, png_const_charp) {}  // OpenCV prints them; one line per bad file is the rule

void readBytes(png_structp png, png_bytep out, png_size_t length) {
  auto* state = static_cast<ReadState*>(png_get_io_ptr(png));
  if (length > state->bytes.size() - state->offset) png_error(png, "truncated PNG (premature end of data)");
  std::memcpy(out, state->bytes.data() + state->offset, length);
  state->offset += length;
}

struct Reader {
  ReadState state;
  png_structp png = nullptr;
  png_infop info = nullptr;
  ~Reader() { png_destroy_read_struct(&png, info != nullptr ? &info : nullptr, nullptr); }
};

std::uint32_t bigEndian32(const unsigned char* p) {
  return (std::uint32_t{p[0]} << 24) | (std::uint32_t{p[1]} << 16) | (std::uint32_t{p[2]} << 8) | p[3];
}

// setjmp: no C++ object with a destructor is created in these two functions after it.
bool readInfo(Reader& r) {
  if (setjmp(png_jmpbuf(r.png))) return false;
  png_set_read_fn(r.png, &r.state, readBytes);
  png_read_info(r.png, r.info);
  return true;
}

bool readRows(Reader& r, png_bytepp rows, int channels, int depth) {
  if (setjmp(png_jmpbuf(r.png))) return false;
  const int bit_depth = png_get_bit_depth(r.png, r.info), color_type = png_get_color_type(r.png, r.info);
  if (depth == CV_8U && bit_depth == 16) png_set_strip_16(r.png);
  else if (std::endian::native == std::endian::little) png_set_swap(r.png);  // 16-bit samples in host order
  if (channels < 4) png_set_strip_alpha(r.png);
  else png_set_tRNS_to_alpha(r.png);
  if (color_type == PNG_COLOR_TYPE_PALETTE) png_set_palette_to_rgb(r.png);
  if ((color_type & PNG_COLOR_MASK_COLOR) == 0 && bit_depth < 8) png_set_expand_gray_1_2_4_to_8(r.png);
  if ((color_type & PNG_COLOR_MASK_COLOR) && channels > 1) png_set_bgr(r.png);
  else if (channels > 1) png_set_gray_to_rgb(r.png);
  else png_set_rgb_to_gray(r.png, 1, 0.299, 0.587);
  png_set_interlace_handling(r.png);
  png_read_update_info(r.png, r.info);
  if (png_get_rowbytes(r.png, r.info) != static_cast<png_size_t>(png_get_image_width(r.png, r.info)) * channels *
                                               (depth == CV_8U ? 1 : 2))
    png_error(r.png, "unexpected sample layout");
  png_read_image(r.png, rows);
  png_read_end(r.png, nullptr);
  return true;
}

}  // namespace

cv::Mat decodePng(Bytes bytes, ImageReadMode mode, const std::string& name) {
  // The size from IHDR before libpng sees it: a forged header (its CRC not updated) is "too large", not a CRC error.
  if (bytes.size() >= 24) requirePixelBudget(bigEndian32(&bytes[16]), bigEndian32(&bytes[20]), name);
  Reader r;
  r.state.bytes = bytes;
  r.png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &r.state, onError, onWarning);
  if (r.png != nullptr) r.info = png_create_info_struct(r.png);
  if (r.png == nullptr || r.info == nullptr) throw Error("cannot decode PNG (out of memory)", name);
  if (!readInfo(r)) throw Error(std::string("corrupt PNG (") + r.state.message + ")", name);
  const png_uint_32 width = png_get_image_width(r.png, r.info), height = png_get_image_height(r.png, r.info);
  requirePixelBudget(width, height, name);
  const int color_type = png_get_color_type(r.png, r.info);
  int file_channels = 1;  // OpenCV's PngDecoder::readHeader
  if (color_type == PNG_COLOR_TYPE_RGB || color_type == PNG_COLOR_TYPE_PALETTE) {
    png_bytep trans = nullptr;
    int num_trans = 0;
    png_color_16p trans_values = nullptr;
    png_get_tRNS(r.png, r.info, &trans, &num_trans, &trans_values);
    file_channels = num_trans > 0 ? 4 : 3;
  } else if (color_type == PNG_COLOR_TYPE_GRAY_ALPHA || color_type == PNG_COLOR_TYPE_RGB_ALPHA) {
    file_channels = 4;
  }
  const int file_depth = png_get_bit_depth(r.png, r.info) == 16 ? CV_16U : CV_8U;
  cv::Mat image(static_cast<int>(height), static_cast<int>(width),
                targetType(mode, CV_MAKETYPE(file_depth, file_channels)));
  std::vector<png_bytep> rows(height);
  for (int y = 0; y < image.rows; ++y) rows[static_cast<std::size_t>(y)] = image.ptr(y);
  if (!readRows(r, rows.data(), image.channels(), image.depth()))
    throw Error(std::string("corrupt PNG (") + r.state.message + ")", name);
  return image;
}

}  // namespace crfcal::io::codec

namespace crfcal::io {
namespace {

void appendBytes(png_structp png, png_bytep data, png_size_t length) {
  auto* out = static_cast<std::vector<unsigned char>*>(png_get_io_ptr(png));
  out->insert(out->end(), data, data + length);
}

void flushNothing(png_structp) {}

struct Writer {
  codec::ReadState state;  // only its message
  png_structp png = nullptr;
  png_infop info = nullptr;
  ~Writer() { png_destroy_write_struct(&png, info != nullptr ? &info : nullptr); }
};

bool writeRows(Writer& w, std::vector<unsigned char>* out, const cv::Mat& image, png_bytepp rows) {
  if (setjmp(png_jmpbuf(w.png))) return false;
  png_set_write_fn(w.png, out, appendBytes, flushNothing);
  // OpenCV's default (grfmt_png.cpp): the Sub filter, zlib level 1 (Z_BEST_SPEED), the RLE strategy (Z_RLE = 3).
  png_set_filter(w.png, PNG_FILTER_TYPE_BASE, PNG_FILTER_SUB);
  png_set_compression_level(w.png, 1);
  png_set_compression_strategy(w.png, 3);
  const int channels = image.channels();
  const int color_type = channels == 1   ? PNG_COLOR_TYPE_GRAY
                         : channels == 3 ? PNG_COLOR_TYPE_RGB
                                         : PNG_COLOR_TYPE_RGB_ALPHA;
  png_set_IHDR(w.png, w.info, static_cast<png_uint_32>(image.cols), static_cast<png_uint_32>(image.rows),
               image.depth() == CV_8U ? 8 : 16, color_type, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(w.png, w.info);
  if (channels > 1) png_set_bgr(w.png);
  if (image.depth() == CV_16U && std::endian::native == std::endian::little) png_set_swap(w.png);
  png_write_image(w.png, rows);
  png_write_end(w.png, w.info);
  return true;
}

}  // namespace

std::vector<unsigned char> encodePng(const cv::Mat& image, const std::string& name) {
  if (image.empty() || (image.depth() != CV_8U && image.depth() != CV_16U) ||
      (image.channels() != 1 && image.channels() != 3 && image.channels() != 4))
    throw Error("PNG needs a non-empty 8/16-bit grey, BGR or BGRA image", name);
  Writer w;
  w.png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &w.state, codec::onError, codec::onWarning);
  if (w.png != nullptr) w.info = png_create_info_struct(w.png);
  if (w.png == nullptr || w.info == nullptr) throw Error("cannot encode PNG (out of memory)", name);
  std::vector<png_bytep> rows(static_cast<std::size_t>(image.rows));
  for (int y = 0; y < image.rows; ++y) rows[static_cast<std::size_t>(y)] = const_cast<png_bytep>(image.ptr(y));
  std::vector<unsigned char> out;
  out.reserve(image.total() * image.elemSize() / 2 + 1024);
  if (!writeRows(w, &out, image, rows.data())) throw Error(std::string("cannot encode PNG (") + w.state.message + ")", name);
  return out;
}

}  // namespace crfcal::io
