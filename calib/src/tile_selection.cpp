#include "crfcal/tile_selection.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/kernel_estimation.hpp"

namespace crfcal {

void TileSelectionOptions::check() const {
  if (tile_size < 64) throw InvalidInput("tile size must be >= 64");
  if (max_tiles < 1) throw InvalidInput("max_tiles must be >= 1");
  if (!(min_valid_fraction > 0 && min_valid_fraction <= 1)) throw InvalidInput("min_valid_fraction in (0, 1]");
}

std::vector<Tile> selectTiles(const cv::Mat& sharp, const cv::Mat& valid, const TileSelectionOptions& options) {
  options.check();
  const cv::Rect bounds = cv::boundingRect(valid);
  if (bounds.area() == 0) throw InvalidInput("the pair does not overlap (no usable pixels after registration)");
  auto score = [&](const cv::Rect& r) {
    const cv::Mat gray = toUnitGray(sharp(r));  // per tile: a 24 MP frame is never converted as a whole
    cv::Mat gx, gy, mag;
    cv::Sobel(gray, gx, CV_64F, 1, 0, 3);
    cv::Sobel(gray, gy, CV_64F, 0, 1, 3);
    cv::magnitude(gx, gy, mag);
    return cv::mean(mag, valid(r))[0];
  };
  if (std::max(sharp.cols, sharp.rows) <= options.whole_image_below) return {Tile{bounds, score(bounds)}};
  std::vector<Tile> tiles;
  const int t = options.tile_size;
  for (int y = bounds.y; y + t <= bounds.y + bounds.height; y += t)
    for (int x = bounds.x; x + t <= bounds.x + bounds.width; x += t) {
      const cv::Rect r(x, y, t, t);
      const double fraction = cv::countNonZero(valid(r)) / static_cast<double>(r.area());
      if (fraction < options.min_valid_fraction) continue;
      tiles.push_back({r, 0});
    }
  if (tiles.empty()) return {Tile{bounds, score(bounds)}};
  cv::parallel_for_(cv::Range(0, static_cast<int>(tiles.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) tiles[i].score = score(tiles[i].rect);
  });
  std::sort(tiles.begin(), tiles.end(), [](const Tile& a, const Tile& b) { return a.score > b.score; });
  if (static_cast<int>(tiles.size()) > options.max_tiles) tiles.resize(options.max_tiles);
  return tiles;
}

std::string KernelDisagreement::summary() const {
  char buffer[200];
  std::snprintf(buffer, sizeof buffer, "%d tiles: relative difference to the combined kernel mean %.3f, max %.3f; "
                "centroid spread %.2f px", tiles, mean_relative, max_relative, centroid_spread);
  return buffer;
}

KernelDisagreement kernelDisagreement(const std::vector<cv::Mat>& tile_kernels, const cv::Mat& combined) {
  KernelDisagreement d;
  d.tiles = static_cast<int>(tile_kernels.size());
  std::vector<cv::Point2d> centroids;
  for (const auto& k : tile_kernels) {
    const double e = kernelRelativeError(k, combined);
    d.mean_relative += e / std::max(1, d.tiles);
    d.max_relative = std::max(d.max_relative, e);
    centroids.push_back(kernelCentroid(k));
  }
  for (size_t i = 0; i < centroids.size(); ++i)
    for (size_t j = i + 1; j < centroids.size(); ++j)
      d.centroid_spread = std::max(d.centroid_spread, cv::norm(centroids[i] - centroids[j]));
  return d;
}

}  // namespace crfcal
