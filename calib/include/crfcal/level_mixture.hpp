#pragma once
// Sparse level mixtures: the blur of a function of a quantised image as a sparse product (seed Eq. 21–22).
//
// For an image I with values on L levels x_v = v/(L−1) and any function f of intensity,
//   (f(I) ⊗ K)(p) = Σ_q K(q) f(I(p − q + c)) = Σ_v w_p(v) f(x_v),
// where w_p(v) is the kernel mass that falls on neighbours of level v. The weights depend only on I and K, so
// they are computed once for the selected pixels; evaluating the blur of any f is then a sparse product with
// O(non-zeros) cost instead of a full-image convolution. The squared masses u_p(v) = Σ K(q)² over the same
// neighbours give the variance of the mixture when I carries independent per-pixel noise (noise_debias.hpp).
// Images that are not on L levels are split linearly between the two neighbouring levels (exact for f
// piecewise linear on the level grid).
#include <cstdint>
#include <span>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

// An image as level indices: value = (1 − frac)·x_lo + frac·x_{lo+1}.
struct LevelImage {
  cv::Mat lo;    // CV_16U level index in [0, levels − 1]
  cv::Mat frac;  // CV_32F in [0,1); empty when every pixel is exactly on a level
  int levels = 256;
};

// Number of levels that represents `image` (CV_8U: 256, CV_16U/float on the 8-bit grid: 256, otherwise 1024).
int naturalLevels(const cv::Mat& image);
// Converts a single-channel CV_8U/CV_16U/CV_32F/CV_64F image ([0,1] for floats) to levels.
LevelImage toLevels(const cv::Mat& image, int levels);

class LevelMixture {
 public:
  LevelMixture() = default;
  // Mixture weights of `sharp` under `kernel` (normalised CV_64F; convolution as in blur_model.hpp) for the
  // given pixels, whose kernel support must lie inside the image (throws InvalidInput otherwise).
  static LevelMixture build(const LevelImage& sharp, const cv::Mat& kernel, std::span<const cv::Point> pixels);

  int pixels() const { return static_cast<int>(row_.size()) - 1; }
  int levels() const { return levels_; }
  std::size_t nonZeros() const { return level_.size(); }

  // out_p = Σ_v w_p(v) values[v] (values has `levels()` entries, out has `pixels()`).
  void mix(std::span<const double> values, std::span<double> out) const;
  // out_p = Σ_v u_p(v) values[v], u_p(v) = Σ K(q)² over the neighbours of level v.
  void mixSquared(std::span<const double> values, std::span<double> out) const;

  // Row p as parallel spans (levels, masses, squared masses).
  std::span<const std::uint16_t> rowLevels(int p) const { return {level_.data() + row_[p], level_.data() + row_[p + 1]}; }
  std::span<const double> rowWeights(int p) const { return {weight_.data() + row_[p], weight_.data() + row_[p + 1]}; }
  std::span<const double> rowSquared(int p) const { return {squared_.data() + row_[p], squared_.data() + row_[p + 1]}; }

 private:
  int levels_ = 0;
  std::vector<std::size_t> row_{0};
  std::vector<std::uint16_t> level_;
  std::vector<double> weight_;
  std::vector<double> squared_;
};

// Pixels whose whole kernel support lies inside an image of `size` (the rest are "border").
cv::Rect interiorRect(cv::Size size, const cv::Mat& kernel);

}  // namespace crfcal
