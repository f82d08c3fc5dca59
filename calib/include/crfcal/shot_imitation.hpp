#pragma once
// A reference shot made to look like another shot of the same scene in everything but its processing: its levels
// mapped onto the other shot's histogram (a monotone map: ranks kept, as an exposure and tone change would), the
// other shot's measured noise σ(v) added, and the result quantised to 8 bits.
//
// The control of an edge comparison (edge_profile.hpp): darkness and noise by themselves change a measured edge
// profile a little (a noisier gradient direction tilts the profiles, fewer levels coarsen them). If a short, dark,
// noisy shot's edges are wider than this imitation's, the widening is smoothing — noise reduction, or the JPEG
// quantisation of a dark frame — and not the measurement. The target's histogram already holds its noise, so the
// imitation is a little noisier than the target: a conservative control. Pure computation.
#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/noise_model.hpp"

namespace crfcal {

struct ShotImitationOptions {
  std::uint64_t seed = 1;  // of the added noise
  int levels = 256;        // output quantised to this many levels (0: not quantised)
  void check() const;      // throws InvalidInput
};

// `reference`, `target`: single channel, CV_8U or float in [0, 1] (sizes may differ; the histogram only is used);
// `target_noise`: the target's σ(v) (measureNoiseLevels), linear between its bins and constant outside; empty: no
// noise. Returns CV_64F in [0, 1] of the reference's size.
cv::Mat imitateShot(const cv::Mat& reference, const cv::Mat& target, const std::vector<NoiseLevelBin>& target_noise,
                    const ShotImitationOptions& options = {});

}  // namespace crfcal
