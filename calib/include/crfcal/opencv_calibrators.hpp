#pragma once
// OpenCV's own multi-exposure calibrators (photo module), the comparison of `crfcal bench bracket`:
// cv::CalibrateDebevec (Debevec & Malik 1997: log-domain least squares with a hat weight and smoothness λ·g'') and
// cv::CalibrateRobertson (Robertson et al. 2003: alternating irradiance / response estimates), both with their
// default parameters, as a user of OpenCV would call them.
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

enum class OpenCvCalibrator { Debevec, Robertson };
const char* toString(OpenCvCalibrator calibrator);

// `frames`: aligned 8-bit BGR frames; `exposure_times`: their exposure times (any common unit). Returns φ of R, G, B
// as 1024 samples at x = i/1023 (OpenCV's 256-entry response interpolated), each divided by its value at
// `normalise_at` (the response's scale is arbitrary). Non-finite entries (Robertson can give NaN) are kept as NaN.
std::vector<std::vector<double>> opencvInverseResponse(const std::vector<cv::Mat>& frames,
                                                       const std::vector<double>& exposure_times,
                                                       OpenCvCalibrator calibrator, double normalise_at = 0.8);

}  // namespace crfcal
