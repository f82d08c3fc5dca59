#pragma once
// Helpers shared by the tests: bundled samples, the crfcal binary, temporary directories.
#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "crfcal/crf_fitter.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/ratio_evidence.hpp"
#include "crfcal/simulation.hpp"

namespace crfcal::test {

std::filesystem::path samples();            // the project's samples/ directory
std::string quote(const std::filesystem::path& path);  // the path single-quoted for a shell command line
nlohmann::json readJson(const std::filesystem::path& path);  // a JSON file, parsed
std::filesystem::path crfcalBinary();       // the built crfcal command
std::filesystem::path sharedData();         // ../shared/data (or $CRFCAL_SHARED_DATA); empty if absent
cv::Mat levinImage(int index);              // samples/levin09/im<index>.png as CV_64F in [0,1]
cv::Mat levinKernel(int index);             // samples/levin09/kernel0<index>.txt, normalised
// A synthetic pair at r = 4 for the band's tests: gamma 2.2, Levin image 2 at a fifth of its brightness, Levin
// kernel 3, noise variance 2·10⁻⁴ (the kernel is levinKernel(3)).
SimulationResult gammaPairAtRatio4();
// Ratio evidence combined from the images' r (σ_images, of which σ_resampled measured by the half-samples) and EXIF's
// 8 (σ_nominal), the images' r e^{log_difference} times EXIF's: the inputs of the band's ratio-term tests.
RatioEvidence combinedRatioEvidence(double images_sigma, double resampled_sigma, double nominal_sigma,
                                    double log_difference);
// The effect diagnostics' inputs for the green channel of a grey pair with a given kernel K: its base fit under
// `fit`, EXIF's r = fit.nominal_ratio.
EffectInputs greenEffectInputs(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& K,
                               const CrfFitOptions& fit);

// OpenCV's thread count (and so crfcal's job arena) set for a scope and restored when it ends, also on a failed
// assertion.
class ThreadCount {
 public:
  explicit ThreadCount(int threads) : previous_(cv::getNumThreads()) { cv::setNumThreads(threads); }
  ~ThreadCount() { cv::setNumThreads(previous_); }

 private:
  int previous_;
};

// A fresh temporary directory removed when the object dies.
class TempDir {
 public:
  TempDir();
  ~TempDir();
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// Runs a shell command; returns its exit status and captures stdout+stderr.
struct CommandResult {
  int exit_code = -1;
  std::string output;
};
CommandResult run(const std::string& command_line);

}  // namespace crfcal::test
