#pragma once
// The TV solver's u-step in Fourier as one pass over FFTW's half spectra (real_fft.hpp: rows × (cols/2 + 1) complex
// values, CV_32FC2 or CV_64FC2), doing what cv::multiply, cv::mulSpectrums and cv::add would do in four passes
// (deconvolution.cpp; docs/RESULTS.md, "Speed at 12 MP"). Complex products of float spectra are formed in float,
// four at a time (OpenCV's universal intrinsics); of double spectra in double, rounded once.
#include <opencv2/core.hpp>

namespace crfcal::half {

// The u-step's spectrum Û = Â · R + F̂ · G (Â: F(Dᵀw); R: the real operator 1 / (|D̂|² + λ/β |K̂|²), one real value
// per frequency (one channel); F̂: F(ḟ); G: λ/β conj(K̂) R) and, for the next step's prediction K ⊗ u, P = Û · K̂.
// Complex operands CV_32FC2 or CV_64FC2 (T), R the same depth with one channel, all continuous and of one size;
// `u_spectrum` and `prediction` are (re)allocated.
template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fill, const cv::Mat& data_gain,
                   const cv::Mat& kernel, cv::Mat& u_spectrum, cv::Mat& prediction);

// The same without a masked data term: Û = Â · R + C, C = F(f) · G fixed per β.
template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fixed_data, cv::Mat& u_spectrum);

}  // namespace crfcal::half
