#pragma once
// Pictures of calibrate's maps for a person to read (OpenCV drawing): a title and notes above, the map, a colour
// bar or legend at the right. The data behind them are in report.json / kernel.txt; these are for the eye.
#include <filesystem>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal::io {

struct FigureText {
  std::string title;
  std::vector<std::string> notes;  // lines under the title (wrapped to the picture's width)
};

// A signed map (e.g. Γ = B − I⊗K) in a diverging blue–white–red colour map centred at 0, scaled symmetrically to
// ± the `percentile`-th percentile of |map| over its non-zero pixels (rarer, larger values saturate: one outlier
// does not wash the rest out). Exact zeros (no data) are grey. `units`: the colour bar's caption lines.
void writeSignedMapFigure(const std::filesystem::path& path, const cv::Mat& map, const FigureText& text,
                          const std::vector<std::string>& units, double percentile = 99);

// A blur kernel enlarged with nearest neighbours to ≥ 280 px, in a perceptual colour map (fraction of its peak),
// ticks in pixels from the kernel's centre, a colour bar. The picture is not a kernel file: kernel.txt is.
void writeKernelFigure(const std::filesystem::path& path, const cv::Mat& kernel, const FigureText& text);

// A 0/255 mask drawn over a dimmed grey copy of `image` (same size; any depth/channels; empty: black), with a
// legend naming what the highlighted (mask) and dimmed (not in mask) pixels are.
void writeMaskFigure(const std::filesystem::path& path, const cv::Mat& mask, const cv::Mat& image,
                     const FigureText& text, const std::string& in_mask, const std::string& not_in_mask);

}  // namespace crfcal::io
