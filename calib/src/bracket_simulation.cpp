#include "crfcal/bracket_simulation.hpp"

#include <cmath>
#include <random>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/response_curve.hpp"
#include "image_units.hpp"

namespace crfcal {

void BracketSimulationOptions::check() const {
  if (exposures.size() < 2) throw InvalidInput("bracket simulation: need ≥ 2 exposures", ErrorSubject::options);
  for (double t : exposures)
    if (!(t > 0 && std::isfinite(t))) throw InvalidInput("bracket simulation: exposures must be > 0", ErrorSubject::options);
  if (!(middle_mean > 0)) throw InvalidInput("bracket simulation: middle_mean must be > 0", ErrorSubject::options);
  if (!(shot_noise >= 0 && read_noise >= 0)) throw InvalidInput("bracket simulation: noise must be ≥ 0", ErrorSubject::options);
  if (!(max_shift >= 0 && max_rotation_deg >= 0))
    throw InvalidInput("bracket simulation: handheld motion must be ≥ 0", ErrorSubject::options);
}

std::vector<cv::Mat> simulateBracket(const cv::Mat& photo, const std::vector<ResponseModel>& phi,
                                     const BracketSimulationOptions& options) {
  options.check();
  if (photo.empty() || (photo.channels() != 1 && photo.channels() != 3))
    throw InvalidInput("bracket simulation: the photo must be grey or BGR", ErrorSubject::sharp_image);
  if (phi.size() != 1 && phi.size() != 3) throw InvalidInput("bracket simulation: one or three curves", ErrorSubject::curve);
  std::vector<ResponseCurve> curves;
  for (const auto& model : phi) curves.emplace_back(model);
  // Scene irradiance: the photo linearised, scaled so that the middle frame's mean irradiance is middle_mean.
  cv::Mat scene = detail::unit(photo);
  cv::pow(scene, 2.2, scene);
  const double middle = options.exposures[options.exposures.size() / 2];
  const double mean = cv::mean(scene)[0];
  scene *= options.middle_mean / (middle * std::max(mean, 1e-6));
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::vector<cv::Mat> frames;
  const cv::Point2f centre(scene.cols / 2.0f, scene.rows / 2.0f);
  for (std::size_t j = 0; j < options.exposures.size(); ++j) {
    cv::Mat moved = scene;
    if (j > 0 && (options.max_shift > 0 || options.max_rotation_deg > 0)) {
      // A deterministic handheld pattern: shifts and rotations of alternating sign, growing with j.
      const double f = double(j) / double(options.exposures.size() - 1), sign = j % 2 ? 1.0 : -1.0;
      cv::Mat motion = cv::getRotationMatrix2D(centre, sign * f * options.max_rotation_deg, 1.0);
      motion.at<double>(0, 2) += sign * f * options.max_shift;
      motion.at<double>(1, 2) += -0.7 * f * options.max_shift;
      cv::warpAffine(scene, moved, motion, scene.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
    }
    cv::Mat frame(scene.size(), CV_8UC(scene.channels()));
    const int planes = scene.channels();
    for (int y = 0; y < scene.rows; ++y) {
      const double* in = moved.ptr<double>(y);
      uchar* out = frame.ptr<uchar>(y);
      for (int x = 0; x < scene.cols * planes; ++x) {
        const double e = options.exposures[j] * in[x];
        const double sigma = std::sqrt(options.shot_noise * std::max(e, 0.0) + options.read_noise);
        const double noisy = std::clamp(e + sigma * normal(rng), 0.0, 1.0);
        // BGR plane p is channel 2 − p (R, G, B order of `phi`).
        const ResponseCurve& curve = curves.size() == 1 ? curves[0] : curves[static_cast<std::size_t>(planes == 1 ? 1 : 2 - x % planes)];
        out[x] = cv::saturate_cast<uchar>(std::round(255.0 * curve.forward(noisy)));
      }
    }
    frames.push_back(frame);
  }
  return frames;
}

}  // namespace crfcal
