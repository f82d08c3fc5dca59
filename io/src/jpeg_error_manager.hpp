// libjpeg's error manager for io/'s JPEG readers and writers (jpeg_info.cpp, codec_jpeg.cpp), private to io/.
// libjpeg's default error_exit calls exit(): jump back to the caller's setjmp instead, with the message; warnings are
// not printed, but a stream that ends before the last scanline (JWRN_JPEG_EOF: libjpeg pads the rest with grey) is
// remembered so that the caller can refuse the file.
#pragma once

#include <csetjmp>
#include <cstdio>

#include <jpeglib.h>
// after jpeglib.h, which it needs
#include <jerror.h>

namespace crfcal::io::detail {

struct JpegErrorManager {
  jpeg_error_mgr base;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX] = {};
  bool premature_end = false;

  // Installs this manager as `info`'s (a jpeg_compress_struct or jpeg_decompress_struct).
  template <class Info>
  void install(Info& info) {
    info.err = jpeg_std_error(&base);
    base.error_exit = &JpegErrorManager::onError;
    base.emit_message = &JpegErrorManager::onMessage;
  }

  static void onError(j_common_ptr info) {
    auto* self = reinterpret_cast<JpegErrorManager*>(info->err);
    info->err->format_message(info, self->message);
    std::longjmp(self->jump, 1);
  }
  static void onMessage(j_common_ptr info, int level) {
    auto* self = reinterpret_cast<JpegErrorManager*>(info->err);
    if (level < 0 && info->err->msg_code == JWRN_JPEG_EOF) self->premature_end = true;
  }
};

}  // namespace crfcal::io::detail
