#pragma once
// Large images: the kernel is estimated on the most edge-rich tiles rather than the whole frame (a 24 MP
// frame holds far more pixels than a 35×35 kernel needs), one kernel per tile, and the tiles' disagreement
// measures how spatially varying the blur is (the seed's model assumes one global K, Eq. 3).
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

struct TileSelectionOptions {
  int tile_size = 512;            // square tiles, pixels (full resolution)
  int max_tiles = 6;              // the most edge-rich tiles kept
  int whole_image_below = 1200;   // images whose longer side is at most this: one region = the valid area
  double min_valid_fraction = 0.95;  // of a tile's pixels inside the usable mask
  void check() const;             // throws InvalidInput
};

struct Tile {
  cv::Rect rect;
  double score = 0;  // mean gradient magnitude of the sharp image over the tile (edge richness)
};

// Tiles of `sharp` (single channel, any depth) ranked by edge richness among those inside `valid` (CV_8U).
// Always returns at least one region (the bounding box of `valid` when no tile qualifies).
std::vector<Tile> selectTiles(const cv::Mat& sharp, const cv::Mat& valid, const TileSelectionOptions& options = {});

// How much per-tile kernels disagree with the combined kernel.
struct KernelDisagreement {
  int tiles = 0;
  double mean_relative = 0;   // mean over tiles of ‖K_t − K‖₂ / ‖K‖₂
  double max_relative = 0;
  double centroid_spread = 0; // largest distance between two tiles' kernel centroids, pixels
  std::string summary() const;
  // Above this mean relative difference the blur is taken to vary across the frame: `calibrate` warns, and
  // `deblur --from` deblurs with the tiles' kernels (--kernels auto).
  static constexpr double kVarying = 0.6;
  bool varies() const { return tiles > 1 && mean_relative > kVarying; }
};
KernelDisagreement kernelDisagreement(const std::vector<cv::Mat>& tile_kernels, const cv::Mat& combined);

}  // namespace crfcal
