#include "crfcal/level_mixture.hpp"

#include <algorithm>
#include <cmath>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"

namespace crfcal {

int naturalLevels(const cv::Mat& image) {
  if (image.depth() == CV_8U) return 256;
  cv::Mat unit = toUnitGray(image);
  cv::Mat scaled = unit * 255.0;
  cv::Mat rounded;
  scaled.convertTo(rounded, CV_32S);
  rounded.convertTo(rounded, CV_64F);
  double worst = cv::norm(scaled, rounded, cv::NORM_INF);
  return worst < 1e-6 ? 256 : 1024;
}

LevelImage toLevels(const cv::Mat& image, int levels) {
  if (levels < 2 || levels > 65536) throw InvalidInput("levels must be in [2, 65536]");
  const cv::Mat unit = toUnitGray(image);
  LevelImage out;
  out.levels = levels;
  out.lo.create(unit.size(), CV_16U);
  cv::Mat frac(unit.size(), CV_32F);
  bool exact = true;
  const double top = levels - 1;
  for (int y = 0; y < unit.rows; ++y) {
    const double* u = unit.ptr<double>(y);
    auto* lo = out.lo.ptr<std::uint16_t>(y);
    auto* fr = frac.ptr<float>(y);
    for (int x = 0; x < unit.cols; ++x) {
      const double s = std::clamp(u[x], 0.0, 1.0) * top;
      double base = std::floor(s);
      double t = s - base;
      if (t < 1e-6) t = 0;
      if (t > 1 - 1e-6) { base += 1; t = 0; }
      if (base >= top) { base = top; t = 0; }
      lo[x] = static_cast<std::uint16_t>(base);
      fr[x] = static_cast<float>(t);
      if (t != 0) exact = false;
    }
  }
  if (!exact) out.frac = frac;
  return out;
}

cv::Rect interiorRect(cv::Size size, const cv::Mat& kernel) {
  // (I ⊗ K)(p) reads I(p − k + c) for k in the kernel's support.
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  int ky0 = kernel.rows, ky1 = -1, kx0 = kernel.cols, kx1 = -1;
  for (int y = 0; y < kernel.rows; ++y)
    for (int x = 0; x < kernel.cols; ++x)
      if (kernel.at<double>(y, x) > 0) {
        ky0 = std::min(ky0, y); ky1 = std::max(ky1, y);
        kx0 = std::min(kx0, x); kx1 = std::max(kx1, x);
      }
  if (ky1 < 0) return {};
  const int y0 = ky1 - cy, y1 = size.height - 1 + ky0 - cy;  // inclusive range of p.y
  const int x0 = kx1 - cx, x1 = size.width - 1 + kx0 - cx;
  const int top = std::max(0, y0), left = std::max(0, x0);
  const int bottom = std::min(size.height - 1, y1), right = std::min(size.width - 1, x1);
  if (bottom < top || right < left) return {};
  return {left, top, right - left + 1, bottom - top + 1};
}

LevelMixture LevelMixture::build(const LevelImage& sharp, const cv::Mat& kernel, std::span<const cv::Point> pixels) {
  if (kernel.type() != CV_64F) throw InvalidInput("level mixture: kernel must be CV_64F");
  struct Tap { int dy, dx; double k; };
  std::vector<Tap> taps;
  const int cy = kernel.rows / 2, cx = kernel.cols / 2;
  for (int y = 0; y < kernel.rows; ++y)
    for (int x = 0; x < kernel.cols; ++x)
      if (const double k = kernel.at<double>(y, x); k > 0) taps.push_back({cy - y, cx - x, k});
  const cv::Rect inside = interiorRect(sharp.lo.size(), kernel);
  LevelMixture m;
  m.levels_ = sharp.levels;
  m.row_.reserve(pixels.size() + 1);
  std::vector<double> dense_w(sharp.levels, 0.0), dense_u(sharp.levels, 0.0);
  std::vector<int> touched;
  touched.reserve(taps.size() * 2);
  const bool has_frac = !sharp.frac.empty();
  auto add = [&](int level, double w, double u) {
    if (dense_w[level] == 0.0 && dense_u[level] == 0.0) touched.push_back(level);
    dense_w[level] += w;
    dense_u[level] += u;
  };
  for (const cv::Point& p : pixels) {
    if (!inside.contains(p)) throw InvalidInput("level mixture: pixel's kernel support leaves the image");
    touched.clear();
    for (const Tap& t : taps) {
      const int y = p.y + t.dy, x = p.x + t.dx;
      const int lo = sharp.lo.at<std::uint16_t>(y, x);
      if (has_frac) {
        const double f = sharp.frac.at<float>(y, x);
        if (f > 0) {
          add(lo, t.k * (1 - f), t.k * t.k * (1 - f));
          add(lo + 1, t.k * f, t.k * t.k * f);
          continue;
        }
      }
      add(lo, t.k, t.k * t.k);
    }
    std::sort(touched.begin(), touched.end());
    for (int level : touched) {
      m.level_.push_back(static_cast<std::uint16_t>(level));
      m.weight_.push_back(dense_w[level]);
      m.squared_.push_back(dense_u[level]);
      dense_w[level] = dense_u[level] = 0.0;
    }
    m.row_.push_back(m.level_.size());
  }
  return m;
}

void LevelMixture::mix(std::span<const double> values, std::span<double> out) const {
  if (static_cast<int>(values.size()) != levels_ || static_cast<int>(out.size()) != pixels())
    throw InvalidInput("level mixture: size mismatch");
  for (int p = 0; p < pixels(); ++p) {
    double s = 0;
    for (std::size_t i = row_[p]; i < row_[p + 1]; ++i) s += weight_[i] * values[level_[i]];
    out[p] = s;
  }
}

void LevelMixture::mixSquared(std::span<const double> values, std::span<double> out) const {
  if (static_cast<int>(values.size()) != levels_ || static_cast<int>(out.size()) != pixels())
    throw InvalidInput("level mixture: size mismatch");
  for (int p = 0; p < pixels(); ++p) {
    double s = 0;
    for (std::size_t i = row_[p]; i < row_[p + 1]; ++i) s += squared_[i] * values[level_[i]];
    out[p] = s;
  }
}

}  // namespace crfcal
