// Binary PNM (P5 grey, P6 RGB; 8-bit, or 16-bit big-endian when maxval > 255), as OpenCV 4.6's grfmt_pxm.cpp.
// The format is a text header and raw samples: no library needed.
#include <cctype>
#include <cstdint>
#include <string>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "image_codecs_internal.hpp"

namespace crfcal::io::codec {
namespace {

// The next decimal number of the header, skipping white space and '#' comments; -1 when there is none.
long headerNumber(Bytes bytes, std::size_t& at) {
  while (at < bytes.size()) {
    if (bytes[at] == '#') {
      while (at < bytes.size() && bytes[at] != '\n' && bytes[at] != '\r') ++at;
    } else if (std::isspace(bytes[at])) {
      ++at;
    } else {
      break;
    }
  }
  if (at >= bytes.size() || !std::isdigit(bytes[at])) return -1;
  long value = 0;
  while (at < bytes.size() && std::isdigit(bytes[at]) && value < (1L << 30)) value = value * 10 + (bytes[at++] - '0');
  return value;
}

}  // namespace

cv::Mat decodePnm(Bytes bytes, ImageReadMode mode, const std::string& name) {
  const int channels = bytes[1] == '6' ? 3 : 1;
  std::size_t at = 2;
  const long width = headerNumber(bytes, at), height = headerNumber(bytes, at), maxval = headerNumber(bytes, at);
  if (width <= 0 || height <= 0 || maxval <= 0 || maxval > 65535 || at >= bytes.size() || !std::isspace(bytes[at]))
    throw Error("corrupt PNM header", name);
  ++at;  // the single white-space character before the samples
  requirePixelBudget(static_cast<double>(width), static_cast<double>(height), name);
  const int depth = maxval > 255 ? CV_16U : CV_8U;
  const std::size_t sample_bytes = depth == CV_16U ? 2 : 1;
  const std::size_t row_bytes = static_cast<std::size_t>(width) * channels * sample_bytes;
  if (bytes.size() - at < row_bytes * static_cast<std::size_t>(height))
    throw Error("truncated PNM (premature end of data)", name);
  cv::Mat file(static_cast<int>(height), static_cast<int>(width), CV_MAKETYPE(depth, channels));
  for (int y = 0; y < file.rows; ++y) {
    const unsigned char* in = bytes.data() + at + static_cast<std::size_t>(y) * row_bytes;
    if (depth == CV_8U) {
      std::copy(in, in + row_bytes, file.ptr<unsigned char>(y));
    } else {
      auto* out = file.ptr<std::uint16_t>(y);
      for (std::size_t i = 0; i < row_bytes / 2; ++i)
        out[i] = static_cast<std::uint16_t>((in[2 * i] << 8) | in[2 * i + 1]);
    }
  }
  const int target = targetType(mode, file.type());
  if (CV_MAT_DEPTH(target) != depth) {  // 16 → 8 bit: the high byte
    cv::Mat reduced(file.size(), CV_MAKETYPE(CV_8U, channels));
    for (int y = 0; y < file.rows; ++y) {
      const auto* in = file.ptr<std::uint16_t>(y);
      auto* out = reduced.ptr<unsigned char>(y);
      for (int i = 0; i < file.cols * channels; ++i) out[i] = static_cast<unsigned char>(in[i] >> 8);
    }
    file = reduced;
  }
  cv::Mat image;
  const int target_channels = CV_MAT_CN(target);
  if (channels == 3 && target_channels == 3) cv::cvtColor(file, image, cv::COLOR_RGB2BGR);
  else if (channels == 3) cv::cvtColor(file, image, cv::COLOR_RGB2GRAY);
  else if (target_channels == 3) cv::cvtColor(file, image, cv::COLOR_GRAY2BGR);
  else image = file;
  return image;
}

}  // namespace crfcal::io::codec
