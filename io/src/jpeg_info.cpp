#include "crfcal/io/jpeg_info.hpp"

#include <csetjmp>
#include <cstdio>
#include <memory>

#include <jpeglib.h>
// after jpeglib.h, which it needs
#include <jerror.h>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "jpeg_error_manager.hpp"

namespace crfcal::io {
namespace {

using ErrorManager = detail::JpegErrorManager;

std::string describe(int components, int h, int v) {
  if (components == 1) return "grey";
  if (h == 1 && v == 1) return "4:4:4";
  if (h == 2 && v == 1) return "4:2:2";
  if (h == 1 && v == 2) return "4:4:0";
  if (h == 2 && v == 2) return "4:2:0";
  if (h == 4 && v == 1) return "4:1:1";
  return std::to_string(h) + "x" + std::to_string(v);
}

}  // namespace

JpegInfo readJpegInfo(const std::filesystem::path& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> file(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!file) throw Error("cannot open", path.string());
  jpeg_decompress_struct info{};
  ErrorManager manager;
  manager.install(info);
  // No C++ objects with destructors are created between setjmp and a possible longjmp.
  if (setjmp(manager.jump)) {
    jpeg_destroy_decompress(&info);
    throw Error(std::string("not a readable JPEG header (") + manager.message + ")", path.string());
  }
  jpeg_create_decompress(&info);
  jpeg_stdio_src(&info, file.get());
  jpeg_read_header(&info, TRUE);
  JpegInfo out;
  out.components = info.num_components;
  if (info.num_components >= 1) {
    out.luma_h = info.comp_info[0].h_samp_factor;
    out.luma_v = info.comp_info[0].v_samp_factor;
    // chroma factors relative to luma (libjpeg stores absolute factors; chroma is normally 1×1)
    if (info.num_components >= 3 && info.comp_info[1].h_samp_factor > 0 && info.comp_info[1].v_samp_factor > 0) {
      out.luma_h /= info.comp_info[1].h_samp_factor;
      out.luma_v /= info.comp_info[1].v_samp_factor;
    }
  }
  jpeg_destroy_decompress(&info);
  out.subsampling = describe(out.components, out.luma_h, out.luma_v);
  return out;
}

JpegSampling jpegSamplingFromString(const std::string& name) {
  if (name == "4:2:0" || name == "420") return JpegSampling::s420;
  if (name == "4:2:2" || name == "422") return JpegSampling::s422;
  if (name == "4:4:4" || name == "444") return JpegSampling::s444;
  throw InvalidInput("unknown JPEG chroma sampling '" + name + "' (4:2:0, 4:2:2 or 4:4:4)");
}

const char* toString(JpegSampling sampling) {
  switch (sampling) {
    case JpegSampling::s420: return "4:2:0";
    case JpegSampling::s422: return "4:2:2";
    case JpegSampling::s444: return "4:4:4";
  }
  return "?";
}

void writeJpegSampled(const std::filesystem::path& path, const cv::Mat& image, int quality, JpegSampling sampling) {
  if (image.depth() != CV_8U || (image.channels() != 1 && image.channels() != 3))
    throw Error("JPEG needs an 8-bit grey or colour image", path.string());
  cv::Mat rgb;
  if (image.channels() == 3) cv::cvtColor(image, rgb, cv::COLOR_BGR2RGB);
  else rgb = image;
  if (!rgb.isContinuous()) rgb = rgb.clone();
  writeAtomically(path, [&](const std::filesystem::path& temporary) {
    std::unique_ptr<FILE, int (*)(FILE*)> file(std::fopen(temporary.c_str(), "wb"), &std::fclose);
    if (!file) throw Error("cannot write image", path.string());
    jpeg_compress_struct info{};
    ErrorManager manager;
    manager.install(info);
    // No C++ objects with destructors are created between setjmp and a possible longjmp.
    if (setjmp(manager.jump)) {
      jpeg_destroy_compress(&info);
      throw Error(std::string("cannot encode JPEG (") + manager.message + ")", path.string());
    }
    jpeg_create_compress(&info);
    jpeg_stdio_dest(&info, file.get());
    info.image_width = static_cast<JDIMENSION>(rgb.cols);
    info.image_height = static_cast<JDIMENSION>(rgb.rows);
    info.input_components = rgb.channels();
    info.in_color_space = rgb.channels() == 3 ? JCS_RGB : JCS_GRAYSCALE;
    jpeg_set_defaults(&info);  // JFIF YCbCr (BT.601 full range), 4:2:0
    jpeg_set_quality(&info, quality, TRUE);
    if (rgb.channels() == 3) {
      info.comp_info[0].h_samp_factor = sampling == JpegSampling::s444 ? 1 : 2;
      info.comp_info[0].v_samp_factor = sampling == JpegSampling::s420 ? 2 : 1;
    }
    jpeg_start_compress(&info, TRUE);
    while (info.next_scanline < info.image_height) {
      JSAMPROW row = const_cast<JSAMPROW>(rgb.ptr<unsigned char>(static_cast<int>(info.next_scanline)));
      jpeg_write_scanlines(&info, &row, 1);
    }
    jpeg_finish_compress(&info);
    jpeg_destroy_compress(&info);
  });
}

void requireCompleteJpeg(const unsigned char* data, std::size_t size, const std::filesystem::path& path) {
  jpeg_decompress_struct info{};
  ErrorManager manager;
  manager.install(info);
  // No C++ objects with destructors are created between setjmp and a possible longjmp.
  if (setjmp(manager.jump)) {
    jpeg_destroy_decompress(&info);
    throw Error(std::string("corrupt JPEG (") + manager.message + ")", path.string());
  }
  jpeg_create_decompress(&info);
  jpeg_mem_src(&info, const_cast<unsigned char*>(data), static_cast<unsigned long>(size));
  jpeg_read_header(&info, TRUE);
  const double pixels = static_cast<double>(info.image_width) * info.image_height;
  if (pixels > kMaxImagePixels) {
    const std::string size = std::to_string(info.image_width) + "x" + std::to_string(info.image_height);
    jpeg_destroy_decompress(&info);
    throw Error("image too large (" + size + "; at most " + std::to_string(kMaxImagePixels / 1000000) +
                " megapixels)", path.string());
  }
  info.scale_num = 1;
  info.scale_denom = 8;  // the whole stream is still entropy-decoded, only the inverse DCT is reduced
  info.dct_method = JDCT_IFAST;
  jpeg_start_decompress(&info);
  // the row buffer comes from libjpeg's own pool: freed by jpeg_destroy_decompress, also after a longjmp
  JSAMPARRAY rows = (*info.mem->alloc_sarray)(reinterpret_cast<j_common_ptr>(&info), JPOOL_IMAGE,
                                              info.output_width * info.output_components, 1);
  while (info.output_scanline < info.output_height && !manager.premature_end) jpeg_read_scanlines(&info, rows, 1);
  const bool truncated = manager.premature_end;
  jpeg_abort_decompress(&info);
  jpeg_destroy_decompress(&info);
  if (truncated) throw Error("truncated JPEG (premature end of data)", path.string());
}

}  // namespace crfcal::io
