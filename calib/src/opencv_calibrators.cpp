#include "crfcal/opencv_calibrators.hpp"

#include <cmath>
#include <limits>

#include <opencv2/photo.hpp>

#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal {

const char* toString(OpenCvCalibrator calibrator) {
  return calibrator == OpenCvCalibrator::Debevec ? "OpenCV CalibrateDebevec" : "OpenCV CalibrateRobertson";
}

std::vector<std::vector<double>> opencvInverseResponse(const std::vector<cv::Mat>& frames,
                                                       const std::vector<double>& exposure_times,
                                                       OpenCvCalibrator calibrator, double normalise_at) {
  if (frames.size() < 2 || frames.size() != exposure_times.size())
    throw InvalidInput("OpenCV calibration: need ≥ 2 frames and one exposure time each", ErrorSubject::options);
  for (const cv::Mat& f : frames)
    if (f.type() != CV_8UC3) throw InvalidInput("OpenCV calibration: frames must be 8-bit BGR", ErrorSubject::options);
  const std::vector<float> times(exposure_times.begin(), exposure_times.end());
  cv::Mat response;
  if (calibrator == OpenCvCalibrator::Debevec) cv::createCalibrateDebevec()->process(frames, response, times);
  else cv::createCalibrateRobertson()->process(frames, response, times);
  std::vector<std::vector<double>> curves;
  for (int c = 0; c < 3; ++c) {
    std::vector<double> codes(256);
    for (int z = 0; z < 256; ++z) codes[static_cast<std::size_t>(z)] = response.at<cv::Vec3f>(z)[2 - c];
    std::vector<double> phi(kCurveSamples);
    for (int i = 0; i < kCurveSamples; ++i)
      phi[static_cast<std::size_t>(i)] = interpolateSamples(codes, double(i) / (kCurveSamples - 1));
    const double scale = interpolateSamples(phi, normalise_at);
    for (double& v : phi) v = std::isfinite(scale) && scale > 0 ? v / scale : std::numeric_limits<double>::quiet_NaN();
    curves.push_back(std::move(phi));
  }
  return curves;
}

}  // namespace crfcal
