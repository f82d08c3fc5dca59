#include "bench_real_regime.hpp"

#include <algorithm>
#include <cmath>

namespace crfcal::app {

RealExposure realExposure(const io::CameraNoiseProfile& camera, double blurred_iso, double ratio,
                          double sharp_noise_scale) {
  RealExposure e;
  e.iso_blurred = blurred_iso > 0 ? blurred_iso : camera.minIso();
  e.iso_sharp = e.iso_blurred * ratio;
  e.noise_blurred = camera.atIso(e.iso_blurred);
  e.noise_sharp = camera.atIso(e.iso_sharp);
  for (PoissonGaussian* channel : {&e.noise_sharp.red, &e.noise_sharp.green, &e.noise_sharp.blue}) {
    channel->a *= sharp_noise_scale;
    channel->b *= sharp_noise_scale;
  }
  return e;
}

void setRealExif(ExifExposure& sharp, ExifExposure& blurred, const RealExposure& e, double ratio, double exif_error) {
  sharp.iso = std::round(e.iso_sharp);
  sharp.exposure_time = 1.0 / std::max(1.0, std::round(*sharp.iso * ratio / (e.iso_blurred * 0.25)));
  blurred.iso = e.iso_blurred;
  blurred.exposure_time = ratio * (1 + exif_error) * *sharp.iso * *sharp.exposure_time / e.iso_blurred;
}

}  // namespace crfcal::app
