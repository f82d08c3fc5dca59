#pragma once
// A tabulated inverse response φ with its exact numerical inverse ψ = φ⁻¹.
//
// φ is represented by its piecewise-linear interpolant on a uniform grid; ψ inverts that same interpolant, so
// ψ(φ(x)) = x holds to rounding, and a convex φ stays convex (Theorem 1's inequalities then hold exactly,
// not only up to interpolation error). Images are evaluated through lookup tables for 8- and 16-bit input.
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal {

// The one validation of a tabulated φ, whatever it comes from (report.json, `table:` files, chart --truth, export,
// fitted curves): at least 2 samples, all finite, φ(0) = 0 and φ(1) = 1, non-decreasing — each within 1e-6, the
// rounding of the 17-digit values crfcal writes. What ResponseCurve::fromSamples accepts; readers call it so that a
// curve one command accepts is never rejected by another.
ModelValidity checkInverseSamples(const std::vector<double>& phi);

class ResponseCurve {
 public:
  // Default grid: 16385 nodes, interpolation error < 1e-8 for the curves of real cameras.
  static constexpr int kDefaultNodes = 16385;

  ResponseCurve();  // the identity φ(x) = x
  // Tabulates `model` (which must be valid: throws InvalidInput with the reason otherwise).
  explicit ResponseCurve(const ResponseModel& model, int nodes = kDefaultNodes);
  // From samples φ(i/(n−1)); must pass checkInverseSamples (throws InvalidInput with its reason).
  static ResponseCurve fromSamples(std::vector<double> phi);

  double inverse(double x) const;  // φ(x), x clamped to [0,1]
  double forward(double y) const;  // ψ(y), y clamped to [0,1]

  // Element-wise φ / ψ of a single-channel CV_8U, CV_16U (through LUTs), CV_32F or CV_64F image in [0,1]
  // (integer types are scaled by 1/255 or 1/65535). Output is CV_64F.
  cv::Mat inverse(const cv::Mat& image) const;
  cv::Mat forward(const cv::Mat& image) const;

  // φ(v / (2^bits − 1)) and ψ(v / (2^bits − 1)) for v = 0 … 2^bits − 1, bits ∈ {8, 16}.
  const std::vector<double>& inverseLut(int bits) const;
  const std::vector<double>& forwardLut(int bits) const;

  // φ at x = i/(n−1).
  std::vector<double> sample(int n = kCurveSamples) const;
  const std::vector<double>& nodes() const { return phi_; }
  bool isConvex(double tolerance = 1e-12) const;

 private:
  explicit ResponseCurve(std::vector<double> phi);
  void build();  // bucket index and LUTs

  std::vector<double> phi_;           // φ at x = i/(N−1)
  std::vector<int> bucket_start_;     // first node whose φ ≥ bucket lower edge (speeds up ψ)
  std::vector<double> lut_inverse8_, lut_inverse16_, lut_forward8_, lut_forward16_;  // built eagerly
};

}  // namespace crfcal
