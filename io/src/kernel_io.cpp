#include "crfcal/io/kernel_io.hpp"

#include <cstdlib>
#include <fstream>
#include <sstream>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/kernel.hpp"

#ifndef CRFCAL_SOURCE_SAMPLES_DIR
#define CRFCAL_SOURCE_SAMPLES_DIR ""
#endif
#ifndef CRFCAL_INSTALL_SAMPLES_DIR
#define CRFCAL_INSTALL_SAMPLES_DIR ""
#endif

namespace crfcal::io {
namespace fs = std::filesystem;

namespace {

cv::Mat readTextMatrix(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw Error("cannot open", path.string());
  std::vector<std::vector<double>> rows;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    for (char& c : line)
      if (c == ',' || c == ';' || c == '\t') c = ' ';
    std::istringstream fields(line);
    std::vector<double> row;
    std::string token;
    while (fields >> token) {
      char* end = nullptr;
      const double value = std::strtod(token.c_str(), &end);
      if (end == token.c_str() || *end != '\0')
        throw Error("line " + std::to_string(line_number) + ": '" + token + "' is not a number", path.string());
      row.push_back(value);
    }
    if (row.empty()) continue;
    if (!rows.empty() && row.size() != rows.front().size())
      throw Error("line " + std::to_string(line_number) + " has " + std::to_string(row.size()) +
                      " values, the first row has " + std::to_string(rows.front().size()),
                  path.string());
    rows.push_back(std::move(row));
  }
  if (rows.empty()) throw Error("no kernel values", path.string());
  cv::Mat kernel(static_cast<int>(rows.size()), static_cast<int>(rows.front().size()), CV_64F);
  for (int y = 0; y < kernel.rows; ++y)
    for (int x = 0; x < kernel.cols; ++x) kernel.at<double>(y, x) = rows[static_cast<size_t>(y)][static_cast<size_t>(x)];
  return kernel;
}

}  // namespace

fs::path samplesDirectory() {
  if (const char* env = std::getenv("CRFCAL_SAMPLES_DIR"); env && *env) return env;
  std::error_code ec;
  if (fs::is_directory(CRFCAL_SOURCE_SAMPLES_DIR, ec)) return CRFCAL_SOURCE_SAMPLES_DIR;
  return CRFCAL_INSTALL_SAMPLES_DIR;
}

cv::Mat readKernel(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw Error("file not found", path.string());
  std::string extension = path.extension().string();
  for (char& c : extension) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  cv::Mat raw;
  if (extension == ".txt" || extension == ".csv" || extension == ".dat" || extension.empty()) {
    raw = readTextMatrix(path);
  } else {
    cv::Mat image = readImage(path);
    if (image.channels() != 1) cv::cvtColor(image, image, cv::COLOR_BGR2GRAY);
    image.convertTo(raw, CV_64F);
  }
  try {
    return normalizeKernel(raw);
  } catch (const InvalidInput& e) {
    throw Error("not a usable blur kernel: " + e.reason(), path.string());
  }
}

cv::Mat kernelFromSpec(const std::string& spec) {
  if (spec.rfind("levin:", 0) == 0) {
    // levin:N, or levin:N@S: Levin's kernel N scaled by S (a longer exposure's larger shake, same trajectory)
    const std::size_t at = spec.find('@');
    int index = 0;
    double scale = 1;
    try {
      index = std::stoi(spec.substr(6, at == std::string::npos ? std::string::npos : at - 6));
      if (at != std::string::npos) scale = std::stod(spec.substr(at + 1));
    } catch (const std::exception&) {
      index = 0;
    }
    if (index < 1 || index > 8) throw Error("kernel spec '" + spec + "': Levin kernels are levin:1 … levin:8");
    if (!(scale >= 0.25 && scale <= 8)) throw Error("kernel spec '" + spec + "': the scale after @ must be 0.25 … 8");
    char name[32];
    std::snprintf(name, sizeof name, "kernel%02d.txt", index);
    const cv::Mat kernel = readKernel(samplesDirectory() / "levin09" / name);
    if (scale == 1) return kernel;
    cv::Mat scaled;
    cv::resize(kernel, scaled, cv::Size(), scale, scale, scale < 1 ? cv::INTER_AREA : cv::INTER_LINEAR);
    // odd sides, as every kernel here has (a centre pixel)
    cv::copyMakeBorder(scaled, scaled, 0, 1 - scaled.rows % 2, 0, 1 - scaled.cols % 2, cv::BORDER_CONSTANT, 0.0);
    return normalizeKernel(cv::max(scaled, 0.0));
  }
  if (spec.rfind("box:", 0) == 0) {
    int length = 0;
    try {
      length = std::stoi(spec.substr(4));
    } catch (const std::exception&) {
    }
    if (length < 1 || length > 1000) throw Error("kernel spec '" + spec + "': box length must be 1 … 1000");
    return boxKernel(length);
  }
  return readKernel(spec);
}

std::string tileKernelFileName(int tile) { return "kernel_tile_" + std::to_string(tile) + ".txt"; }

void writeKernelText(const fs::path& path, const cv::Mat& kernel) {
  std::ostringstream out;
  out.precision(10);
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  for (int y = 0; y < k.rows; ++y) {
    for (int x = 0; x < k.cols; ++x) out << (x ? " " : "") << k.at<double>(y, x);
    out << '\n';
  }
  writeTextFile(path, out.str());
}

void writeKernelPng(const fs::path& path, const cv::Mat& kernel, int min_size) {
  cv::Mat k;
  kernel.convertTo(k, CV_64F);
  double peak = 0;
  cv::minMaxLoc(k, nullptr, &peak);
  if (peak <= 0) peak = 1;
  cv::Mat image;
  k.convertTo(image, CV_8U, 255.0 / peak);
  const int scale = std::max(1, (min_size + std::max(k.rows, k.cols) - 1) / std::max(k.rows, k.cols));
  cv::resize(image, image, cv::Size(), scale, scale, cv::INTER_NEAREST);
  writeImage(path, image);
}

}  // namespace crfcal::io
