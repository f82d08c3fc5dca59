#include "crfcal/effect_planting.hpp"

#include <algorithm>
#include <cmath>
#include <functional>
#include <random>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal {

// The thresholds (`crfcal bench effects --sweep`, docs/RESULTS.md#effects): for the effects that bias φ when
// ignored, the strength at which the seed model's φ (effects off) is worse than its clean twin's by 0.01 RMSE
// (median; 2.5 of 255, the size of the clean-case error itself). The others do not bias φ and are stated by the
// physical tolerance they exceed.
double plantingThreshold(const std::string& effect) {
  if (effect == "exposure_ratio_mismatch") return 0.2;
  if (effect == "channel_mixing") return 0.1;
  if (effect == "signal_dependent_noise") return 3.0;
  if (effect == "clipping") return 0.0125;
  if (effect == "vignetting") return 0.15;
  if (effect == "spatially_varying_blur") return 0.5;
  if (effect == "black_level_offset") return 0.00125;
  if (effect == "none") return 0;
  throw InvalidInput("unknown effect '" + effect + "'");
}

std::string thresholdReason(const std::string& effect) {
  if (effect == "exposure_ratio_mismatch")
    return "EXIF off by 20 %: twice the 10 % tolerance of nominal EXIF values (1/3-stop rounding of times, ISOs, "
           "f-numbers); phi is not biased while r is fitted freely";
  if (effect == "channel_mixing") return "10 % of the other channels mixed in: phi_G biased by 0.01 RMSE when ignored";
  if (effect == "signal_dependent_noise")
    return "noise variance 3x larger at level 0.1 than at 0.9: homoscedastic weights keep at most 75 % efficiency "
           "(Kantorovich 4k/(1+k)^2); phi is not biased by the noise law (pixels are selected by B alone; the Jensen bias of phi(I) is that of "
           "homoscedastic noise of the same power)";
  if (effect == "clipping")
    return "1.25 % of the informative pixels on a plateau below full scale: phi biased by 0.007 (twin with the same "
           "measurable range) to 0.01 RMSE when ignored";
  if (effect == "vignetting") return "B's corners 15 % darker than I's: phi biased by 0.01 RMSE when ignored";
  if (effect == "spatially_varying_blur")
    return "the kernels at the two edges differ by half of K minus its 90-degree rotation (beyond the kernel "
           "estimator's own error); phi is barely biased by it";
  if (effect == "black_level_offset")
    return "irradiance offset of 0.125 % of full scale in one shot (12/255 at black through a gamma-2.2 curve): phi "
           "biased by 0.01 RMSE when ignored";
  if (effect == "none") return "clean pair";
  throw InvalidInput("unknown effect '" + effect + "'");
}

void PlantingOptions::check() const {
  plantingThreshold(effect);
  plantingThreshold(second_effect);
  if (form != "detector" && form != "held_out") throw InvalidInput("planting: form must be detector or held_out");
  if (!(strength >= 0) || !(second_strength >= 0)) throw InvalidInput("planting: strength must be >= 0");
  if (second_effect != "none" && second_effect == effect) throw InvalidInput("planting: the two effects must differ");
  if (!(ratio > 0)) throw InvalidInput("planting: ratio must be > 0");
  if (!(exposure > 0 && exposure <= 1)) throw InvalidInput("planting: exposure must be in (0, 1]");
  if (!(sharp_sigma >= 0) || noise_gain_blurred < 0 || read_noise_blurred < 0)
    throw InvalidInput("planting: noise must be >= 0");
  if (sharp_sensor_noise)
    for (const PoissonGaussian* law : {&sharp_sensor_noise->red, &sharp_sensor_noise->green, &sharp_sensor_noise->blue})
      if (!std::isfinite(law->a) || !std::isfinite(law->b) || law->a < 0)
        throw InvalidInput("planting: the sharp shot's sensor noise must be finite, its shot-noise term >= 0");
  for (const auto& [name, value] : {std::pair{effect, strength}, std::pair{second_effect, second_strength}}) {
    if (name == "clipping" && !(value < 1)) throw InvalidInput("planting: clipping strength must be < 1");
    if (name == "signal_dependent_noise" && !(value >= 1))
      throw InvalidInput("planting: signal_dependent_noise strength is a variance ratio >= 1");
  }
}

namespace {

// Which effects are planted, at what strength, in which form.
struct PlantedEffects {
  const PlantingOptions& o;
  bool has(const std::string& name) const { return o.effect == name || o.second_effect == name; }
  double strength(const std::string& name) const {
    if (o.effect == name) return o.strength;
    if (o.second_effect == name) return o.second_strength;
    return 0;
  }
  bool heldOut() const { return o.form == "held_out"; }
};

void addDetail(PlantedPair& pair, const std::string& text) {
  pair.detail += (pair.detail.empty() ? "" : "; ") + text;
}

void multiplyBy(cv::Mat& image, const std::function<double(double x, double y)>& factor) {
  for (int y = 0; y < image.rows; ++y) {
    double* p = image.ptr<double>(y);
    for (int x = 0; x < image.cols; ++x) p[x] *= factor(x, y);
  }
}

// ρ² = squared distance to the centre over the squared half-diagonal.
std::function<double(double, double)> rhoSquared(const cv::Size& size) {
  const double R = 0.5 * std::hypot(size.width, size.height);
  const double cx = (size.width - 1) / 2.0, cy = (size.height - 1) / 2.0;
  return [=](double x, double y) { return ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (R * R); };
}

// Held-out spatially varying blur: a rotation about the centre during the exposure. The irradiance is averaged
// over 15 rotations spread over θ, where θ·(half-diagonal) = s × the kernel's extent at the corners.
cv::Mat rotationBlur(const cv::Mat& blurred, double s, int kernel_extent) {
  const double R = 0.5 * std::hypot(blurred.cols, blurred.rows);
  const double theta_deg = s * kernel_extent / R * 180.0 / CV_PI;
  const cv::Point2f centre(static_cast<float>((blurred.cols - 1) / 2.0), static_cast<float>((blurred.rows - 1) / 2.0));
  constexpr int kSteps = 15;
  cv::Mat sum = cv::Mat::zeros(blurred.size(), CV_64F), rotated;
  for (int k = 0; k < kSteps; ++k) {
    const double angle = theta_deg * (double(k) / (kSteps - 1) - 0.5);
    cv::warpAffine(blurred, rotated, cv::getRotationMatrix2D(centre, angle, 1.0), blurred.size(), cv::INTER_LINEAR,
                   cv::BORDER_REFLECT);
    sum += rotated;
  }
  return sum / kSteps;
}

// Held-out spatially varying blur: depth-dependent scale, K scaled by 1 − s at the top row to 1 + s at the bottom
// (5 scaled kernels, blended linearly between their rows).
cv::Mat depthScaledBlur(const cv::Mat& E, const cv::Mat& K, double s) {
  constexpr int kBands = 5;
  std::vector<cv::Mat> bands;
  for (int j = 0; j < kBands; ++j) {
    const double scale = std::max(0.2, 1 + s * (2.0 * j / (kBands - 1) - 1));
    const int w = std::max(1, static_cast<int>(std::lround(K.cols * scale)) | 1);
    const int h = std::max(1, static_cast<int>(std::lround(K.rows * scale)) | 1);
    cv::Mat scaled;
    cv::resize(K, scaled, cv::Size(w, h), 0, 0, cv::INTER_LINEAR);
    bands.push_back(convolve(E, normalizeKernel(scaled)));
  }
  cv::Mat out(E.size(), CV_64F);
  for (int y = 0; y < E.rows; ++y) {
    const double t = double(y) / std::max(1, E.rows - 1) * (kBands - 1);
    const int j = std::min(kBands - 2, static_cast<int>(t));
    const double f = t - j;
    for (int x = 0; x < E.cols; ++x)
      out.at<double>(y, x) = (1 - f) * bands[j].at<double>(y, x) + f * bands[j + 1].at<double>(y, x);
  }
  return out;
}

// A real camera's colour mixing: Canon EOS 5D Mark II (Adobe DNG ColorMatrix2, XYZ(D65) → camera) times sRGB →
// XYZ (D65), rows normalised to sum 1 (white stays white). Rows/columns in R, G, B order.
cv::Matx33d cameraMixing() {
  const cv::Matx33d cam_from_xyz(0.4716, 0.0603, -0.0830, -0.7798, 1.5474, 0.2480, -0.1496, 0.1937, 0.6651);
  const cv::Matx33d xyz_from_srgb(0.4124, 0.3576, 0.1805, 0.2126, 0.7152, 0.0722, 0.0193, 0.1192, 0.9505);
  cv::Matx33d m = cam_from_xyz * xyz_from_srgb;
  for (int r = 0; r < 3; ++r) {
    const double sum = m(r, 0) + m(r, 1) + m(r, 2);
    for (int c = 0; c < 3; ++c) m(r, c) /= sum;
  }
  return m;
}

// The real matrix blended with the identity so that the mean absolute off-diagonal mass per row is s (the detector
// form's off-diagonal mass at strength s). Planes in OpenCV's B, G, R order.
std::vector<cv::Mat> mixLikeCamera(const std::vector<cv::Mat>& Eb, double s) {
  const cv::Matx33d real = cameraMixing();
  double off = 0;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      if (r != c) off += std::abs(real(r, c)) / 3;
  const double k = s / off;
  std::vector<cv::Mat> mixed(3);
  for (int r = 0; r < 3; ++r) {  // r, c: RGB indices; plane index 2 − r
    mixed[2 - r] = cv::Mat::zeros(Eb[0].size(), CV_64F);
    for (int c = 0; c < 3; ++c) {
      const double w = (r == c ? 1.0 : 0.0) + k * (real(r, c) - (r == c ? 1.0 : 0.0));
      mixed[2 - r] += w * Eb[2 - c];
    }
    mixed[2 - r] = cv::max(mixed[2 - r], 0.0);
  }
  return mixed;
}

// The level above which a fraction s of the pair's informative pixels lies (B below full scale and I unsaturated
// over the kernel's support — saturated regions carry no information with or without a clip).
double informativeQuantile(const std::vector<cv::Mat>& Ei, const std::vector<cv::Mat>& Eb, const cv::Mat& K,
                           double s) {
  cv::Mat saturated = cv::Mat::zeros(Ei[0].size(), CV_8U);
  for (const auto& e : Ei) saturated |= e >= 1.0;
  const int n = std::max(K.rows, K.cols) | 1;
  cv::dilate(saturated, saturated, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(n, n)));
  std::vector<double> v;
  for (const auto& e : Eb)
    for (int y = 0; y < e.rows; ++y)
      for (int x = 0; x < e.cols; ++x)
        if (e.at<double>(y, x) < 1.0 && !saturated.at<uchar>(y, x)) v.push_back(e.at<double>(y, x));
  if (v.empty()) throw InvalidInput("planting: the blurred frame is saturated");
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>((1 - std::min(s, 0.9)) * (v.size() - 1))];
}

// Irradiance of B before the response: r (E ⊗ K), with the blur and colour effects.
std::vector<cv::Mat> blurredIrradiance(const std::vector<cv::Mat>& E, const cv::Mat& K, const PlantedEffects& fx,
                                       std::mt19937_64& extra, PlantedPair& pair) {
  const int nc = static_cast<int>(E.size());
  const double svb = fx.strength("spatially_varying_blur");
  const bool varying = fx.has("spatially_varying_blur");
  const bool rotation = fx.heldOut() && std::uniform_int_distribution<int>(0, 1)(extra) == 1;
  if (varying && fx.heldOut())
    addDetail(pair, rotation ? "blur: rotation about the centre" : "blur: depth-dependent kernel scale");
  cv::Mat K2;
  if (varying && !fx.heldOut()) cv::rotate(K, K2, cv::ROTATE_90_CLOCKWISE);
  std::vector<cv::Mat> Eb(nc);
  for (int c = 0; c < nc; ++c) {
    cv::Mat blurred;
    if (varying && fx.heldOut() && !rotation) {
      blurred = depthScaledBlur(E[c], K, svb);
    } else {
      blurred = convolve(E[c], K);
      if (varying && fx.heldOut()) blurred = rotationBlur(blurred, svb, std::max(K.rows, K.cols));
    }
    if (varying && !fx.heldOut()) {
      const cv::Mat other = convolve(E[c], K2);
      for (int y = 0; y < blurred.rows; ++y) {
        double* b = blurred.ptr<double>(y);
        const double* q = other.ptr<double>(y);
        for (int x = 0; x < blurred.cols; ++x) {
          const double t = std::min(svb, 1.0) * x / std::max(1, blurred.cols - 1);
          b[x] = (1 - t) * b[x] + t * q[x];
        }
      }
    }
    Eb[c] = fx.o.ratio * blurred;
  }
  if (fx.has("channel_mixing")) {
    const double s = fx.strength("channel_mixing");
    if (fx.heldOut()) {
      Eb = mixLikeCamera(Eb, s);
      addDetail(pair, "mixing: a real camera's colour matrix");
    } else {
      std::vector<cv::Mat> mixed(nc);
      for (int c = 0; c < nc; ++c) {
        mixed[c] = (1 - s) * Eb[c];
        for (int d = 0; d < nc; ++d)
          if (d != c) mixed[c] += 0.5 * s * Eb[d];
      }
      Eb = mixed;
    }
  }
  return Eb;
}

void plantVignetting(std::vector<cv::Mat>& Ei, std::vector<cv::Mat>& Eb, const PlantedEffects& fx,
                     std::mt19937_64& extra, PlantedPair& pair) {
  const double s = fx.strength("vignetting");
  const auto rho2 = rhoSquared(Eb[0].size());
  if (!fx.heldOut()) {
    for (auto& e : Eb) multiplyBy(e, [&](double x, double y) { return 1 - s * rho2(x, y); });
    return;
  }
  // cos⁴ law: the corner (ρ = 1) keeps 1 − s: (1 + t²)² = 1 / (1 − s).
  const double t2 = 1 / std::sqrt(1 - std::min(s, 0.95)) - 1;
  const bool in_sharp = std::uniform_int_distribution<int>(0, 1)(extra) == 1;
  addDetail(pair, std::string("vignetting: cos^4 in the ") + (in_sharp ? "sharp" : "blurred") + " shot");
  for (auto& e : in_sharp ? Ei : Eb)
    multiplyBy(e, [&](double x, double y) { return 1 / std::pow(1 + rho2(x, y) * t2, 2); });
}

void plantOffset(std::vector<cv::Mat>& Ei, std::vector<cv::Mat>& Eb, const PlantedEffects& fx, bool flip,
                 std::mt19937_64& extra, PlantedPair& pair) {
  const double s = fx.strength("black_level_offset");
  const int nc = static_cast<int>(Ei.size());
  if (!fx.heldOut()) {
    addDetail(pair, flip ? "offset in the sharp shot" : "offset in the blurred shot (flare)");
    for (int c = 0; c < nc; ++c) (flip ? Ei[c] : Eb[c]) += s;
    return;
  }
  std::uniform_real_distribution<double> u(0, 1);
  const int form = std::uniform_int_distribution<int>(0, 2)(extra);
  if (form < 2) {  // per-channel offsets, in the sharp (0) or the blurred (1) shot
    addDetail(pair, std::string("per-channel offsets in the ") + (form == 0 ? "sharp" : "blurred") + " shot");
    for (int c = 0; c < nc; ++c) (form == 0 ? Ei[c] : Eb[c]) += s * (0.5 + u(extra));
    return;
  }
  // A flare veil: a broad Gaussian bump (σ = half the diagonal) centred somewhere in the frame, mean ≈ s.
  const cv::Size size = Eb[0].size();
  const double cx = u(extra) * size.width, cy = u(extra) * size.height;
  const double sigma = 0.5 * std::hypot(size.width, size.height);
  cv::Mat veil(size, CV_64F);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x)
      veil.at<double>(y, x) = std::exp(-((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (2 * sigma * sigma));
  veil *= s / std::max(cv::mean(veil)[0], 1e-9);
  addDetail(pair, "a low-frequency flare veil in the blurred shot");
  for (auto& e : Eb) e += veil;
}

// Returns the clip level of B's irradiance (1: none); a knee (held out) compresses instead.
double plantClipping(const std::vector<cv::Mat>& Ei, std::vector<cv::Mat>& Eb, const cv::Mat& K,
                     const ResponseCurve& curve, const PlantedEffects& fx, PlantedPair& pair) {
  const double level = informativeQuantile(Ei, Eb, K, fx.strength("clipping"));
  pair.plateau_intensity = std::floor(curve.forward(level) * 255.0 + 0.5) / 255.0;
  if (!fx.heldOut()) {
    addDetail(pair, "plateau at irradiance " + std::to_string(level) + " (intensity " +
                        std::to_string(pair.plateau_intensity) + ")");
    return level;
  }
  const double w = 0.5 * (1 - level);
  for (auto& e : Eb)
    e.forEach<double>([&](double& v, const int*) {
      if (v > level) v = level + w * (1 - std::exp(-(v - level) / w));
    });
  addDetail(pair, "highlight knee at irradiance " + std::to_string(level));
  return 1.0;
}

// I and B from their irradiances: I through the curve with the seed's Gaussian intensity noise (level-dependent
// when planted) or with a sensor's irradiance noise before it (sharp_sensor_noise), B with the long exposure's small
// Poisson–Gaussian irradiance noise, the clip, the curve and the handheld misregistration; both 8-bit.
PlantedPair renderPair(const std::vector<cv::Mat>& Ei, const std::vector<cv::Mat>& Eb, double clip,
                       const ResponseCurve& curve, const PlantedEffects& fx, std::mt19937_64& rng, cv::Size size,
                       PlantedPair pair) {
  const PlantingOptions& o = fx.o;
  std::normal_distribution<double> normal(0.0, 1.0);
  const double noise_ratio = fx.strength("signal_dependent_noise");
  cv::Mat A = cv::getRotationMatrix2D(cv::Point2f(size.width / 2.0f, size.height / 2.0f), o.rotation_deg, 1.0);
  A.at<double>(0, 2) += o.shift_x;
  A.at<double>(1, 2) += o.shift_y;
  pair.homography = cv::Mat::eye(3, 3, CV_64F);
  A.copyTo(pair.homography.rowRange(0, 2));
  const bool moved = o.shift_x != 0 || o.shift_y != 0 || o.rotation_deg != 0;
  const int nc = static_cast<int>(Ei.size());
  std::vector<cv::Mat> sharp(nc), blurred(nc);
  const bool sensor = o.sharp_sensor_noise && !fx.has("signal_dependent_noise");
  for (int c = 0; c < nc; ++c) {
    cv::Mat i;
    if (sensor) {  // the camera's way: noise on the irradiance, then the clip and the curve
      const PoissonGaussian& law = nc == 1 || c == 1 ? o.sharp_sensor_noise->green
                                   : c == 0          ? o.sharp_sensor_noise->blue  // BGR
                                                     : o.sharp_sensor_noise->red;
      cv::Mat e = Ei[c].clone();
      for (int y = 0; y < e.rows; ++y) {
        double* p = e.ptr<double>(y);
        for (int x = 0; x < e.cols; ++x) p[x] += std::sqrt(law.variance(p[x])) * normal(rng);
      }
      i = curve.forward(cv::max(cv::min(e, 1.0), 0.0));
    } else {  // the seed's way (Sec. 5): Gaussian noise on the intensity
      i = curve.forward(cv::max(cv::min(Ei[c], 1.0), 0.0));
      for (int y = 0; y < i.rows; ++y) {
        double* p = i.ptr<double>(y);
        for (int x = 0; x < i.cols; ++x) {
          double sd = o.sharp_sigma;
          if (fx.has("signal_dependent_noise"))
            sd *= std::pow(noise_ratio, 0.5 * (0.5 - std::clamp(p[x], 0.0, 1.0)) / 0.8);
          p[x] += sd * normal(rng);
        }
      }
    }
    i = cv::max(cv::min(i, 1.0), 0.0);
    cv::Mat e = Eb[c].clone();
    for (int y = 0; y < e.rows; ++y) {
      double* p = e.ptr<double>(y);
      for (int x = 0; x < e.cols; ++x)
        p[x] += std::sqrt(o.noise_gain_blurred * std::max(p[x], 0.0) + o.read_noise_blurred) * normal(rng);
    }
    cv::Mat b = curve.forward(cv::max(cv::min(e, clip), 0.0));
    if (moved) {
      cv::Mat w;
      cv::warpAffine(b, w, A, b.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
      b = w;
    }
    i.convertTo(sharp[c], CV_8U, 255.0);
    b.convertTo(blurred[c], CV_8U, 255.0);
  }
  cv::merge(sharp, pair.sharp);
  cv::merge(blurred, pair.blurred);
  return pair;
}

}  // namespace

PlantedPair plantEffect(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel_in,
                        const PlantingOptions& o) {
  o.check();
  if (photo.empty()) throw InvalidInput("planting: empty photo");
  const PlantedEffects fx{o};
  if (fx.has("channel_mixing") && photo.channels() != 3) throw InvalidInput("planting: channel_mixing needs colour");
  const ResponseCurve curve(phi);
  const cv::Mat K = normalizeKernel(kernel_in);
  std::mt19937_64 rng(o.seed);
  // The held-out forms draw from their own stream, so the detector forms' pairs stay what they were.
  std::mt19937_64 extra(o.seed * 0x9E3779B97F4A7C15ULL + 17);
  std::uniform_int_distribution<int> coin(0, 1);
  const bool flip = coin(rng) == 1;

  std::vector<cv::Mat> planes;
  cv::split(photo, planes);
  const int nc = static_cast<int>(planes.size());
  std::vector<cv::Mat> E(nc);
  double mean_lin = 0;
  for (int c = 0; c < nc; ++c) {
    cv::Mat u = toUnitGray(planes[c]);
    cv::pow(u, 2.2, E[c]);
    mean_lin += cv::mean(E[c])[0] / nc;
  }
  const double gain = o.exposure / std::max(mean_lin, 1e-6);
  for (auto& e : E) {
    e *= gain;
    cv::min(e, 1.0, e);
  }

  PlantedPair pair;
  pair.effect = o.second_effect == "none" ? o.effect : o.effect + "+" + o.second_effect;
  pair.strength = o.effect == "none" ? 0.0 : o.strength;
  pair.true_ratio = o.ratio;
  pair.exif_ratio = o.ratio;
  if (fx.has("exposure_ratio_mismatch")) {
    const double s = fx.strength("exposure_ratio_mismatch");
    pair.exif_ratio = flip ? o.ratio * (1 + s) : o.ratio / (1 + s);
    addDetail(pair, flip ? "EXIF ratio too large" : "EXIF ratio too small");
  }
  std::vector<cv::Mat> Eb = blurredIrradiance(E, K, fx, extra, pair);
  std::vector<cv::Mat> Ei(nc);
  for (int c = 0; c < nc; ++c) Ei[c] = E[c].clone();
  if (fx.has("vignetting")) plantVignetting(Ei, Eb, fx, extra, pair);
  if (fx.has("black_level_offset")) plantOffset(Ei, Eb, fx, flip, extra, pair);
  const double clip = fx.has("clipping") ? plantClipping(Ei, Eb, K, curve, fx, pair) : 1.0;
  return renderPair(Ei, Eb, clip, curve, fx, rng, photo.size(), pair);
}

}  // namespace crfcal
