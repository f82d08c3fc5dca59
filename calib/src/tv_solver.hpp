#pragma once
// The TV solver of the deconvolution (deconvolution.cpp, which plans the tiles and forms the operators of each FFT
// canvas): FTVd's splitting with ADMM multipliers and the masked data term by majorisation–minimisation, on one
// canvas, in FFTW's half layout (real_fft.hpp, half_spectrum.hpp).
#include <opencv2/core.hpp>

#include "crfcal/deconvolution.hpp"

namespace crfcal::detail {

// ---- the u-step's operators on one FFT canvas ------------------------------------------------------------------
// They depend only on the canvas size, the kernel and β, so every tile of the same padded size shares them
// (deconvolution.cpp forms them once per size and kernel).
struct CanvasOperators {
  cv::Mat kernel_spectrum;   // K̂, packed (the Wiener solve)
  // The TV solver's, in FFTW's half layout (real_fft.hpp):
  cv::Size size;             // the canvas
  cv::Mat kernel_half;       // K̂ (complex)
  cv::Mat gradient_energy;   // |D̂x|² + |D̂y|² (real)
  cv::Mat kernel_energy;     // |K̂|² (real)
  cv::Mat first_reciprocal;  // R at options.beta_start
  cv::Mat first_data_gain;   // G at options.beta_start

  // R = 1 / (N (|D̂|² + λ/β |K̂|²)) (real) and G = λ/β conj(K̂) R at `beta`. FFTW's inverse DFT is unscaled: the
  // 1 / N = 1 / (rows · cols) of the inverse is folded into R and G, and so into Û and the prediction Û · K̂.
  void stepOperators(double beta, double lambda, cv::Mat& reciprocal, cv::Mat& data_gain) const {
    const double ratio = lambda / beta;
    cv::divide(1.0 / static_cast<double>(size.area()), gradient_energy + ratio * kernel_energy, reciprocal);
    cv::Mat parts[2];
    cv::split(kernel_half, parts);
    parts[0] = parts[0].mul(reciprocal, ratio);
    parts[1] = parts[1].mul(reciprocal, -ratio);  // conj(K̂)
    cv::merge(parts, 2, data_gain);
  }
};

// FTVd on the canvas `f` (CV_32F: T = float, or CV_64F: T = double) with the data mask `mask` (CV_8U, 0 = out of
// the data term), `canvas` formed for f's size; `iterations` (optional) receives the u-steps taken. The solution is
// a view of the calling thread's workspace: valid until that thread's next solve.
template <typename T>
cv::Mat totalVariationSolve(const cv::Mat& f, const cv::Mat& mask, const CanvasOperators& canvas,
                            const DeconvolutionOptions& options, int* iterations);

}  // namespace crfcal::detail
