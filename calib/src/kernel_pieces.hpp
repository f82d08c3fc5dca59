// The pieces of an estimated blur kernel: the connected parts of its support after pruning, and what they say when
// the estimate reaches its window's border. A motion blur is one connected trajectory; an estimate that reaches the
// border either is a blur cut off by the window (its mass piled on the border) or has fallen apart into specks
// (the sharp shot's noise over a kernel of thousands of unknowns), and the user needs to know which.
#pragma once

#include <string>

#include <opencv2/core.hpp>

namespace crfcal::detail {

struct KernelPieces {
  int count = 0;             // pieces kept
  double largest_share = 1;  // the largest piece's share of the mass kept
};

// Keeps the 8-connected pieces of K's support (CV_64F, ≥ 0) with at least 10 % of the largest one's mass and zeroes
// the rest: isolated specks are noise ([27] likewise removes them by hysteresis thresholding).
KernelPieces keepMassivePieces(cv::Mat& K);

// Width of the outer ring of an n×n window whose mass tells that a kernel reaches the border (2 px from 15 px on).
int borderRing(int n);
// Fraction of K's mass in that ring.
double borderMass(const cv::Mat& K);
// The ring's share of the window's area: the border mass of a kernel spread evenly over its window.
double borderAreaShare(int n);

// The message of a kernel estimate at its size limit. One whose largest piece holds less than half its mass and
// whose border holds no more than an even spread would put there "fell apart" (the pair does not resolve the blur);
// otherwise it "reaches its size limit" (a larger window helps). The benches' accurate kernels keep 52 % or more of
// their mass in one piece; the large-blur run's scattered 79 px estimate 11 % in 30 pieces
// (docs/RESULTS.md#kernel-fell-apart).
std::string kernelSizeLimitMessage(const cv::Mat& K, const KernelPieces& pieces);

}  // namespace crfcal::detail
