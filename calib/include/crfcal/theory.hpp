#pragma once
// Sec. 3 of the seed (Chen et al., ECCV 2012): the blur inconsistency Γ = B − B̂ between the irradiance blur
// model B = ψ(φ(I) ⊗ K) (Eq. 5) and the intensity blur model B̂ = I ⊗ K, made measurable:
//   - Fig. 1(a): Γ profiles of a 1-D signal for box kernels of 10, 20, 30 and 80 px under φ = gamma 2.2;
//   - Fig. 1(b)/(c): a pattern of blocks of growing brightness, its horizontal motion blur and Γ per edge;
//   - Theorem 1: a checker of 0 ≤ Γ ≤ Imax − Imin (Eq. 16) with Claim 1/2/3 statistics on any image.
// Pure computation: everything is built on convolve / irradianceBlur / intensityBlur / localRange of
// blur_model.hpp, so that the theorem is checked on exactly the forward model the rest of crfcal uses.
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal::theory {

// ---------------------------------------------------------------------------------------------------------
// Fig. 1(a): 1-D profiles.

// The deterministic 1-D sharp signal I(x), x = 0..999, used for Fig. 1(a) (values in [0,1]):
//   [0,100)    flat 0.15
//   [100,250)  raised-cosine ramp 0.15 → 0.65 (smooth, max slope 0.0052 / px)
//   [250,350)  flat 0.65
//   [350,500)  smooth raised-cosine dip 0.65 → 0.45 → 0.65 (low frequency, C¹)
//   [500,600)  flat 0.65; step edge at x = 600 down to 0.45 (contrast 0.2)
//   [600,700)  flat 0.45; step edge at x = 700 down to 0.05 (contrast 0.4)
//   [700,820)  flat 0.05; step edge at x = 820 up to 0.95 (contrast 0.9)
//   [820,1000) flat 0.95
// Steps are ≥ 100 px apart, so even the 80 px kernel sees one edge at a time.
std::vector<double> fig1Signal();

struct ProfileOptions {
  std::vector<int> kernel_lengths{10, 20, 30, 80};  // horizontal box kernels of Fig. 1(a) (Sec. 3.1, Claim 2)
  ResponseModel model = GammaModel{2.2};           // φ; Fig. 1 uses gamma 2.2
  // A neighbour difference |I(x) − I(x−1)| above this is a step edge; a sample is "near an edge" when its
  // kernel support contains a step. The smooth parts of fig1Signal() change by ≤ 0.0053 / px.
  double jump_threshold = 0.05;
  void check() const;  // throws InvalidInput
};

struct GammaProfile {
  int kernel_length = 0;
  std::vector<double> blurred;            // B = ψ(φ(I) ⊗ K), Eq. 5
  std::vector<double> intensity_blurred;  // B̂ = I ⊗ K
  std::vector<double> gamma;              // Γ = B − B̂
  std::vector<unsigned char> near_edge;   // 1 where the kernel support holds a step edge
  double max_gamma = 0, min_gamma = 0;
  double max_abs_gamma_smooth = 0;   // over samples not near an edge (Claim 2: ≈ 0 for small kernels)
  double max_gamma_edge = 0;         // over samples near an edge (Claim 3: large)
  double mean_abs_gamma_smooth = 0;
};

struct ProfileResult {
  std::vector<double> sharp;  // I
  std::vector<GammaProfile> profiles;
  std::string summary() const;
};

// Γ profiles of `signal` (values in [0,1]) for each kernel length in `options` (horizontal box kernels,
// convolution with replicated borders, as in blur_model.hpp).
ProfileResult blurProfiles(const std::vector<double>& signal, const ProfileOptions& options = {});

// ---------------------------------------------------------------------------------------------------------
// Fig. 1(b)/(c): blocks of growing brightness on a dark background.

struct PatternOptions {
  std::vector<double> block_values{0.2, 0.4, 0.6, 0.8, 1.0};  // foreground blocks, left to right (Fig. 1(c))
  double background = 0.0;  // dark background: block i has edges of contrast block_values[i] − background
  int block_width = 100;    // px; ≥ the largest kernel of Fig. 1(b) (80 px) so edges stay separate
  int gap = 100;            // px between blocks and before the first / after the last block
  int height = 60;          // image rows; blocks span the middle third
  int motion_length = 20;   // horizontal motion blur of Fig. 1(c), px
  ResponseModel model = GammaModel{2.2};  // φ of Fig. 1(c)
  void check() const;       // throws InvalidInput
};

struct EdgeStat {
  int block = 0;           // 0-based block index
  int x = 0;               // column of the first pixel on the right side of the step
  bool rising = true;      // background → block (left edge) or block → background (right edge)
  double contrast = 0;     // |block − background| = Imax − Imin across the edge (Theorem 1's bound)
  double max_gamma = 0;    // max Γ on the middle row where the kernel straddles the edge (± 1 px)
  // Claim 3 / Eq. 12 generalised to a step a → b: at the edge B̂ = a + t (b − a) and
  // B = ψ((1 − t) φ(a) + t φ(b)) with t the partial sums of the kernel; this is max_t of B − B̂.
  double predicted_max_gamma = 0;
};

struct PatternResult {
  cv::Mat sharp;              // I, CV_64F
  cv::Mat blurred;            // B
  cv::Mat intensity_blurred;  // B̂
  cv::Mat gamma;              // Γ
  std::vector<EdgeStat> edges;  // two per block, left to right
  double max_gamma = 0, min_gamma = 0;
  std::string summary() const;
};

cv::Mat blockPattern(const PatternOptions& options = {});
PatternResult analyzePattern(const PatternOptions& options = {});

// ---------------------------------------------------------------------------------------------------------
// Theorem 1: 0 ≤ Γ ≤ Imax − Imin for convex φ (Eq. 13–16), with Claim 1/2 statistics.

struct Theorem1Options {
  // Allowance for rounding in 0 ≤ Γ ≤ Imax − Imin (Eq. 16). ψ is steep where φ' is small (dark pixels under a
  // gamma curve), so convolution rounding (~1e-16) can grow there; 1e-12 is still far below one 16-bit level.
  double tolerance = 1e-12;
  double smooth_range = 0.05;  // Imax − Imin below this: a low-frequency pixel (Claim 2)
  double edge_range = 0.3;     // Imax − Imin at least this: an edge pixel (Claim 3)
  bool keep_maps = false;      // return B, B̂, Γ and Imax − Imin
  void check() const;          // throws InvalidInput
};

// What Theorem 1 needs besides the curve: I, K, B̂ = I ⊗ K and Imin/Imax. Shared between curves.
struct BlurContext {
  cv::Mat sharp;              // I, CV_64F in [0,1]
  cv::Mat kernel;             // K, normalised
  cv::Mat intensity_blurred;  // B̂
  LocalRange range;           // Imin, Imax over the kernel's support
};
BlurContext makeBlurContext(const cv::Mat& sharp, const cv::Mat& kernel);

struct Theorem1Check {
  bool curve_convex = false;   // ResponseCurve::isConvex() — the theorem's hypothesis
  long long pixels = 0;
  double min_gamma = 0;        // lower bound: ≥ −tolerance for convex φ (Eq. 14)
  double max_gamma = 0;
  double mean_gamma = 0;
  double max_upper_excess = 0;       // max(Γ − (Imax − Imin)); ≤ tolerance (Eq. 16), for any monotone φ
  double max_blurred_above_max = 0;  // max(B − Imax) ≤ 0 (Eq. 15)
  double min_intensity_above_min = 0;  // min(B̂ − Imin) ≥ 0
  long long lower_violations = 0;  // pixels with Γ < −tolerance
  long long upper_violations = 0;  // pixels with Γ > Imax − Imin + tolerance
  // Claim 1: uniform pixels, Imax − Imin == 0 exactly.
  long long uniform_pixels = 0;
  double max_abs_gamma_uniform = 0;
  // Claim 2 / 3: low-frequency vs edge pixels (Theorem1Options::smooth_range / edge_range).
  long long smooth_pixels = 0, edge_pixels = 0;
  double max_abs_gamma_smooth = 0, mean_abs_gamma_smooth = 0;
  double max_gamma_edge = 0, mean_gamma_edge = 0;
  double max_tightness = 0;  // max Γ / (Imax − Imin) over non-uniform pixels (≤ 1 by Theorem 1)
  double correlation = 0;    // Pearson correlation of Γ with Imax − Imin
  cv::Mat blurred, intensity_blurred, gamma, range;  // with keep_maps

  bool lowerBoundHolds() const { return lower_violations == 0; }
  bool upperBoundHolds() const { return upper_violations == 0; }
  bool holds() const { return lowerBoundHolds() && upperBoundHolds(); }
  std::string summary() const;
};

Theorem1Check checkTheorem1(const BlurContext& context, const ResponseCurve& curve, const Theorem1Options& options = {});
Theorem1Check checkTheorem1(const cv::Mat& sharp, const ResponseCurve& curve, const cv::Mat& kernel,
                            const Theorem1Options& options = {});

// ---------------------------------------------------------------------------------------------------------
// Curves for the Theorem 1 check.

// Greatest convex minorant (lower convex hull) of φ samples at x = i/(n−1). For a non-decreasing φ with
// φ(0) = 0 and φ(1) = 1 the result is convex, non-decreasing and keeps both endpoints — the closest convex
// curve from below, used to turn a real but not globally convex curve (the EMoR mean) into a convex one.
std::vector<double> convexMinorant(const std::vector<double>& phi);

struct NamedCurve {
  std::string name;
  ResponseModel model;
  std::string note;  // where it comes from
};

// The curves `crfcal theory` checks: gamma 2.2 and 1.8 (convex), the EMoR mean inverse g0 (not globally
// convex), its convex minorant, GGCM fits (Eq. 19, ggcm::fitInverse) of the EMoR mean and of two EMoR curves,
// and the concave gamma 1/2.2 (the converse: the lower bound must break).
std::vector<NamedCurve> referenceCurves();

}  // namespace crfcal::theory
