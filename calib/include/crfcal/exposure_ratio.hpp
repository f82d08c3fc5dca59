#pragma once
// Exposure ratio r = Δt_B / Δt_I of Eq. 4 from the two shots' camera settings (the seed's footnote 4 / Sec. 4:
// "we calculate initial exposure ratio according to exposure time and ISO value"):
//   r = (ISO_B · t_B · F_I²) / (ISO_I · t_I · F_B²)
// (irradiance reaching the sensor ∝ t / F², recorded signal ∝ ISO gain). Pure computation: EXIF is read by
// crfcal::io (io/exif.hpp) into ExifExposure.
#include <optional>
#include <string>

namespace crfcal {

// The exposure settings of one shot, as far as known. Missing values are std::nullopt.
struct ExifExposure {
  std::optional<double> iso;            // ISO speed (gain)
  std::optional<double> exposure_time;  // seconds
  std::optional<double> f_number;       // N of f/N
  std::string make;
  std::string model;
  // Where each value came from (e.g. "Exif.Photo.ISOSpeedRatings", "LibRaw"), for the report.
  std::string iso_source, exposure_time_source, f_number_source;
  std::optional<double> focal_length;   // mm (informational)
  std::string date_time;                // DateTimeOriginal (informational)

  // True when ISO and exposure time are known (the F-number may be missing: then assumed equal in both shots).
  bool usable() const { return iso && exposure_time && *iso > 0 && *exposure_time > 0; }
  std::string camera() const;  // "make model" (trimmed; "unknown camera" if both are empty)
  std::string summary() const; // "ISO 100, 2 s, f/2.2 (vivo vivo X6S A)"
};

// The factors of r, each a ratio blurred / sharp (F-number factor inverted: (F_I / F_B)²).
struct ExposureRatioFactors {
  double iso = 1;       // ISO_B / ISO_I
  double time = 1;      // t_B / t_I
  double aperture = 1;  // (F_I / F_B)²; 1 when an F-number is missing
  bool aperture_known = true;
  double ratio() const { return iso * time * aperture; }
  std::string summary() const;  // "r = 6.25 = ISO 0.03125 x time 200 x aperture 1"
};

// Footnote-4 ratio of blurred over sharp. Throws InvalidInput when ISO or exposure time is missing or
// non-positive in either shot (the message names what is missing and suggests --ratio).
ExposureRatioFactors exposureRatio(const ExifExposure& sharp, const ExifExposure& blurred);

// Formats an exposure time as a photographer would ("1/100 s", "2 s", "0.3 s").
std::string formatExposureTime(double seconds);

}  // namespace crfcal
