#pragma once
// The shape of a blur kernel: one continuous path (a handheld shake during one exposure) or separate blobs (a long
// shot assembled from several stabilised frames, each frame a compact blob at its own offset).
//
// A motion during one exposure leaves one connected trace; a multi-frame long shot whose frames are aligned before
// merging leaves one blob, and one whose frames are merged unaligned leaves several blobs with gaps between them.
// The support is the kernel above `support_fraction` of its maximum; its 8-connected components are counted when
// they hold at least `min_component_mass` of the mass (estimation specks hold less). Pure computation.
#include <opencv2/core.hpp>

namespace crfcal {

struct KernelShapeOptions {
  double support_fraction = 0.05;    // support: entries above this fraction of the kernel's maximum
  double min_component_mass = 0.10;  // a component counts when it holds at least this fraction of the mass
  void check() const;                // throws InvalidInput
};

struct KernelShape {
  int components = 0;              // counted components of the support
  double largest_mass = 0;         // fraction of the mass in the largest component
  double rms_radius = 0;           // about the centroid, pixels (kernelRmsRadius)
  double elongation = 1;           // √(λ_max / λ_min) of the second moments (1: round; large: a line)
  int support = 0;                 // support entries
  bool multimodal() const { return components > 1; }
};

// `kernel`: single channel, non-negative, not all zero. Throws InvalidInput otherwise.
KernelShape describeKernelShape(const cv::Mat& kernel, const KernelShapeOptions& options = {});

}  // namespace crfcal
