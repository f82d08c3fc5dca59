// The kernel's canvas (pair_stages.hpp, Canvas): the edge-rich tiles side by side, in [0,1], the sharp shot also
// denoised for the kernel estimation.
#include <algorithm>


#include "image_units.hpp"
#include "irradiance_kernel_inputs.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

Canvas makeCanvas(const cv::Mat& sharp8, const cv::Mat& blurred8, const cv::Mat& usable, const std::vector<Tile>& tiles,
                  int margin) {
  Canvas c;
  const cv::Rect frame(0, 0, sharp8.cols, sharp8.rows);
  std::vector<cv::Rect> crops;
  for (const auto& t : tiles)
    crops.push_back(cv::Rect(t.rect.x - margin, t.rect.y - margin, t.rect.width + 2 * margin, t.rect.height + 2 * margin) &
                    frame);
  int width = 0, height = 0;
  for (const auto& r : crops) {
    width += r.width + 1;
    height = std::max(height, r.height);
  }
  if (crops.size() == 1 && crops[0] == frame) {
    c.sharp = unit(sharp8);
    c.blurred = unit(blurred8);
    c.usable = usable.clone();
    c.regions = {tiles[0].rect};
  } else {
    c.sharp = cv::Mat::zeros(height, width, CV_64F);
    c.blurred = cv::Mat::zeros(height, width, CV_64F);
    c.usable = cv::Mat::zeros(height, width, CV_8U);
    int x = 0;
    for (std::size_t i = 0; i < crops.size(); ++i) {
      const cv::Rect& r = crops[i];
      const cv::Rect at(x, 0, r.width, r.height);
      unit(sharp8(r)).copyTo(c.sharp(at));
      unit(blurred8(r)).copyTo(c.blurred(at));
      usable(r).copyTo(c.usable(at));
      c.regions.push_back(tiles[i].rect - r.tl() + at.tl());
      x += r.width + 1;
    }
  }
  c.sharp_denoised = denoiseForKernel(c.sharp);
  return c;
}

}  // namespace crfcal::detail
