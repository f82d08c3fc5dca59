#pragma once
// The whole dual-image calibration of Sec. 4 on a real (handheld) pair, as named stages (docs/ARCHITECTURE.md):
//   checks (sizes, saturated frames, edges) → align: registration (registration.hpp; the blurred shot is resampled
//   into the sharp frame, the noisy sharp shot is never resampled), the test that both shots show one scene,
//   edge-rich tiles (tile_selection.hpp) → kernel: estimation (kernel_estimation.hpp) in an approximately linear
//   domain (the sharp image's histogram matched to the blurred one's: a monotone map that removes most of the
//   exposure and tone difference), kernel-aware registration refinement (ECC of I ⊗ K against B) and the kernel
//   again → fit window → φ fit per channel (crf_fitter.hpp, Eq. 21–25) and `rounds` × { kernel re-estimated in the
//   irradiance domain φ(I), φ(B) with the current φ_G; φ refitted } with the change per round reported → effects
//   (effects.hpp) → verdict (Γ map, warnings, covered range, the verdict per channel: channel_verdict.hpp).
// Pure computation: images in, curves/kernel/diagnostics out; progress through a callback.
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/channel_verdict.hpp"
#include "crfcal/chroma_subsampling.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/ratio_evidence.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/kernel_estimation.hpp"
#include "crfcal/registration.hpp"
#include "crfcal/tile_selection.hpp"

namespace crfcal {

struct PairCalibrationOptions {
  RegistrationOptions registration;
  KernelEstimationOptions kernel;
  // A first kernel estimate that fails at kernel.kernel_size is tried with the sharp shot's black admitted, then made
  // again 1.5× larger (odd) while it reaches its size limit, up to this size: a long handheld exposure can blur by
  // more than the default 35 px, and the estimate itself shows when it does (its mass on the border). 0: automatic, a
  // quarter of the sharp shot's shorter side, at most 79 (a 119 px kernel took 17 min on an 800 px frame). Equal to
  // kernel.kernel_size: no growth. A grown kernel makes the verdict at most weak (docs/RESULTS.md#kernel-growth).
  int max_kernel_size = 0;
  TileSelectionOptions tiles;
  CrfFitOptions fit;                 // nominal_ratio = the EXIF ratio (footnote 4) or --ratio
  bool register_pair = true;         // false: the pair is already aligned
  bool refine_registration = true;   // kernel-aware refinement (ECC of I ⊗ K against B) after the first kernel
  cv::Mat given_kernel;              // non-empty: skip estimation (--kernel FILE)
  bool rgb = true;                   // fit R, G, B (else G only; grey input is always one channel "G")
  int rounds = 2;                    // kernel ↔ φ rounds after the first fit (Sec. 4 iterates φ and r; we add K)
  // The irradiance-domain kernel rounds (Eq. 4 is linear there) differ from the first, intensity-domain estimate:
  //  * each gradient equation is weighted by 1/φ'(B), so that residuals count in the intensity units the errors are
  //    made in; unweighted, the bright edges (a convex φ is steepest there) dominate with their amplified JPEG and
  //    chroma errors and bias the kernel, hence r;
  //  * a weaker sparsity prior (kernel.lambda is for the first estimate, where the histogram-matched model is only
  //    approximate and a strong prior keeps spurious mass out — an underexposed phone shot hits the size limit at
  //    0.01): with the re-weighting a small entry pays ~9× λ, which cuts the faint arms of real handheld kernels.
  // Both choices are measured by `crfcal bench pairs --ratio 2` (docs/RESULTS.md, "kernel rounds").
  // false: the rounds unweighted.
  bool weight_irradiance_kernel = true;
  double irradiance_kernel_lambda = 0.01;
  double saturated_frame_limit = 0.6;  // more than this fraction of an image clipped: "saturated frame"
  // Kernel RMS radius (kernelRmsRadius) below which the blur cannot determine r: with almost no blur the pair is a
  // plain two-exposure pair, for which φ^γ with r^γ fits as well as φ with r (the exponential ambiguity), and the
  // noise of the sharp shot (Jensen's bias) tilts the fit towards a low r (docs/RESULTS.md, "small blurs").
  double min_blur_radius = 1.0;
  // Below min_blur_radius (measured on the first kernel), if the first fit's r disagrees with fit.nominal_ratio
  // (EXIF or --ratio) by more than small_blur_ratio_tolerance, r is held at fit.nominal_ratio and a warning says
  // so. Along the ambiguity log r moves by γ·log r, so near r = 1 the images still give r from brightness and agree
  // with EXIF; at larger r they drift and the hold helps (docs/RESULTS.md, "small blurs").
  // false: r is fitted anyway (only warned).
  bool fix_ratio_when_blur_is_small = true;
  // The small-blur hold's tolerance on |r_images / r_EXIF − 1|: the tolerance of nominal EXIF values (rounded
  // shutter times, ISOs and apertures); the same 10 % as effects.ratio_tolerance, set separately.
  double small_blur_ratio_tolerance = 0.10;
  double min_covered_span = 0.5;     // intensity span covered by a channel's data below this: warn (extrapolation)
  // The sharp shot's JPEG chroma sampling (`calibrate --chroma-model auto` reads it from the file; default 1×1: the
  // pointwise model). Subsampled: R and B are fitted only where the sharp shot's lost chroma detail is small
  // (chroma_subsampling.hpp, issue 20); G, carried by luma, keeps today's model. The blurred shot's chroma needs
  // nothing: its blur removed the detail the blocks lose. Measured (docs/RESULTS.md#chroma-choice, with chroma_choice):
  // demo pair B 0.133 → 0.024; 27 semi-real pairs at r = 1 R 0.0202 → 0.0143, B 0.0676 → 0.0253, but at r = 4
  // B 0.0143 → 0.0168 and at 4:2:2 one scene worse, hence opt-in (the default is replace_chroma_biased_fits).
  ChromaSubsampling sharp_chroma;
  ChromaDetailOptions chroma_detail;
  // With sharp_chroma subsampled: R and B are fitted both ways and keep the chroma model only where its fit lies
  // above the pointwise one (chroma_subsampling.hpp ChromaModelChoice; measured: docs/RESULTS.md#chroma-choice).
  ChromaModelChoice chroma_choice;
  // The sharp shot's chroma sampling as its file stores it, whatever the model (for the chroma check and the verdict
  // of R and B fitted by the pointwise model from a subsampled sharp shot). 1×1: full resolution or not a JPEG.
  ChromaSubsampling sharp_stored_chroma;
  // The chroma check (after the final fits, each pointwise R or B of a subsampled sharp shot fitted once more where
  // that shot's chroma is flat): true replaces the reported fit by that one where the two differ in shape by more
  // than verdict.max_chroma_shape_difference and it lies above (the sign of the bias the lost chroma puts in,
  // ChromaModelChoice) — unless an effect's extended model supplied φ. false: the check only informs the verdict.
  // Measured (docs/RESULTS.md#chroma-replace): 27 semi-real pairs at r = 1 B 0.0717 → 0.0298, r = 4 and 8 unchanged.
  bool replace_chroma_biased_fits = true;
  // ... provided the flat-chroma fit fixes the curve's exponent by itself: its CrfFitResult::ambiguity_rise (the
  // data energy's relative rise at φ^γ, r^γ, γ = 1 ± 0.1) at least this. Leaving out the edges whose chroma varies
  // can leave too little to do so; that fit then drifts along φ^γ (measured: 4:2:2 pairs whose flat fit rose
  // 0.030–0.055 came out 1.1–4× worse than their pointwise fit). Chosen on the IMG_2601 scene of `bench pairs`
  // (worse replacements ≤ 0.055, better ones ≥ 0.105), reported on its two other scenes
  // (docs/RESULTS.md#chroma-replace).
  double chroma_replacement_min_ambiguity_rise = 0.075;
  int max_fit_side = 1024;           // the fit sees at most this window around the best tile (speed on 24 MP)
  CurveBandOptions band;             // the pointwise band of φ per channel (curve_band.hpp); replicates = 0: none
  EffectOptions effects;             // residual diagnostics after the fit (effects.hpp); detected → φ from the extended model
  VerdictOptions verdict;            // the per-channel verdict's thresholds (channel_verdict.hpp)
  // r from the images combined with the nominal ratio by their precisions (ratio_evidence.hpp), after the
  // kernel↔φ rounds; enabled = false: r from the images alone.
  RatioEvidenceOptions ratio_evidence;
  std::string nominal_ratio_name = "EXIF";  // how the verdict's reasons name fit.nominal_ratio ("EXIF", "--ratio")
  // Keep the fit's inputs in the result (PairCalibrationResult::fit_inputs: the fit window of both shots per
  // channel, the final kernel, the fit's options) for a joint fit of several pairs (joint_calibration.hpp).
  // false: not kept (a few MB per pair).
  bool keep_fit_inputs = false;
  std::function<void(const std::string& stage, double fraction, const std::string& detail)> progress;
  void check() const;                // throws InvalidInput
};

struct CalibrationRound {
  int round = 0;               // 0: intensity-domain kernel; ≥ 1: irradiance-domain kernel
  double kernel_change = 0;    // ‖K_round − K_previous‖₂ / ‖K_previous‖₂ (0 for round 0)
  double phi_change = 0;       // RMSE of φ_G against the previous round (0 for round 0)
  double ratio = 1;            // fitted r of G
  double kernel_residual = 0;  // relative gradient-domain residual of the kernel fit
};

// What the φ fit of each channel saw (PairCalibrationOptions::keep_fit_inputs): enough to refit the pair's data,
// alone or jointly with other pairs of the same camera (joint_calibration.hpp).
struct PairFitInputs {
  std::map<std::string, cv::Mat> sharp, blurred;  // per channel: both shots in the fit window (0 outside the overlap)
  std::map<std::string, cv::Mat> sharp_error;     // per channel: the chroma error bound (subsampled JPEG only)
  cv::Mat kernel;                                 // the final kernel, cropped as the fitter gets it
  CrfFitOptions options;                          // the fit's options (r's hold and the noise handling included)
  bool empty() const { return sharp.empty(); }
};

// A kernel estimated on one of PairCalibrationResult::tiles alone: the blur there (spatial variation; `deblur --from`
// deblurs each part of the image with the nearest one).
struct TileKernel {
  int tile = 0;    // index into PairCalibrationResult::tiles (a tile without usable edges has no kernel)
  cv::Mat kernel;  // CV_64F, sums to 1
};

struct PairCalibrationResult {
  RegistrationResult registration;
  double sharp_rotation_deg = 0;         // ±90: the sharp shot was framed in the other orientation and turned
  KernelEstimate kernel;                 // final kernel (given kernels: kernel set, other fields default)
  bool kernel_estimated = true;
  std::vector<Tile> tiles;
  std::vector<TileKernel> tile_kernels;  // the last kernel round's, per tile with usable edges, when more than one tile
  KernelDisagreement disagreement;
  std::vector<std::string> channels;     // "R","G","B" or "G"
  // Channels fitted only where the sharp shot's subsampled chroma is flat (options.sharp_chroma, or reported so by the
  // chroma check: options.replace_chroma_biased_fits; issue 20)
  std::vector<std::string> chroma_model_channels;
  // With options.chroma_choice: per subsampled channel the best scale of the chroma model's fit against the pointwise
  // one over their common range (kept the chroma model iff above chroma_choice.min_relative_scale). Empty: no choice.
  std::map<std::string, double> chroma_model_scale;
  std::map<std::string, CrfFitResult> fits;
  std::vector<CalibrationRound> rounds;
  double blur_radius = 0;                // RMS radius of the final kernel about its centroid, pixels
  // > 0: the kernel estimate failed with the sharp shot's black areas left out (no usable windows in a night scene of
  // the real regime, or the kernel at its size limit) and was made again with them admitted; the black share of the
  // overlap. The verdict is then at
  // most weak (an edge into black loses its dark side: measured on night pairs, docs/RESULTS.md#sharp-black-admitted).
  double kernel_sharp_black_admitted = 0;
  // > 0: the first kernel estimate reached its size limit (options.kernel.kernel_size) and was made again larger
  // (PairCalibrationOptions::max_kernel_size); the size it was estimated at. The verdict is then at most weak
  // (measured on large real-regime blurs: most such pairs' r off by more than 5 %, docs/RESULTS.md#kernel-growth).
  int kernel_grown_to = 0;
  bool ratio_fixed_by_small_blur = false;  // r held at EXIF/--ratio (fix_ratio_when_blur_is_small)
  double ratio_images_small_blur = 0;      // then: the r of the first, free fit that disagreed
  // r from the images and the nominal ratio combined (options.ratio_evidence); ratio_from_evidence: the fits were
  // redone with r held at evidence.ratio (it moved r by more than min_relative_change).
  RatioEvidence ratio_evidence;
  bool ratio_from_evidence = false;
  std::map<std::string, std::pair<double, double>> covered_range;  // per channel: intensities the data constrain
  cv::Rect fit_window;                   // region handed to the fitter (full-resolution coordinates)
  cv::Mat gamma_map;                     // Γ = B − I ⊗ K on G inside fit_window (CV_64F)
  cv::Mat weights;                       // CV_8U, pixels used by the G fit inside fit_window
  std::map<std::string, double> timings; // seconds per stage
  std::vector<std::string> warnings;
  EffectReport effects;                  // named effects tested on the residuals (effects.hpp)
  std::map<std::string, CurveBand> bands;  // per channel with a covered range (options.band; empty when off)
  std::map<std::string, CrfFitResult> base_fits;  // the fits before an effect's extended model replaced them
  // Per channel: the shots' brightness ratio (quantile matching with the EMoR mean curve, as `study ratio`; absent
  // when too few usable levels) and
  // the verdict (channel_verdict.hpp).
  std::map<std::string, double> brightness_ratio;
  std::map<std::string, ChannelVerdict> verdicts;
  PairFitInputs fit_inputs;  // empty unless options.keep_fit_inputs
  std::string summary() const;
  // The centre of tile kernel `t`'s tile in the blurred shot's pixels (the tiles are in the sharp shot's frame; the
  // registration's homography maps it).
  cv::Point2d tileCentreInBlurred(const TileKernel& t) const;
};

// sharp / blurred: the two shots (grey or BGR, CV_8U or CV_16U, same depth and channels; the same size, or
// transposed sizes — portrait vs landscape — in which case the sharp shot is turned by the ±90° that registers).
// All outputs (gamma map, weights, kernel) are in the (turned) sharp frame. Throws InvalidInput with a one-line
// reason for saturated frames, a non-overlapping pair, two different scenes, an edgeless pair, a kernel at its size
// limit; its subject() (error.hpp) says whether the sharp image, the blurred image or the pair is at fault.
PairCalibrationResult calibratePair(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options);

}  // namespace crfcal
