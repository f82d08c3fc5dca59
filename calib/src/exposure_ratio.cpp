#include "crfcal/exposure_ratio.hpp"

#include <cmath>
#include <cstdio>

#include "crfcal/error.hpp"

namespace crfcal {

std::string ExifExposure::camera() const {
  std::string text = make;
  // Many cameras repeat the make in the model ("Canon" + "Canon EOS R6"): do not print it twice.
  if (!model.empty()) {
    if (text.empty() || model.rfind(text, 0) == 0) text = model;
    else text += " " + model;
  }
  return text.empty() ? "unknown camera" : text;
}

std::string formatExposureTime(double seconds) {
  char buffer[64];
  if (!(seconds > 0)) return "?";
  if (seconds < 0.5) {
    const double inverse = 1.0 / seconds;
    if (std::abs(inverse - std::round(inverse)) < 0.05 * inverse) {
      std::snprintf(buffer, sizeof buffer, "1/%.0f s", std::round(inverse));
      return buffer;
    }
  }
  std::snprintf(buffer, sizeof buffer, "%g s", seconds);
  return buffer;
}

std::string ExifExposure::summary() const {
  std::string text;
  char buffer[64];
  if (iso) {
    std::snprintf(buffer, sizeof buffer, "ISO %g", *iso);
    text += buffer;
  } else {
    text += "ISO ?";
  }
  text += ", " + (exposure_time ? formatExposureTime(*exposure_time) : std::string("t ?"));
  if (f_number) {
    std::snprintf(buffer, sizeof buffer, ", f/%g", *f_number);
    text += buffer;
  }
  return text + " (" + camera() + ")";
}

std::string ExposureRatioFactors::summary() const {
  char buffer[200];
  std::snprintf(buffer, sizeof buffer, "r = %.6g = ISO %.6g x time %.6g x aperture %.6g%s", ratio(), iso, time,
                aperture, aperture_known ? "" : " (F-number missing: assumed equal)");
  return buffer;
}

ExposureRatioFactors exposureRatio(const ExifExposure& sharp, const ExifExposure& blurred) {
  auto require = [](const ExifExposure& e, const char* which) {
    std::string missing;
    if (!e.iso || !(*e.iso > 0)) missing = "ISO";
    if (!e.exposure_time || !(*e.exposure_time > 0)) missing += missing.empty() ? "exposure time" : " and exposure time";
    if (!missing.empty())
      throw InvalidInput(std::string("the ") + which + " image has no usable " + missing +
                         " in its EXIF; give the exposure ratio with --ratio");
  };
  require(sharp, "sharp");
  require(blurred, "blurred");
  ExposureRatioFactors f;
  f.iso = *blurred.iso / *sharp.iso;
  f.time = *blurred.exposure_time / *sharp.exposure_time;
  if (sharp.f_number && blurred.f_number && *sharp.f_number > 0 && *blurred.f_number > 0) {
    const double q = *sharp.f_number / *blurred.f_number;
    f.aperture = q * q;
  } else {
    f.aperture = 1;
    f.aperture_known = false;
  }
  if (!std::isfinite(f.ratio()) || !(f.ratio() > 0)) throw InvalidInput("the EXIF exposure ratio is not finite");
  return f;
}

}  // namespace crfcal
