#pragma once
// The median profile across an image's strong edges: how wide its edges are and whether they ring.
//
// Eq. 4 of the seed models the sharp shot as ψ(E) per pixel and the blurred one as ψ(r·φ(I) ⊗ K) with K ≥ 0. Two
// things a phone's JPEG engine does break that: noise reduction smooths the "sharp" shot's edges (the kernel between
// the shots is then not the shake alone), and sharpening adds sign-changing lobes next to edges (an overshoot on the
// bright side, an undershoot on the dark side), which no non-negative kernel produces. Both show in the median
// profile across strong edges, each profile normalised to a unit step (0 on its dark far end, 1 on its bright one):
// the 10–90 % rise distance is the edge width; the bright side's maximum above 1 is the overshoot, the dark side's
// minimum below 0 the undershoot. The median over many edges cancels the noise; a systematic lobe survives.
// Pure computation.
#include <vector>

#include <opencv2/core.hpp>

namespace crfcal {

struct EdgeProfileOptions {
  int radius = 5;                // profile sampled over −radius … +radius pixels across the edge
  double step = 0.5;             // sampling step along the profile, pixels
  double edge_fraction = 0.02;   // edges: the strongest this fraction of the interior pixels' gradients (after NMS)
  // A profile's step (bright far end − dark far end) at least this fraction of the image's 0.5–99.5 % level range
  // (relative: a short shot underexposed by r = 6 holds 99.5 % of its pixels below 0.1).
  double min_contrast = 0.15;
  // An isolated step: (bright far end − dark far end) at least this fraction of the profile's max − min. Thin lines
  // and double edges inside the window fail it; a halo of up to 1/isolation − 1 of the step (in total) passes.
  double isolation = 0.5;
  int max_edges = 5000;          // at most this many (strongest first)
  double direction_sigma = 1.0;  // Gaussian σ (pixels) smoothing the copy the gradient direction is taken from
  void check() const;            // throws InvalidInput
};

struct EdgeProfile {
  std::vector<double> offset;   // pixels across the edge (dark side negative)
  std::vector<double> profile;  // median normalised profile (0 → 1), per offset
  int edges = 0;                // profiles averaged
  double width = 0;             // 10–90 % rise distance of `profile`, pixels (NaN when it never crosses)
  double overshoot = 0;         // max of `profile` on the bright side minus its bright far end (≥ 0)
  double undershoot = 0;        // its dark far end minus the min on the dark side (≥ 0)
  double halo() const { return 0.5 * (overshoot + undershoot); }
};

// `image`: single channel, CV_8U, CV_16U or float in [0, 1]. Throws InvalidInput when the image is smaller than the
// profile or has no strong edge.
EdgeProfile measureEdgeProfile(const cv::Mat& image, const EdgeProfileOptions& options = {});

}  // namespace crfcal
