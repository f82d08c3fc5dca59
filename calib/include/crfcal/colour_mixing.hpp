#pragma once
// Colour models of a camera's RAW → JPEG rendering, beyond the seed's "one pointwise curve per channel".
//
// The seed (and the dual-image fitter) assume  jpeg_c = f_c(s_c · raw_c): each channel is its own pointwise curve
// of its own linear channel (Sec. 3: B = ψ(r · (φ(I) ⊗ K)) per channel). Real cameras apply white balance, then a
// 3×3 colour-correction matrix, clip to the output gamut, then the tone curve — and some a further (saturation)
// mix after the curve. Models, nested (each fit starts from the previous one's solution):
//   pointwise:         jpeg_c = f_c(s_c · raw_c)                       (diagonal M; the seed's assumption)
//   mix:               jpeg_c = f_c((M · raw)_c), f_c extrapolated linearly outside [0, 1]   (no clipping)
//   mix_clip:          jpeg_c = f_c(clip01((M · raw)_c))               (gamut clipping before the curve)
//   mix_clip_post:     jpeg   = N · f(clip01(M · raw))                 (+ a 3×3 mix after the curve)
// f_c is monotone piecewise linear on knots t_k = (k/K)², k = 0..K (dense in the darks, where linear RAW lives):
// f_c(t_k) = b_c + Σ_{j≤k} δ_{c,j}, δ ≥ 0, b_c a free black offset. Every prediction is finally clipped to [0, 1].
// Fit: least squares over all samples and channels + a small slope-roughness penalty, all parameters jointly with
// NLopt L-BFGS (bounds δ ≥ 0, s > 0; central-difference gradient — the model is piecewise linear).
#include <array>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace crfcal {

// One colour sample: linear RAW and the camera's JPEG of the same spot (both in [0, 1], R, G, B).
struct ColourSample {
  std::array<double, 3> raw{};
  std::array<double, 3> jpeg{};
  int group = 0;  // caller's label (e.g. scene), not used by the fit
  int patch = -1; // caller's label (e.g. ColorChecker patch 0..23; 18..23 are the grey patches)
  double weight = 1;
};

enum class ColourModelKind { pointwise, mix, mix_clip, mix_clip_post };
const char* toString(ColourModelKind kind);
// All kinds in nesting order.
std::vector<ColourModelKind> allColourModelKinds();

struct ColourFitOptions {
  int knots = 12;              // K segments of each f_c
  double smoothness = 1e-4;    // weight of Σ (slope_{k+1} − slope_k)² relative to the mean squared data residual
  int max_evaluations = 4000;  // per NLopt run
  void check() const;          // throws InvalidInput
};

struct ColourModel {
  ColourModelKind kind = ColourModelKind::pointwise;
  Eigen::Matrix3d mix = Eigen::Matrix3d::Identity();   // M (diagonal for pointwise)
  Eigen::Matrix3d post = Eigen::Matrix3d::Identity();  // N (identity unless mix_clip_post)
  std::vector<double> knots;                           // t_k, k = 0..K
  std::array<std::vector<double>, 3> curve;            // f_c(t_k)

  // Predicted JPEG (in [0, 1]) of a RAW triple.
  std::array<double, 3> predict(const std::array<double, 3>& raw) const;
  // f_c(x) (clipped or extrapolated according to kind).
  double curveValue(int channel, double x) const;
};

struct ColourFitResult {
  ColourModel model;
  double train_rmse = 0;  // over the training samples and channels, JPEG units [0, 1]
  int evaluations = 0;
  std::string summary() const;
};

// Fits the model of `kind` (and, for its start, the nested simpler ones). Throws InvalidInput for fewer than 8
// samples or non-finite values.
ColourFitResult fitColourModel(const std::vector<ColourSample>& samples, ColourModelKind kind,
                               const ColourFitOptions& options = {});
// Fits all four kinds in nesting order (cheaper than four separate calls).
std::vector<ColourFitResult> fitColourModels(const std::vector<ColourSample>& samples,
                                             const ColourFitOptions& options = {});

// Re-fits only the white balance of a fitted model on new samples (e.g. the six grey patches of another scene, as a
// camera's white balance does): M ← M · diag(g), g > 0 found by NLopt BOBYQA on log g; colour matrix and curves
// are kept. Throws InvalidInput for fewer than 2 samples.
ColourModel adaptWhiteBalance(const ColourModel& model, const std::vector<ColourSample>& samples);

// RMS prediction error over samples and channels, JPEG units [0, 1] (weighted by sample weight).
double colourRmse(const ColourModel& model, const std::vector<ColourSample>& samples);

}  // namespace crfcal
