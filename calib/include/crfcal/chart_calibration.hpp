#pragma once
// Inverse response from (intensity, linear reference) pairs with unknown exposure scales: the ColorChecker
// calibration (`crfcal chart`) and the RAW→JPEG camera curves of the benchmark (`crfcal curves`).
//
// Model: reference_i = s_g(i) · φ(x_i), with φ the EMoR/PCA inverse model of Grossberg & Nayar
// (φ = g0 + Σ_{k≤K} c_k h_k, φ(0)=0 and φ(1)=1 by construction, constrained monotone on the 1024 basis nodes) and one
// free positive scale s_g per group g (a shot, or all shots of a camera when the reference is in common units).
// Least squares in the reference domain, Σ w_i (y_i − s_g φ(x_i))² (+ one-sided terms for censored samples, a
// small roughness penalty and a local-exponent penalty, ScaledFitOptions::smoothness / exponent_smoothness),
// solved jointly over (c, s) by NLopt SLSQP with the linear monotonicity constraints. K is chosen by
// cross-validation over caller-given folds (leave one shot out, or leave one patch out). Where there is no data
// (x below/above the covered range) φ is the K-term EMoR model's extrapolation, kept smooth by the two penalties.
#include <functional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "crfcal/colorchecker.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal {

struct ScaledObservation {
  // Exact: y = s·φ(x). Censored samples (one side clipped) only bound the curve: AtMost: s·φ(x) ≤ y (the measured
  // value clipped at the top, so the true x is larger), AtLeast: s·φ(x) ≥ y (the reference clipped at the top).
  enum class Kind { Exact, AtMost, AtLeast };
  Kind kind = Kind::Exact;
  double x = 0;       // measured intensity in [0,1] (e.g. JPEG / 255)
  double y = 0;       // linear reference (> 0), any scale per group
  int group = 0;      // observations of a group share one unknown scale s_g (0 … groups−1)
  int fold = 0;       // cross-validation fold (e.g. shot or patch id)
  double weight = 1;
};

struct ScaledFitOptions {
  int terms = 0;          // K; 0 = choose in [min_terms, max_terms] by cross-validation
  int min_terms = 1;
  int max_terms = 7;      // Grossberg & Nayar: 3–5 terms reach DoRF accuracy; more overfit 24-patch charts
  int monotone_grid = 1024;  // φ' ≥ 0 imposed between consecutive nodes (1024 = basis nodes: exact)
  int max_evaluations = 4000;
  double cv_tolerance = 0.02;  // take the smallest K whose CV error is within (1 + cv_tolerance) of the best
  // Weight λ of the roughness penalty λ·Σ_j (φ(x_{j+1}) − 2φ(x_j) + φ(x_{j−1}))² on a 64-point grid, added to the
  // data term Σ w (y − sφ)² / Σ w y². Negligible for smooth curves (≈ 1e-7 for x^2.2) where data exist, it keeps
  // the unobserved ends from bending into a cliff (a K-term EMoR can otherwise trade the unknown scale against a
  // jump to φ(1) = 1 just past the last sample).
  double smoothness = 0.01;
  // Weight λ of the local-exponent penalty λ·Σ_j (g_{j+1} − g_j)², g_j = Δlog φ / Δlog x between the nodes
  // x_j = j/64 from the last one inside the data up to 1: the curve's local gamma keeps changing the way the data
  // show, the GGCM view of a response (seed Eq. 19: φ = x^(1/P(x)) with a smooth P). Zero for any φ = x^γ and
  // independent of the unknown exposure scales, so unlike `smoothness` it cannot be lowered by trading a scale
  // against a steep end: it decides φ between the brightest exact sample and φ(1) = 1, i.e. the normalisation of
  // the whole curve, and leaves the fit inside the data to the data. 1e-4: on synthetic charts with known curves
  // (`crfcal bench chart`) it lowers the mean full-range φ error by 16–24 % and the RAW-reference worst case from
  // 0.20 to 0.12 at unchanged shape error; it costs on film-like shoulders; 1e-3 bends them further
  // (docs/RESULTS.md#chart).
  double exponent_smoothness = 1e-4;
  // Variable projection: the scales s_g are not optimisation variables but their closed-form least-squares values
  // for the current φ (exact samples only), so SLSQP works on the K coefficients alone. Needed when there are many
  // groups (a multi-exposure bracket: one group per scene point, bracket_calibration.hpp); false keeps the joint
  // (c, s) optimisation the chart calibration was measured with.
  bool profile_scales = false;
  void check() const;
};

struct ScaledFitResult {
  EmorModel model;
  std::vector<double> inverse;      // φ at x = i/1023
  std::vector<double> scales;       // s_g per group (0 for groups without observations)
  int terms = 0;
  std::vector<std::pair<int, double>> cv_rmse;  // (K, cross-validated RMSE in φ units) for each K tried
  std::vector<double> residuals;    // per observation, φ units: y_i/s_g − φ(x_i) (0 for satisfied bounds)
  double rmse = 0;                  // of `residuals` (weighted by w)
  double max_error = 0;
  std::pair<double, double> covered_range{0, 0};  // min / max x of the exact observations
  int observations = 0;             // exact ones
  int censored = 0;                 // AtMost / AtLeast ones
  std::string summary() const;
};

// Fits φ and the scales. Throws InvalidInput if fewer than 3 observations, non-finite or y ≤ 0.
ScaledFitResult fitScaledInverse(std::span<const ScaledObservation> observations, const ScaledFitOptions& options = {});
// Fit with a fixed K (no cross-validation; options.terms ignored).
ScaledFitResult fitScaledInverseFixed(std::span<const ScaledObservation> observations, int terms,
                                      const ScaledFitOptions& options = {});

// ---- ColorChecker calibration ------------------------------------------------------------------------------------

// One shot of the chart: the sampled patches of the measured (e.g. JPEG) image and optionally of the linear RAW of
// the same shot (used as the reference with ChartReference::Raw).
struct ChartShot {
  std::string name;
  std::vector<chart::PatchStats> measured;
  std::vector<chart::PatchStats> raw;  // empty unless a RAW reference is given
  double exposure = 0;                 // relative exposure (e.g. from EXIF); 0 = unknown (a free scale per shot)
  int scene = 0;  // shots of one scene (same chart, same light) share the coloured patches' irradiances
                  // (ReferenceSet::AllPatches); another light or white balance is another scene
};

struct ChartCalibrationOptions {
  bool use_raw = false;                              // reference = RAW patch values of the same shot (per channel)
  chart::ReferenceSet reference = chart::ReferenceSet::Neutral;  // published reference otherwise
  bool raw_common_scale = true;   // with RAW: one scale for all shots (RAW values are in common linear units)
  // With RAW and raw_common_scale: one scale per scene (ChartShot::scene) instead of one for all shots. The gain
  // between a camera's RAW channel and its JPEG tone curve changes with the light (white balance): on the Middlebury
  // cameras the grey patches of the two illuminations sit up to 17 % apart in R and B about one common-scale curve
  // (docs/RESULTS.md#bracket). false: one scale for all (what `crfcal chart --raw` and `bench chart` use).
  bool raw_scale_per_scene = false;
  bool raw_neutral_only = false;  // with RAW: use only the six grey patches (no colour-matrix crosstalk)
  ScaledFitOptions fit;           // K chosen by leave-one-patch-out CV (leave-one-shot-out with RAW)
  ggcm::FitOptions ggcm;          // conversion of the EMoR result to GGCM (seed Eq. 19, [28]), n = 4
  std::vector<int> channels{0, 1, 2};  // R, G, B
  // ReferenceSet::AllPatches without exposures for every shot: rounds alternating the curves (K = 3, all channels)
  // with the shots' exposures (one per shot, shared by R, G, B), before the final fit with cross-validated K.
  int exposure_rounds = 4;
  // ReferenceSet::AllPatches: a coloured patch's channel below this (unit scale) is not data (the camera's colour
  // matrix can push a saturated colour below zero, where the JPEG clips; the bracket's noise floor).
  double colour_floor = 0.02;
  // ReferenceSet::AllPatches: a coloured patch whose RMS relative misfit to the channel's curve exceeds this many
  // times the median patch's is left out (a camera's gamut mapping or hue-dependent rendering is not one curve per
  // channel); 0 = keep all.
  double colour_outlier_factor = 3;
  // ReferenceSet::AllPatches: weight of a grey sample relative to a coloured one. 1: on the five Middlebury cameras
  // the choice was made on, 3 (greys weighing as much as the 18 colours) was worse (docs/RESULTS.md#chart).
  double grey_weight = 1;
  // ReferenceSet::AllPatches: the pointwise band of each channel's φ (scaled_fit_band.hpp), refits on halves of the
  // patches (a patch of a scene is the resampling unit: its shots share its irradiance), K and exposures held.
  // replicates = 0: no band. The other reference sets have too few patches to halve (the six greys): no band.
  CurveBandOptions band;
  void check() const;
};

struct ChartPatchResidual {
  int shot = 0;
  int patch = 0;
  double x = 0;         // measured value
  double reference = 0; // y / s_shot (normalised reference, i.e. the φ value this patch says)
  double residual = 0;  // reference − φ(x)
};

struct ChartChannelResult {
  int channel = 0;
  ScaledFitResult fit;
  GgcmModel ggcm;
  double ggcm_rmse = 0;  // RMSE between the GGCM curve and the EMoR curve (1024 samples)
  bool ggcm_valid = true;
  std::vector<ChartPatchResidual> patches;
  CurveBand band;         // ReferenceSet::AllPatches with options.band.replicates > 0; empty otherwise
  int rejected = 0;       // patch samples not used as exact data (clipped / non-uniform; fit.censored of them
                          // entered as bounds)
};

struct ChartCalibrationResult {
  std::vector<ChartChannelResult> channels;
  // ReferenceSet::AllPatches: the relative exposure of each shot used by the fit (given, or fitted; the brightest
  // shot of the set = 1). Empty otherwise.
  std::vector<double> exposures;
  std::vector<std::string> warnings;
  std::string summary() const;
};

using ProgressCallback = std::function<void(double fraction, const std::string& detail)>;

ChartCalibrationResult calibrateChart(const std::vector<ChartShot>& shots, const ChartCalibrationOptions& options,
                                      const ProgressCallback& progress = {});

// Channel letter ("R", "G", "B").
std::string channelName(int channel);

}  // namespace crfcal
