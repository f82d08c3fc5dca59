#include "crfcal/effect_planting.hpp"

#include <algorithm>
#include <cmath>
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
  if (!(strength >= 0)) throw InvalidInput("planting: strength must be >= 0");
  if (!(ratio > 0)) throw InvalidInput("planting: ratio must be > 0");
  if (!(exposure > 0 && exposure <= 1)) throw InvalidInput("planting: exposure must be in (0, 1]");
  if (!(sharp_sigma >= 0) || noise_gain_blurred < 0 || read_noise_blurred < 0)
    throw InvalidInput("planting: noise must be >= 0");
  if (effect == "clipping" && !(strength < 1)) throw InvalidInput("planting: clipping strength must be < 1");
  if (effect == "signal_dependent_noise" && !(strength >= 1))
    throw InvalidInput("planting: signal_dependent_noise strength is a variance ratio >= 1");
}

PlantedPair plantEffect(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel_in,
                        const PlantingOptions& o) {
  o.check();
  if (photo.empty()) throw InvalidInput("planting: empty photo");
  const std::string& effect = o.effect;
  const double s = effect == "none" ? 0.0 : o.strength;
  if (effect == "channel_mixing" && photo.channels() != 3) throw InvalidInput("planting: channel_mixing needs colour");
  const ResponseCurve curve(phi);
  const cv::Mat K = normalizeKernel(kernel_in);
  std::mt19937_64 rng(o.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
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
  pair.effect = effect;
  pair.strength = s;
  pair.true_ratio = o.ratio;
  pair.exif_ratio = o.ratio;
  if (effect == "exposure_ratio_mismatch") {
    pair.exif_ratio = flip ? o.ratio * (1 + s) : o.ratio / (1 + s);
    pair.detail = flip ? "EXIF ratio too large" : "EXIF ratio too small";
  }

  // Irradiance of B before the response: r (E ⊗ K), with the effect.
  std::vector<cv::Mat> Eb(nc);
  cv::Mat K2;
  if (effect == "spatially_varying_blur") cv::rotate(K, K2, cv::ROTATE_90_CLOCKWISE);
  for (int c = 0; c < nc; ++c) {
    cv::Mat blurred = convolve(E[c], K);
    if (effect == "spatially_varying_blur") {
      const cv::Mat other = convolve(E[c], K2);
      for (int y = 0; y < blurred.rows; ++y) {
        double* b = blurred.ptr<double>(y);
        const double* q = other.ptr<double>(y);
        for (int x = 0; x < blurred.cols; ++x) {
          const double t = std::min(s, 1.0) * x / std::max(1, blurred.cols - 1);
          b[x] = (1 - t) * b[x] + t * q[x];
        }
      }
    }
    Eb[c] = o.ratio * blurred;
  }
  if (effect == "channel_mixing") {
    std::vector<cv::Mat> mixed(nc);
    for (int c = 0; c < nc; ++c) {
      mixed[c] = (1 - s) * Eb[c];
      for (int d = 0; d < nc; ++d)
        if (d != c) mixed[c] += 0.5 * s * Eb[d];
    }
    Eb = mixed;
  }
  if (effect == "vignetting") {
    const double R = 0.5 * std::hypot(photo.cols, photo.rows);
    const double cx = (photo.cols - 1) / 2.0, cy = (photo.rows - 1) / 2.0;
    for (auto& e : Eb)
      for (int y = 0; y < e.rows; ++y) {
        double* p = e.ptr<double>(y);
        for (int x = 0; x < e.cols; ++x) {
          const double r2 = ((x - cx) * (x - cx) + (y - cy) * (y - cy)) / (R * R);
          p[x] *= 1 - s * r2;
        }
      }
  }
  std::vector<cv::Mat> Ei(nc);
  for (int c = 0; c < nc; ++c) Ei[c] = E[c].clone();
  if (effect == "black_level_offset") {
    pair.detail = flip ? "offset in the sharp shot" : "offset in the blurred shot (flare)";
    for (int c = 0; c < nc; ++c) {
      if (flip) Ei[c] += s;
      else Eb[c] += s;
    }
  }
  double clip = 1.0;
  if (effect == "clipping") {
    // The plateau: the level above which a fraction s of the pair's informative pixels lies (B below full scale
    // and I unsaturated over the kernel's support — saturated regions carry no information with or without it).
    cv::Mat saturated = cv::Mat::zeros(E[0].size(), CV_8U);
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
    clip = v[static_cast<std::size_t>((1 - std::min(s, 0.9)) * (v.size() - 1))];
    pair.plateau_intensity = std::floor(curve.forward(clip) * 255.0 + 0.5) / 255.0;
    pair.detail = "plateau at irradiance " + std::to_string(clip) + " (intensity " +
                  std::to_string(pair.plateau_intensity) + ")";
  }

  cv::Mat A = cv::getRotationMatrix2D(cv::Point2f(photo.cols / 2.0f, photo.rows / 2.0f), o.rotation_deg, 1.0);
  A.at<double>(0, 2) += o.shift_x;
  A.at<double>(1, 2) += o.shift_y;
  pair.homography = cv::Mat::eye(3, 3, CV_64F);
  A.copyTo(pair.homography.rowRange(0, 2));
  const bool moved = o.shift_x != 0 || o.shift_y != 0 || o.rotation_deg != 0;
  std::vector<cv::Mat> sharp(nc), blurred(nc);
  for (int c = 0; c < nc; ++c) {
    // I: the seed's Sec. 5 model, Gaussian noise on the intensities (level-dependent when planted).
    cv::Mat i = curve.forward(cv::max(cv::min(Ei[c], 1.0), 0.0));
    for (int y = 0; y < i.rows; ++y) {
      double* p = i.ptr<double>(y);
      for (int x = 0; x < i.cols; ++x) {
        double sd = o.sharp_sigma;
        if (effect == "signal_dependent_noise") sd *= std::pow(s, 0.5 * (0.5 - std::clamp(p[x], 0.0, 1.0)) / 0.8);
        p[x] += sd * normal(rng);
      }
    }
    i = cv::max(cv::min(i, 1.0), 0.0);
    // B: the long exposure's (small) Poisson–Gaussian irradiance noise, then the clip.
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

}  // namespace crfcal
