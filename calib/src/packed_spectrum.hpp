#pragma once
// The TV solver's u-step in Fourier as one pass over spectra in OpenCV's packed (CCS) layout, doing what
// cv::multiply, cv::mulSpectrums and cv::add did in four passes (deconvolution.cpp; docs/RESULTS.md, "Speed at
// 12 MP"). The arithmetic is the same operation by operation — complex products formed in double and rounded once,
// as cv::mulSpectrums forms them; every other product and sum in T — so the results are bit-identical.
//
// The packed layout of a rows×cols real 2-D DFT (cv::dft without DFT_COMPLEX_OUTPUT): columns 0 and, when cols is
// even, cols − 1 hold those frequency columns' transforms stacked vertically (row 0 real, rows (2i − 1, 2i) one
// (re, im) pair, row rows − 1 real when rows is even); every other column pair (2j − 1, 2j) holds one (re, im) pair
// side by side.
#include <opencv2/core.hpp>

namespace crfcal::packed {

// The u-step's spectrum Û = Â ∘ R + F̂ · G (Â: F(Dᵀw); R: the real operator 1 / (|D̂|² + λ/β |K̂|²) with its value in
// both slots of every pair, applied element-wise; F̂: F(ḟ); G: λ/β conj(K̂) R) and, for the next step's prediction
// K ⊗ u, P = Û · K̂. All CV_32F or all CV_64F (T), one channel, continuous, the same size (at least 2×2); `u_spectrum`
// and `prediction` are (re)allocated.
template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fill, const cv::Mat& data_gain,
                   const cv::Mat& kernel, cv::Mat& u_spectrum, cv::Mat& prediction);

// The same without a masked data term: Û = Â ∘ R + C, C = F(f) · G fixed per β.
template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fixed_data, cv::Mat& u_spectrum);

}  // namespace crfcal::packed
