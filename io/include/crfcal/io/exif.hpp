#pragma once
// EXIF exposure settings through Exiv2 (JPEG, TIFF, PNG, and camera RAW: CR2, CR3 (BMFF), NEF, ARW, DNG, …).
//   ISO:           Exiv2::isoSpeed() (Exif.Photo.ISOSpeedRatings, Exif.Image.ISOSpeedRatings, Canon/Nikon/Sony/
//                  Olympus/Pentax/… maker notes), then Exif.Photo.PhotographicSensitivity,
//                  Exif.Photo.RecommendedExposureIndex, Exif.Photo.ExposureIndex, Exif.Nikon3.ISOSpeed,
//                  Exif.NikonIi.ISO, Exif.CanonSi.ISOSpeed, Exif.CanonCs.ISOSpeed.
//   exposure time: Exif.Photo.ExposureTime / Exif.Image.ExposureTime, APEX fallback t = 2^−Tv from
//                  Exif.Photo.ShutterSpeedValue.
//   F-number:      Exif.Photo.FNumber / Exif.Image.FNumber, APEX fallback N = 2^(Av/2) from Exif.Photo.ApertureValue.
// For RAW files whose metadata Exiv2 cannot parse, io/raw_image.hpp's LibRaw values are the fallback
// (readRawExposure).
#include <filesystem>

#include "crfcal/exposure_ratio.hpp"

namespace crfcal::io {

// Reads the exposure settings. A file Exiv2 cannot open or that has no EXIF gives an ExifExposure with all
// values missing (not an error: the caller decides; see ExifExposure::usable()). Throws crfcal::Error naming the
// file only when the file does not exist.
ExifExposure readExif(const std::filesystem::path& path);

// Writes ISO, exposure time, F-number, make and model into an existing JPEG/TIFF/PNG (in place). Used to make
// semi-real test pairs with a known EXIF ratio. Throws crfcal::Error naming the file.
void writeExif(const std::filesystem::path& path, const ExifExposure& exposure);

}  // namespace crfcal::io
