#pragma once
// The real regime of `crfcal bench pairs` (issue 17): real handheld pairs as the seed's footnote 4 shoots them, the
// long low-ISO blurred shot normally exposed and the short high-ISO sharp shot underexposed by r, each with a real
// camera's measured raw noise (darktable profile) at its ISO, and the EXIF a camera would write for them.
#include "crfcal/exposure_ratio.hpp"
#include "crfcal/io/noise_profiles.hpp"
#include "crfcal/sensor_noise.hpp"

namespace crfcal::app {

// The camera's noise and the two shots' ISOs for a ratio r (blurred ISO · r for the sharp shot: r× less light at r×
// the gain, e.g. ISO 100 at t and ISO 800 at t / 64 for r = 8).
struct RealExposure {
  double iso_blurred = 0, iso_sharp = 0;
  SensorNoise noise_blurred, noise_sharp;
};

// `blurred_iso` ≤ 0: the camera's lowest profiled ISO. `sharp_noise_scale` multiplies the sharp shot's noise variance
// (0: noise-free; `bench pairs --sharp-noise-scale`, one part of the simulation changed at a time).
RealExposure realExposure(const io::CameraNoiseProfile& camera, double blurred_iso, double ratio,
                          double sharp_noise_scale = 1);

// EXIF of a real-regime pair: the sharp shot at its ISO rounded as a camera writes it and a shutter time 1/n near
// 1/4 s · ISO_B / (ISO_I · r); the blurred shot at ISO_B and the time that makes the EXIF ratio
// ISO_B·t_B / (ISO_I·t_I) the truth × (1 + exif_error), as in the sharp-normal regime (EXIF stores the long time to
// 1 ms: about 0.2 % of the ratio).
void setRealExif(ExifExposure& sharp, ExifExposure& blurred, const RealExposure& e, double ratio, double exif_error);

}  // namespace crfcal::app
