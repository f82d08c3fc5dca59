// The kernel's canvas (pair_stages.hpp, Canvas): the edge-rich tiles side by side, in [0,1], the sharp shot also
// denoised for the kernel estimation.
#include <algorithm>

#include <opencv2/imgproc.hpp>

#include "crfcal/noise_estimation.hpp"
#include "image_units.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {
namespace {

// The sharp image is the noisy (high-ISO) one; noise in ∂I biases the gradient-domain kernel regression
// (errors in variables: the kernel shrinks and spreads). As in [27], it is denoised first — an edge-preserving
// bilateral filter scaled to the estimated noise level — for kernel estimation only (the φ fit uses the raw I).
cv::Mat denoiseForKernel(const cv::Mat& image) {
  const double sigma = estimateNoiseSigma(image).sigma;
  if (!(sigma > 0.002)) return image;
  cv::Mat f, out;
  image.convertTo(f, CV_32F);
  cv::bilateralFilter(f, out, 7, static_cast<float>(std::max(3 * sigma, 0.02)), 2.0);
  out.convertTo(out, CV_64F);
  return out;
}

}  // namespace

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
