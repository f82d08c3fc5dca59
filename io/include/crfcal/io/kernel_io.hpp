#pragma once
// Blur kernels on disk: text matrices (rows = y; whitespace or comma separated, '#' comments) or images.
#include <filesystem>
#include <string>

#include <opencv2/core.hpp>

namespace crfcal::io {

// Reads and normalises a kernel (sum 1). Throws crfcal::Error naming the file and the problem.
cv::Mat readKernel(const std::filesystem::path& path);

// Resolves a kernel SPEC: "levin:N" (N = 1..8, the bundled Levin et al. 2009 kernels), "box:L" (horizontal
// motion of L pixels) or a file path.
cv::Mat kernelFromSpec(const std::string& spec);

// The directory holding the bundled samples (CRFCAL_SAMPLES_DIR environment variable, else the source tree's
// samples/ recorded at build time, else <prefix>/share/crfcal/samples).
std::filesystem::path samplesDirectory();

// Writes a kernel as a text matrix (%.10g) and as a PNG scaled to its peak, atomically.
void writeKernelText(const std::filesystem::path& path, const cv::Mat& kernel);
void writeKernelPng(const std::filesystem::path& path, const cv::Mat& kernel, int min_size = 64);

// "kernel_tile_<tile>.txt": the file of the kernel a calibration estimated on its tile `tile` alone (beside
// report.json, listed under "kernel" → "tile_kernels").
std::string tileKernelFileName(int tile);

}  // namespace crfcal::io
