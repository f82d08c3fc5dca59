#include "crfcal/io/image_codecs.hpp"

#include <algorithm>
#include <cctype>
#include <string>

#include <exiv2/exiv2.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/jpeg_info.hpp"
#include "image_codecs_internal.hpp"

namespace crfcal::io {
namespace codec {

void requirePixelBudget(double width, double height, const std::string& name) {
  if (width * height > static_cast<double>(kMaxImagePixels))
    throw Error("image too large (" + std::to_string(static_cast<long long>(width)) + "x" +
                    std::to_string(static_cast<long long>(height)) + "; at most " +
                    std::to_string(kMaxImagePixels / 1000000) + " megapixels)",
                name);
  if (width < 1 || height < 1) throw Error("not a readable image (its header gives no pixels)", name);
}

int targetType(ImageReadMode mode, int file_type) {
  switch (mode) {
    case ImageReadMode::unchanged: return file_type;
    case ImageReadMode::color: return CV_8UC3;
    case ImageReadMode::grey: return CV_8UC1;
  }
  return file_type;
}

int exifOrientation(const unsigned char* data, std::size_t size) {
  static const unsigned char kExifHeader[] = {'E', 'x', 'i', 'f', 0, 0};
  if (size <= sizeof kExifHeader || !std::equal(std::begin(kExifHeader), std::end(kExifHeader), data)) return 0;
  try {
    Exiv2::LogMsg::setLevel(Exiv2::LogMsg::mute);
    Exiv2::ExifData exif;
    Exiv2::ExifParser::decode(exif, data + sizeof kExifHeader, static_cast<uint32_t>(size - sizeof kExifHeader));
    const auto entry = exif.findKey(Exiv2::ExifKey("Exif.Image.Orientation"));
    if (entry == exif.end() || entry->count() == 0) return 0;
    const long value = entry->toLong();
    return value >= 1 && value <= 8 ? static_cast<int>(value) : 0;
  } catch (const std::exception&) {
    return 0;  // a damaged EXIF block: OpenCV ignores it too
  }
}

}  // namespace codec

namespace {

enum class Format { jpeg, png, tiff, pnm, other_image, unknown };

Format formatOf(std::span<const unsigned char> b) {
  const auto starts = [&](std::initializer_list<unsigned char> magic) {
    return b.size() >= magic.size() && std::equal(magic.begin(), magic.end(), b.begin());
  };
  if (starts({0xFF, 0xD8, 0xFF})) return Format::jpeg;
  if (starts({0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'})) return Format::png;
  if (starts({'I', 'I', 42, 0}) || starts({'M', 'M', 0, 42}) || starts({'I', 'I', 43, 0}) || starts({'M', 'M', 0, 43}))
    return Format::tiff;  // classic or BigTIFF
  if (b.size() >= 3 && b[0] == 'P' && (b[1] == '5' || b[1] == '6') && std::isspace(b[2])) return Format::pnm;
  // Formats OpenCV reads and crfcal does not: BMP, other PNM/PFM/PAM, WebP, OpenEXR, JPEG 2000, Radiance HDR, Sun
  // raster, GIF.
  if (starts({'B', 'M'}) || (b.size() >= 2 && b[0] == 'P' && std::string("1234fF7").find(static_cast<char>(b[1])) != std::string::npos) ||
      (starts({'R', 'I', 'F', 'F'}) && b.size() >= 12 && std::equal(b.begin() + 8, b.begin() + 12, "WEBP")) ||
      starts({0x76, 0x2F, 0x31, 0x01}) || starts({0, 0, 0, 0x0C, 'j', 'P', ' ', ' '}) || starts({0xFF, 0x4F, 0xFF, 0x51}) ||
      starts({'#', '?'}) || starts({0x59, 0xA6, 0x6A, 0x95}) || starts({'G', 'I', 'F', '8'}))
    return Format::other_image;
  return Format::unknown;
}

// OpenCV's ApplyExifOrientation (loadsave.cpp): the stored rows turned to how the camera was held.
void applyOrientation(int orientation, cv::Mat& image) {
  switch (orientation) {
    case 2: cv::flip(image, image, 1); break;
    case 3: cv::flip(image, image, -1); break;
    case 4: cv::flip(image, image, 0); break;
    case 5: cv::transpose(image, image); break;
    case 6: cv::transpose(image, image), cv::flip(image, image, 1); break;
    case 7: cv::transpose(image, image), cv::flip(image, image, -1); break;
    case 8: cv::transpose(image, image), cv::flip(image, image, 0); break;
    default: break;  // 1 (as stored) or no tag
  }
}

}  // namespace

cv::Mat decodeImage(std::span<const unsigned char> bytes, ImageReadMode mode, const std::string& name) {
  if (bytes.empty()) throw Error("file is empty", name);
  int orientation = 0;
  cv::Mat image;
  switch (formatOf(bytes)) {
    case Format::jpeg: image = codec::decodeJpeg(bytes, mode, name, orientation); break;
    case Format::png: image = codec::decodePng(bytes, mode, name); break;
    case Format::tiff: image = codec::decodeTiff(bytes, mode, name); break;
    case Format::pnm: image = codec::decodePnm(bytes, mode, name); break;
    case Format::other_image: throw Error("unsupported image format (crfcal reads JPEG, PNG, TIFF, PNM)", name);
    case Format::unknown: throw Error("not a readable image (corrupt or unsupported format)", name);
  }
  if (mode != ImageReadMode::unchanged) applyOrientation(orientation, image);
  return image;
}

}  // namespace crfcal::io
