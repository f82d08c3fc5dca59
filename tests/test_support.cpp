#include "test_support.hpp"

#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <random>

#include <sys/wait.h>

#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"

namespace crfcal::test {
namespace fs = std::filesystem;

std::string quote(const fs::path& path) { return "'" + path.string() + "'"; }

nlohmann::json readJson(const fs::path& path) {
  std::ifstream in(path);
  return nlohmann::json::parse(in);
}

fs::path samples() { return CRFCAL_SAMPLES; }
fs::path crfcalBinary() { return CRFCAL_BINARY; }

fs::path sharedData() {
  if (const char* env = std::getenv("CRFCAL_SHARED_DATA"); env && *env) return fs::is_directory(env) ? env : "";
  const fs::path candidate = fs::path(CRFCAL_SAMPLES).parent_path().parent_path() / "shared" / "data";
  return fs::is_directory(candidate) ? candidate : fs::path();
}

cv::Mat levinImage(int index) { return io::readGrayUnit(samples() / "levin09" / ("im" + std::to_string(index) + ".png")); }

cv::Mat levinKernel(int index) { return io::kernelFromSpec("levin:" + std::to_string(index)); }

EffectInputs greenEffectInputs(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& K,
                               const CrfFitOptions& fit) {
  EffectInputs in;
  in.channels = {"G"};
  in.sharp["G"] = sharp;
  in.blurred["G"] = blurred;
  in.fits["G"] = fitInverseCrf(sharp, blurred, K, fit);
  in.kernel = K;
  in.kernel_estimated = false;
  in.nominal_ratio = fit.nominal_ratio;
  in.fit = fit;
  return in;
}

SimulationResult gammaPairAtRatio4() {
  SimulationOptions sim;
  sim.ratio = 4;
  sim.noise_variance = 0.0002;
  return simulatePair(levinImage(2) * 0.2, GammaModel{2.2}, levinKernel(3), sim);
}

TempDir::TempDir() {
  std::random_device device;
  path_ = fs::temp_directory_path() / ("crfcal-test-" + std::to_string(device()));
  fs::create_directories(path_);
}

TempDir::~TempDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

CommandResult run(const std::string& command_line) {
  CommandResult result;
  FILE* pipe = ::popen((command_line + " 2>&1").c_str(), "r");
  if (!pipe) return result;
  std::array<char, 4096> buffer{};
  size_t n = 0;
  while ((n = std::fread(buffer.data(), 1, buffer.size(), pipe)) > 0) result.output.append(buffer.data(), n);
  const int status = ::pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return result;
}

RatioEvidence combinedRatioEvidence(double images_sigma, double resampled_sigma, double nominal_sigma,
                                    double log_difference) {
  RatioEvidence e;
  e.combined = true;
  e.decision = RatioDecision::combined;
  e.images_log_sigma = images_sigma;
  e.resampled_log_sigma = resampled_sigma;
  e.nominal_log_sigma = nominal_sigma;
  e.nominal_ratio = 8;
  e.images_ratio = 8 * std::exp(log_difference);
  const double wi = 1 / (images_sigma * images_sigma), wn = 1 / (nominal_sigma * nominal_sigma);
  e.images_weight = wi / (wi + wn);
  e.log_sigma = 1 / std::sqrt(wi + wn);
  e.conflict_sigmas = std::abs(log_difference) / std::hypot(images_sigma, nominal_sigma);
  return e;
}

}  // namespace crfcal::test
