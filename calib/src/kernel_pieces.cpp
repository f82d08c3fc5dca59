#include "kernel_pieces.hpp"

#include <algorithm>
#include <cstdio>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace crfcal::detail {

KernelPieces keepMassivePieces(cv::Mat& K) {
  cv::Mat labels;
  const int count = cv::connectedComponents(K > 0, labels, 8, CV_32S);
  std::vector<double> mass(static_cast<std::size_t>(count), 0);
  for (int y = 0; y < K.rows; ++y)
    for (int x = 0; x < K.cols; ++x) mass[static_cast<std::size_t>(labels.at<int>(y, x))] += K.at<double>(y, x);
  double largest = 0;
  for (int l = 1; l < count; ++l) largest = std::max(largest, mass[static_cast<std::size_t>(l)]);
  const double least_kept = 0.1 * largest;
  for (int y = 0; y < K.rows; ++y)
    for (int x = 0; x < K.cols; ++x)
      if (mass[static_cast<std::size_t>(labels.at<int>(y, x))] < least_kept) K.at<double>(y, x) = 0;
  KernelPieces pieces;
  double kept = 0;
  for (int l = 1; l < count; ++l)  // label 0 is the background
    if (mass[static_cast<std::size_t>(l)] >= least_kept) {
      ++pieces.count;
      kept += mass[static_cast<std::size_t>(l)];
    }
  if (kept > 0) pieces.largest_share = largest / kept;
  return pieces;
}

int borderRing(int n) { return n >= 15 ? 2 : 1; }

double borderMass(const cv::Mat& K) {
  const int n = K.rows;
  const int ring = borderRing(n);
  const double total = cv::sum(K)[0];
  if (!(total > 0)) return 0;
  const double inner = cv::sum(K(cv::Rect(ring, ring, n - 2 * ring, n - 2 * ring)))[0];
  return (total - inner) / total;
}

double borderAreaShare(int n) {
  const int inner = n - 2 * borderRing(n);
  return 1.0 - double(inner) * inner / (double(n) * n);
}

std::string kernelSizeLimitMessage(const cv::Mat& K, const KernelPieces& pieces) {
  const double border_mass = borderMass(K);
  char buffer[400];
  if (pieces.count > 1 && pieces.largest_share < 0.5 && border_mass <= borderAreaShare(K.rows))
    std::snprintf(buffer, sizeof buffer,
                  "the blur kernel estimate fell apart at its size limit (%dx%d px: %d separate pieces, the largest "
                  "with %.0f%% of its mass, %.0f%% of it on the border): the pair does not resolve the blur; the sharp "
                  "shot's noise may hide it, or it is larger than the window (then a larger --max-kernel-size helps)",
                  K.cols, K.rows, pieces.count, 100 * pieces.largest_share, 100 * border_mass);
  else
    std::snprintf(buffer, sizeof buffer,
                  "the blur kernel reaches its size limit (%dx%d px, %.0f%% of its mass on the border): the blur or "
                  "the residual misregistration is larger; try a larger --max-kernel-size",
                  K.cols, K.rows, 100 * border_mass);
  return buffer;
}

}  // namespace crfcal::detail
