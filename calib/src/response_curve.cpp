#include "crfcal/response_curve.hpp"

#include <algorithm>
#include <cmath>

#include <opencv2/core/utility.hpp>

#include "crfcal/error.hpp"

namespace crfcal {
namespace {

std::vector<double> lut(int bits, auto&& function) {
  const int size = 1 << bits;
  std::vector<double> table(static_cast<size_t>(size));
  for (int v = 0; v < size; ++v) table[static_cast<size_t>(v)] = function(double(v) / (size - 1));
  return table;
}

}  // namespace

ModelValidity checkInverseSamples(const std::vector<double>& phi) {
  if (phi.size() < 2) return {false, "a response curve needs at least 2 samples"};
  return checkValidity(TableModel{phi}, static_cast<int>(phi.size()), 1e-6);
}

ResponseCurve::ResponseCurve() : ResponseCurve(std::vector<double>{0.0, 1.0}) {}

ResponseCurve::ResponseCurve(const ResponseModel& model, int nodes) {
  if (nodes < 2) throw InvalidInput("a response curve needs at least 2 nodes");
  if (auto validity = checkValidity(model); !validity) throw InvalidInput("invalid response curve: " + validity.reason);
  phi_ = sampleInverse(model, nodes);
  // Remove rounding-level decreases so that ψ is well defined.
  for (size_t i = 1; i < phi_.size(); ++i) phi_[i] = std::max(phi_[i], phi_[i - 1]);
  phi_.front() = 0.0;
  phi_.back() = 1.0;
  build();
}

ResponseCurve::ResponseCurve(std::vector<double> phi) : phi_(std::move(phi)) { build(); }

ResponseCurve ResponseCurve::fromSamples(std::vector<double> phi) {
  if (auto validity = checkInverseSamples(phi); !validity)
    throw InvalidInput("invalid response curve: " + validity.reason);
  for (size_t i = 1; i < phi.size(); ++i) phi[i] = std::max(phi[i], phi[i - 1]);
  phi.front() = 0.0;
  phi.back() = 1.0;
  return ResponseCurve(std::move(phi));
}

void ResponseCurve::build() {
  // bucket_start_[b] = first node i with φ_i ≥ b / buckets: ψ(y) only searches between two bucket starts.
  const int buckets = static_cast<int>(phi_.size()) - 1;
  bucket_start_.assign(static_cast<size_t>(buckets) + 2, static_cast<int>(phi_.size()) - 1);
  size_t node = 0;
  for (int b = 0; b <= buckets; ++b) {
    const double edge = double(b) / buckets;
    while (node < phi_.size() && phi_[node] < edge) ++node;
    bucket_start_[static_cast<size_t>(b)] = static_cast<int>(std::min(node, phi_.size() - 1));
  }
  lut_inverse8_ = lut(8, [this](double x) { return inverse(x); });
  lut_inverse16_ = lut(16, [this](double x) { return inverse(x); });
  lut_forward8_ = lut(8, [this](double y) { return forward(y); });
  lut_forward16_ = lut(16, [this](double y) { return forward(y); });
}

double ResponseCurve::inverse(double x) const {
  if (!(x > 0)) return 0.0;
  if (x >= 1) return 1.0;
  const double position = x * double(phi_.size() - 1);
  const size_t i = std::min(static_cast<size_t>(position), phi_.size() - 2);
  const double t = position - double(i);
  return phi_[i] + t * (phi_[i + 1] - phi_[i]);
}

double ResponseCurve::forward(double y) const {
  if (!(y > 0)) return 0.0;
  if (y >= 1) return 1.0;
  const int buckets = static_cast<int>(phi_.size()) - 1;
  const int b = std::min(static_cast<int>(y * buckets), buckets - 1);
  const auto first = phi_.begin() + std::max(0, bucket_start_[static_cast<size_t>(b)] - 1);
  const auto last = phi_.begin() + std::min<int>(static_cast<int>(phi_.size()), bucket_start_[static_cast<size_t>(b) + 1] + 1);
  // i = last node with φ_i ≤ y
  auto it = std::upper_bound(first, last, y);
  size_t i = static_cast<size_t>(std::distance(phi_.begin(), it));
  i = i == 0 ? 0 : i - 1;
  if (i >= phi_.size() - 1) return 1.0;
  const double span = phi_[i + 1] - phi_[i];
  const double t = span > 0 ? (y - phi_[i]) / span : 0.0;
  return (double(i) + t) / double(phi_.size() - 1);
}

namespace {

cv::Mat applyCurve(const cv::Mat& image, const std::vector<double>& lut8, const std::vector<double>& lut16,
                   const auto& function) {
  if (image.channels() != 1) throw InvalidInput("response curves apply to single-channel images");
  cv::Mat out(image.size(), CV_64F);
  const int depth = image.depth();
  if (depth != CV_8U && depth != CV_16U && depth != CV_32F && depth != CV_64F)
    throw InvalidInput("unsupported image depth for a response curve");
  cv::parallel_for_(cv::Range(0, image.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      double* o = out.ptr<double>(y);
      switch (depth) {
        case CV_8U: {
          const uchar* p = image.ptr<uchar>(y);
          for (int x = 0; x < image.cols; ++x) o[x] = lut8[p[x]];
          break;
        }
        case CV_16U: {
          const ushort* p = image.ptr<ushort>(y);
          for (int x = 0; x < image.cols; ++x) o[x] = lut16[p[x]];
          break;
        }
        case CV_32F: {
          const float* p = image.ptr<float>(y);
          for (int x = 0; x < image.cols; ++x) o[x] = function(double(p[x]));
          break;
        }
        default: {
          const double* p = image.ptr<double>(y);
          for (int x = 0; x < image.cols; ++x) o[x] = function(p[x]);
        }
      }
    }
  });
  return out;
}

}  // namespace

cv::Mat ResponseCurve::inverse(const cv::Mat& image) const {
  return applyCurve(image, lut_inverse8_, lut_inverse16_, [this](double x) { return inverse(x); });
}

cv::Mat ResponseCurve::forward(const cv::Mat& image) const {
  return applyCurve(image, lut_forward8_, lut_forward16_, [this](double y) { return forward(y); });
}

const std::vector<double>& ResponseCurve::inverseLut(int bits) const {
  if (bits == 8) return lut_inverse8_;
  if (bits == 16) return lut_inverse16_;
  throw InvalidInput("lookup tables exist for 8 and 16 bits only");
}

const std::vector<double>& ResponseCurve::forwardLut(int bits) const {
  if (bits == 8) return lut_forward8_;
  if (bits == 16) return lut_forward16_;
  throw InvalidInput("lookup tables exist for 8 and 16 bits only");
}

std::vector<double> ResponseCurve::sample(int n) const {
  std::vector<double> samples(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) samples[static_cast<size_t>(i)] = inverse(double(i) / (n - 1));
  return samples;
}

bool ResponseCurve::isConvex(double tolerance) const {
  for (size_t i = 1; i + 1 < phi_.size(); ++i)
    if (phi_[i + 1] - 2 * phi_[i] + phi_[i - 1] < -tolerance) return false;
  return true;
}

}  // namespace crfcal
