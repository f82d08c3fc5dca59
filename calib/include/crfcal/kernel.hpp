#pragma once
// Blur kernels K: non-negative CV_64F matrices summing to one (Sec. 3: "all kernel elements in K are
// non-negative and sum to one"). Row index = y. Convolution, not correlation, is applied everywhere.
#include <string>

#include <opencv2/core.hpp>

namespace crfcal {

struct KernelCheck {
  bool valid = true;
  std::string reason;
  explicit operator bool() const { return valid; }
};

// Whether `kernel` is usable as a blur kernel: single channel, non-empty, finite, no entry below
// −`tolerance`, and sum within `tolerance` of 1.
KernelCheck checkKernel(const cv::Mat& kernel, double tolerance = 1e-6);

// Converts to CV_64F, clamps tiny negatives (≥ −1e-6 of the peak) to 0, and divides by the sum.
// Throws InvalidInput if the kernel is empty, not finite, has real negative mass, or sums to 0.
cv::Mat normalizeKernel(const cv::Mat& kernel);

// A horizontal motion (box) kernel of `length` pixels — the 1-D kernels of the seed's Fig. 1.
cv::Mat boxKernel(int length);

// The smallest rectangle holding all of the kernel's mass (≥ `threshold` × peak), keeping the kernel centred
// on the same point by trimming symmetrically.
cv::Mat cropKernel(const cv::Mat& kernel, double threshold = 0.0);

// Mask (CV_8U, 255 where K > 0) of the kernel's support: the neighbourhood whose pixels enter (I ⊗ K)(p).
cv::Mat kernelSupport(const cv::Mat& kernel);

// The kernel's mass centroid relative to its centre (cols/2, rows/2), pixels: the shift the kernel applies.
// (0, 0) for a kernel without mass.
cv::Point2d kernelCentroid(const cv::Mat& kernel);

// RMS radius of the kernel's mass about its centroid, pixels: the blur's extent (0 for a delta or no mass).
double kernelRmsRadius(const cv::Mat& kernel);

}  // namespace crfcal
