#include "crfcal/handheld_simulation.hpp"

#include <cmath>
#include <random>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal {
namespace {

// The noise of plane `c` of an OpenCV image with `planes` planes: BGR order, a single plane is treated as green.
PoissonGaussian channelNoise(const SensorNoise& noise, size_t c, size_t planes) {
  if (planes != 3) return noise.green;
  return c == 0 ? noise.blue : c == 1 ? noise.green : noise.red;
}

}  // namespace

void HandheldPairOptions::check() const {
  if (!(ratio > 0)) throw InvalidInput("ratio must be > 0");
  if (!(exposure > 0 && exposure <= 1)) throw InvalidInput("exposure must be in (0, 1]");
  if (noise_gain_sharp < 0 || noise_gain_blurred < 0 || read_noise < 0) throw InvalidInput("noise must be >= 0");
  if (!(std::abs(blurred_offset) <= 0.5)) throw InvalidInput("blurred_offset must be in [-0.5, 0.5]");
  for (const auto& noise : {sharp_noise, blurred_noise})
    if (noise)
      for (const PoissonGaussian& channel : {noise->red, noise->green, noise->blue})
        if (!(channel.a >= 0) || !std::isfinite(channel.b))
          throw InvalidInput("camera noise needs a >= 0 and a finite b (variance = a·x + b)");
}

HandheldPair makeHandheldPair(const cv::Mat& photo, const ResponseModel& phi, const cv::Mat& kernel_in,
                              const HandheldPairOptions& options) {
  options.check();
  if (photo.empty()) throw InvalidInput("empty photo");
  const ResponseCurve curve(phi);
  const cv::Mat kernel = normalizeKernel(kernel_in);
  std::vector<cv::Mat> planes;
  cv::split(photo, planes);
  // Irradiance: the photo linearised with a generic 2.2 gamma, scaled to the requested mean exposure.
  double mean_lin = 0;
  std::vector<cv::Mat> irr(planes.size());
  for (size_t c = 0; c < planes.size(); ++c) {
    cv::Mat u = toUnitGray(planes[c]);
    cv::pow(u, 2.2, irr[c]);
    mean_lin += cv::mean(irr[c])[0] / planes.size();
  }
  const double gain = options.exposure / std::max(mean_lin, 1e-6);
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  auto noisy = [&](const cv::Mat& e, const PoissonGaussian& noise) {
    cv::Mat out = e.clone();
    for (int y = 0; y < out.rows; ++y) {
      double* p = out.ptr<double>(y);
      for (int x = 0; x < out.cols; ++x) p[x] += std::sqrt(noise.variance(p[x])) * normal(rng);
    }
    return out;
  };
  cv::Mat A = cv::getRotationMatrix2D(cv::Point2f(photo.cols / 2.0f, photo.rows / 2.0f), options.rotation_deg, 1.0);
  A.at<double>(0, 2) += options.shift_x;
  A.at<double>(1, 2) += options.shift_y;
  HandheldPair pair;
  pair.homography = cv::Mat::eye(3, 3, CV_64F);
  A.copyTo(pair.homography.rowRange(0, 2));
  std::vector<cv::Mat> sharp(planes.size()), blurred(planes.size());
  const bool sharp_normal = options.normally_exposed == HandheldPairOptions::NormallyExposed::Sharp;
  for (size_t c = 0; c < planes.size(); ++c) {
    cv::Mat e = irr[c] * gain;
    cv::Mat sharp_irr, blurred_irr;
    if (sharp_normal) {
      cv::min(e, 1.0, e);
      sharp_irr = e;
      blurred_irr = options.ratio * convolve(e, kernel);
    } else {  // e is the scene irradiance L seen by the blurred shot; the sharp shot sees L / r (Eq. 4)
      sharp_irr = e / options.ratio;
      blurred_irr = convolve(e, kernel);
    }
    if (options.blurred_offset != 0) blurred_irr += options.blurred_offset;
    const PoissonGaussian sharp_noise = options.sharp_noise ? channelNoise(*options.sharp_noise, c, planes.size())
                                                            : PoissonGaussian{options.noise_gain_sharp, options.read_noise};
    const PoissonGaussian blurred_noise = options.blurred_noise
                                              ? channelNoise(*options.blurred_noise, c, planes.size())
                                              : PoissonGaussian{options.noise_gain_blurred, options.read_noise};
    cv::Mat i = curve.forward(cv::max(cv::min(noisy(sharp_irr, sharp_noise), 1.0), 0.0));
    cv::Mat moved;
    if (options.warp_irradiance) {
      cv::Mat blurred_irr_moved;
      cv::warpAffine(blurred_irr, blurred_irr_moved, A, blurred_irr.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
      moved = curve.forward(cv::max(cv::min(noisy(blurred_irr_moved, blurred_noise), 1.0), 0.0));
    } else {
      cv::Mat b_irr = noisy(blurred_irr, blurred_noise);
      cv::Mat b = curve.forward(cv::max(cv::min(b_irr, 1.0), 0.0));
      cv::warpAffine(b, moved, A, b.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    }
    i.convertTo(sharp[c], CV_8U, 255.0);
    moved.convertTo(blurred[c], CV_8U, 255.0);
  }
  cv::merge(sharp, pair.sharp);
  cv::merge(blurred, pair.blurred);
  return pair;
}

cv::Mat underexposedSharpShot(const cv::Mat& scene, const ResponseModel& phi, double ratio, const PoissonGaussian& noise,
                              std::uint64_t seed) {
  if (scene.empty() || scene.channels() != 1) throw InvalidInput("the scene must be one non-empty channel");
  if (!(ratio > 0)) throw InvalidInput("ratio must be > 0");
  const ResponseCurve curve(phi);
  cv::Mat irradiance = curve.inverse(toUnitGray(scene)) / ratio;
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int y = 0; y < irradiance.rows; ++y) {
    double* p = irradiance.ptr<double>(y);
    for (int x = 0; x < irradiance.cols; ++x) p[x] += std::sqrt(noise.variance(p[x])) * normal(rng);
  }
  cv::Mat shot;
  curve.forward(cv::max(cv::min(irradiance, 1.0), 0.0)).convertTo(shot, CV_8U, 255.0);
  return shot;
}

}  // namespace crfcal
