#pragma once
// Real 2-D DFTs for the deconvolution (deconvolution.cpp), computed by FFTW: a third to a quarter of cv::dft's cost
// at the deconvolution's canvas sizes (OpenCV 4.6 of Debian has no IPP; docs/RESULTS.md, "Speed at 12 MP"), where
// the DFTs were two thirds of the time. Two layouts:
// - OpenCV's packed CCS layout (forward / inverse), so that cv::mulSpectrums and cv::divSpectrums read the spectra
//   unchanged. Its layout: columns 0 and, when cols is even, cols − 1 hold those frequency columns' transforms
//   stacked vertically (row 0 real, rows (2i − 1, 2i) one (re, im) pair, row rows − 1 real when rows is even);
//   every other column pair (2j − 1, 2j) holds one (re, im) pair side by side.
// - FFTW's own half spectrum (forwardHalf / inverseHalf): rows × (cols/2 + 1) complex values, frequency (y, j) at
//   row y, column j, no conversion pass, unscaled both ways. The TV solver's inner loop uses it.
//
// Plans are made once per (size, precision, direction) with FFTW_ESTIMATE under a lock (FFTW's planner is not
// thread-safe; executing a plan is) and kept for the process. FFTW_ESTIMATE plans without timing anything: the same
// algorithm in every run (results reproducible bit for bit) and no planning time; FFTW_MEASURE's plans were no
// faster on the 2-core machine at 900×864 and 960×900 and cost 1–2 s of planning per size.
#include <opencv2/core.hpp>

namespace crfcal::fft {

// The packed spectrum of `real` (CV_32F or CV_64F, one channel, at least 2×2): what cv::dft(real, packed) gives.
// `packed` is (re)allocated with real's size and depth.
void forward(const cv::Mat& real, cv::Mat& packed);

// The scaled real inverse of a packed spectrum: what cv::dft(packed, real, DFT_INVERSE | DFT_SCALE |
// DFT_REAL_OUTPUT) gives (the imaginary slots of the self-conjugate frequencies are taken as zero, as OpenCV does).
// `real` is (re)allocated with packed's size and depth (it may be `packed` itself: the spectrum is read first).
void inverse(const cv::Mat& packed, cv::Mat& real);

// FFTW's half spectrum of `real` (CV_32F or CV_64F, one channel, at least 2×2), unscaled: `half` is (re)allocated
// as rows × (cols/2 + 1), CV_32FC2 or CV_64FC2 (re, im).
void forwardHalf(const cv::Mat& real, cv::Mat& half);

// The real image of a half spectrum, unscaled (the forward transform followed by this one multiplies by rows·cols):
// `real` is (re)allocated as rows × `cols` (the half spectrum's width fixes cols only up to its parity). Only the
// Hermitian part of `half` counts. FFTW's c2r transform overwrites `half`.
void inverseHalf(cv::Mat& half, int cols, cv::Mat& real);

// A packed (CCS) spectrum as FFTW's half spectrum, times `scale`.
cv::Mat packedToHalf(const cv::Mat& packed, double scale = 1);

}  // namespace crfcal::fft
