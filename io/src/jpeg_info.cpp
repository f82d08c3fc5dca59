#include "crfcal/io/jpeg_info.hpp"

#include <csetjmp>
#include <cstdio>
#include <memory>

#include <jpeglib.h>

#include "crfcal/error.hpp"

namespace crfcal::io {
namespace {

struct ErrorManager {
  jpeg_error_mgr base;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX] = {};
};

void onError(j_common_ptr info) {
  auto* manager = reinterpret_cast<ErrorManager*>(info->err);
  info->err->format_message(info, manager->message);
  std::longjmp(manager->jump, 1);
}

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
  info.err = jpeg_std_error(&manager.base);
  manager.base.error_exit = onError;
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

}  // namespace crfcal::io
