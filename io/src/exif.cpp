#include "crfcal/io/exif.hpp"

#include <cmath>
#include <mutex>

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wdeprecated-declarations"
#include <exiv2/exiv2.hpp>

#include "crfcal/error.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;
namespace {

void initialiseExiv2() {
  static std::once_flag once;
  std::call_once(once, [] {
    Exiv2::LogMsg::setLevel(Exiv2::LogMsg::mute);
#ifdef EXV_ENABLE_BMFF
    Exiv2::enableBMFF(true);  // CR3, HEIF, AVIF
#endif
  });
}

std::optional<double> positive(const Exiv2::ExifData& data, const char* key) {
  const auto it = data.findKey(Exiv2::ExifKey(key));
  if (it == data.end() || it->count() == 0) return std::nullopt;
  double value = 0;
  if (it->typeId() == Exiv2::unsignedRational || it->typeId() == Exiv2::signedRational) {
    const Exiv2::Rational q = it->toRational(0);
    if (q.second == 0) return std::nullopt;
    value = static_cast<double>(q.first) / q.second;
  } else {
    value = it->toFloat(0);
  }
  if (!std::isfinite(value) || !(value > 0)) return std::nullopt;
  return value;
}

std::optional<double> signedValue(const Exiv2::ExifData& data, const char* key) {
  const auto it = data.findKey(Exiv2::ExifKey(key));
  if (it == data.end() || it->count() == 0) return std::nullopt;
  double value = 0;
  if (it->typeId() == Exiv2::unsignedRational || it->typeId() == Exiv2::signedRational) {
    const Exiv2::Rational q = it->toRational(0);
    if (q.second == 0) return std::nullopt;
    value = static_cast<double>(q.first) / q.second;
  } else {
    value = it->toFloat(0);
  }
  if (!std::isfinite(value)) return std::nullopt;
  return value;
}

std::string text(const Exiv2::ExifData& data, const char* key) {
  const auto it = data.findKey(Exiv2::ExifKey(key));
  if (it == data.end()) return {};
  std::string value = it->toString();
  while (!value.empty() && (value.back() == ' ' || value.back() == '\0')) value.pop_back();
  while (!value.empty() && value.front() == ' ') value.erase(value.begin());
  return value;
}

}  // namespace

ExifExposure readExif(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  initialiseExiv2();
  ExifExposure exposure;
  Exiv2::ExifData data;
  try {
    auto image = Exiv2::ImageFactory::open(path.string());
    if (image.get() == nullptr) return exposure;
    image->readMetadata();
    data = image->exifData();
  } catch (const std::exception&) {
    return exposure;  // not a format Exiv2 knows, or corrupt metadata: no EXIF
  }
  if (data.empty()) return exposure;

  // ISO: Exiv2's easy-access list first (standard tags and many maker notes), then the EXIF 2.3 names and
  // the maker-note keys it may miss.
  try {
    const auto it = Exiv2::isoSpeed(data);
    if (it != data.end() && it->count() > 0) {
      const double value = it->toFloat(0);
      if (std::isfinite(value) && value > 0 && value < 1e7) {
        exposure.iso = value;
        exposure.iso_source = it->key();
      }
    }
  } catch (const std::exception&) {
  }
  for (const char* key : {"Exif.Photo.ISOSpeedRatings", "Exif.Photo.PhotographicSensitivity", "Exif.Image.ISOSpeedRatings",
                          "Exif.Photo.RecommendedExposureIndex", "Exif.Photo.ISOSpeed", "Exif.Photo.ExposureIndex",
                          "Exif.Nikon3.ISOSpeed", "Exif.NikonIi.ISO", "Exif.Nikon3.ISOSettings", "Exif.CanonSi.ISOSpeed",
                          "Exif.CanonCs.ISOSpeed", "Exif.Sony2.ISOSetting", "Exif.Pentax.ISO"}) {
    if (exposure.iso) break;
    try {
      if (auto v = positive(data, key)) {
        // Nikon3.ISOSpeed is (0, ISO): take the second component.
        const auto it = data.findKey(Exiv2::ExifKey(key));
        double value = *v;
        if (it->count() > 1 && it->toFloat(0) == 0) value = it->toFloat(1);
        // CanonSi.ISOSpeed stores 32·log2(ISO·32/100) (Exiv2 prints ISO = 100/32 · 2^(v/32)).
        if (std::string(key) == "Exif.CanonSi.ISOSpeed") value = 100.0 * std::exp2(value / 32.0 - 5.0);
        if (value > 0 && value < 1e7) {
          exposure.iso = value;
          exposure.iso_source = key;
        }
      }
    } catch (const std::exception&) {
    }
  }

  try {
    for (const char* key : {"Exif.Photo.ExposureTime", "Exif.Image.ExposureTime"}) {
      if (auto v = positive(data, key)) {
        exposure.exposure_time = *v;
        exposure.exposure_time_source = key;
        break;
      }
    }
    if (!exposure.exposure_time) {
      for (const char* key : {"Exif.Photo.ShutterSpeedValue", "Exif.Image.ShutterSpeedValue"}) {
        if (auto tv = signedValue(data, key)) {  // APEX: Tv = −log2 t
          exposure.exposure_time = std::exp2(-*tv);
          exposure.exposure_time_source = std::string(key) + " (APEX)";
          break;
        }
      }
    }
    for (const char* key : {"Exif.Photo.FNumber", "Exif.Image.FNumber"}) {
      if (auto v = positive(data, key)) {
        exposure.f_number = *v;
        exposure.f_number_source = key;
        break;
      }
    }
    if (!exposure.f_number) {
      for (const char* key : {"Exif.Photo.ApertureValue", "Exif.Image.ApertureValue"}) {
        if (auto av = signedValue(data, key)) {  // APEX: Av = 2 log2 N
          exposure.f_number = std::exp2(*av / 2.0);
          exposure.f_number_source = std::string(key) + " (APEX)";
          break;
        }
      }
    }
    if (auto v = positive(data, "Exif.Photo.FocalLength")) exposure.focal_length = *v;
  } catch (const std::exception&) {
  }
  exposure.make = text(data, "Exif.Image.Make");
  exposure.model = text(data, "Exif.Image.Model");
  exposure.date_time = text(data, "Exif.Photo.DateTimeOriginal");
  return exposure;
}

void writeExif(const fs::path& path, const ExifExposure& exposure) {
  initialiseExiv2();
  try {
    auto image = Exiv2::ImageFactory::open(path.string());
    if (image.get() == nullptr) throw Error("cannot open for EXIF writing", path.string());
    image->readMetadata();
    Exiv2::ExifData data = image->exifData();
    auto rational = [](double value) {
      // Exposure times below 1 s as 1/n, others with a denominator of 1000.
      if (value < 1 && value > 0 && std::abs(1 / value - std::round(1 / value)) < 1e-9)
        return Exiv2::URational(1, static_cast<uint32_t>(std::lround(1 / value)));
      return Exiv2::URational(static_cast<uint32_t>(std::lround(value * 1000)), 1000);
    };
    if (!exposure.make.empty()) data["Exif.Image.Make"] = exposure.make;
    if (!exposure.model.empty()) data["Exif.Image.Model"] = exposure.model;
    if (exposure.iso) data["Exif.Photo.ISOSpeedRatings"] = static_cast<uint16_t>(std::lround(*exposure.iso));
    if (exposure.exposure_time) data["Exif.Photo.ExposureTime"] = rational(*exposure.exposure_time);
    if (exposure.f_number)
      data["Exif.Photo.FNumber"] = Exiv2::URational(static_cast<uint32_t>(std::lround(*exposure.f_number * 10)), 10);
    image->setExifData(data);
    image->writeMetadata();
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Error(std::string("cannot write EXIF: ") + e.what(), path.string());
  }
}

}  // namespace crfcal::io
#pragma GCC diagnostic pop
