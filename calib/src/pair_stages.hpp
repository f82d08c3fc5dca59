#pragma once
// The stages of calibratePair (pair_calibration.cpp), each a function over one private state. In order:
//   checks           pair_stage_checks.cpp   sizes, depths, orientation; saturated frames; no edges
//   align            pair_stage_align.cpp    registration (seed Sec. 4 "we first align"), the blurred shot warped into
//                                            the sharp frame, the same-scene test, the kernel's tiles and canvas
//   kernel           pair_stage_kernel.cpp   first kernel (Eq. 4 in the histogram-matched intensity domain) and the
//                                            kernel-aware registration refinement
//   fit window       pair_stage_fit.cpp      the window handed to the φ fit (Eq. 21–25) and the per-channel fit
//   kernel↔φ rounds  pair_stage_rounds.cpp   φ_G, the small-blur hold of r, K re-estimated in the irradiance domain
//   effects          pair_stage_effects.cpp  named effects on the residuals (effects.hpp)
//   ratio evidence   pair_stage_ratio.cpp    the images' r combined with EXIF / --ratio (ratio_evidence.hpp)
//   verdict          pair_stage_verdict.cpp  Γ map (Sec. 3), weights, warnings and the data's covered range
//   band             pair_stage_band.cpp     the pointwise band of φ (curve_band.hpp) over the covered range
// Internal to calib (not installed). Everything works in the SHARP frame: the smooth blurred shot is resampled,
// the noisy sharp shot never is (registration.hpp, warpToSharp).
#include <chrono>
#include <map>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/pair_calibration.hpp"

namespace crfcal::detail {

using Clock = std::chrono::steady_clock;
inline double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

// The kernel's working set: the edge-rich tiles (each grown by the kernel's reach) side by side in one small
// mosaic, so that denoising, tone matching and the φ transforms of every round touch a few megapixels, not the
// whole 24 MP frame. A one-pixel unusable gutter separates the crops (no equation straddles two of them). Small
// frames (one region) use the frame itself.
struct Canvas {
  cv::Mat sharp, sharp_denoised, blurred, usable;  // CV_64F in [0,1] (usable CV_8U)
  std::vector<cv::Rect> regions;                   // the tiles in canvas coordinates
};

// pair_canvas.cpp: the canvas of `tiles` (full-frame 8/16-bit planes in the sharp frame), crops grown by `margin`.
Canvas makeCanvas(const cv::Mat& sharp8, const cv::Mat& blurred8, const cv::Mat& usable, const std::vector<Tile>& tiles,
                  int margin);

struct PairCalibrationState {
  explicit PairCalibrationState(const PairCalibrationOptions& o) : options(o), kernel_options(o.kernel) {}
  const PairCalibrationOptions& options;
  // options.kernel, its kernel_size grown when the first estimate reached it (PairCalibrationOptions::
  // max_kernel_size): what every later kernel estimate and the canvas's margin use.
  KernelEstimationOptions kernel_options;
  PairCalibrationResult result;  // filled stage by stage; returned at the end

  // Forwards to options.progress (if any).
  void report(const std::string& stage, double fraction, const std::string& detail = {}) const {
    if (options.progress) options.progress(stage, fraction, detail);
  }

  // checks / orientation
  cv::Mat sharp, blurred;        // the shots; the sharp one turned to the blurred one's orientation if needed
  bool registered = false;       // registration already done while finding the orientation
  double same_scene_correlation = 1;  // sameSceneCorrelation of the registered pair (align stage)
  Clock::time_point register_start = Clock::now();  // the "register" timing runs from here

  // Full-frame planes in the images' own 8/16-bit depth (masks, tiles, warps); only the kernel's tiles and the
  // fit window are converted to floating point.
  std::vector<cv::Mat> sharp_planes, blurred_planes;  // BGR order (one plane for grey)
  cv::Mat sharp_g8, blurred_own_g8;                   // G planes; the blurred one in its own frame
  double clip_high = 0, clip_low = 0;                 // fit.saturation_high/low in the images' codes
  cv::Mat sharp_clipped;                              // I's clipped regions (CV_8U), highlights and black
  cv::Mat sharp_black;                                // I's black regions (CV_8U), part of sharp_clipped
  // The kernel's usable pixels keep I's black (the retry of a failed kernel estimate:
  // estimateFirstKernelAdmittingBlack).
  bool kernel_admits_sharp_black = false;
  // The first kernel may grow past options.kernel.kernel_size (estimateFirstKernelAdmittingBlack: after the retry with
  // the sharp shot's black admitted).
  bool kernel_may_grow = false;

  // align: everything that depends on the alignment (re-done after the kernel-aware refinement)
  cv::Mat blurred_g8;  // B's G plane resampled into the sharp frame
  cv::Mat overlap;     // CV_8U, sharp-frame pixels the blurred shot covers
  cv::Mat usable;      // CV_8U, overlap minus (dilated) clipped pixels of either shot
  Canvas canvas;

  // kernel
  cv::Mat kernel;  // K, the current kernel (result.kernel.kernel once estimated)

  // chroma: per channel, the bound of the error a subsampled JPEG's chroma put into the sharp shot's decoded values
  // (chromaErrorBound; only R and B of a subsampled colour shot), in the sharp frame
  std::map<std::string, cv::Mat> sharp_chroma_error;
  // The same bound for the channels the pointwise model fits from a subsampled sharp shot: the chroma check's fits
  // (checkPointwiseChroma) use it; the reported fits do not.
  std::map<std::string, cv::Mat> sharp_chroma_check_error;

  // fit window: both shots inside result.fit_window, per channel, in the images' depth (0 outside the overlap)
  std::map<std::string, cv::Mat> window_sharp, window_blurred, window_sharp_error, window_sharp_check_error;
  // checkPointwiseChroma: per pointwise channel of a subsampled sharp shot; read by computeVerdict.
  struct ChromaCheck {
    double shape_difference = -1;  // shape RMSE, reported fit vs its fit where the sharp chroma is flat (< 0: failed)
    int pixels_left_out = 0;       // how many pixels that fit left out
    double scale = 0;              // best factor a: flat-chroma fit ≈ a · reported fit (0: not measured)
    double ambiguity_rise = 0;     // the flat-chroma fit's CrfFitResult::ambiguity_rise
    bool replaced = false;         // the flat-chroma fit is reported (options.replace_chroma_biased_fits)
    std::string not_replaced;      // why a flat-chroma fit beyond the difference and above was not (verdict text)
  };
  std::map<std::string, ChromaCheck> chroma_check;
  // The pointwise fits of the channels that kept the chroma model (fitChannels' choice): the effect diagnostics see
  // these, so that their decisions — and G — are those of the pointwise model.
  std::map<std::string, CrfFitResult> pointwise_fits;

  // rounds
  CrfFitOptions fit_options;      // options.fit; fit_ratio cleared when the small-blur hold applies
  double first_blur_radius = 0;   // kernelRmsRadius of the first kernel (the hold's criterion)
};

// The plane of channel `name` ("R", "G", "B") in BGR-ordered `planes` (grey: the only plane).
const cv::Mat& channelPlane(const std::vector<cv::Mat>& planes, const std::string& name);

// ---- checks (pair_stage_checks.cpp)
// Sizes, bit depths, channels; true when the frames are transposed (portrait vs landscape). Throws InvalidInput.
bool checkPairShapes(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options);
// Channels, planes and clip levels of state.sharp / state.blurred.
void splitPlanes(PairCalibrationState& state);
// Saturated frames and an edgeless sharp shot. Throws InvalidInput (subject: the image at fault).
void checkExposureAndEdges(const PairCalibrationState& state);

// ---- align (pair_stage_align.cpp)
// The sharp shot turned by the ±90° that registers onto the blurred one (sets state.sharp, registered).
void turnSharpShot(PairCalibrationState& state, const cv::Mat& sharp_in);
// Registration (unless done while turning), then the alignment, the same-scene test and the kernel's tiles.
void registerShots(PairCalibrationState& state);
// The blurred shot warped into the sharp frame and the overlap, then the usable pixels, tiles and canvas.
void alignToRegistration(PairCalibrationState& state);
// The kernel's usable pixels (the overlap, unclipped in both shots), its edge-rich tiles and their canvas, whose
// margin is the kernel's size (state.kernel_options).
void selectKernelTiles(PairCalibrationState& state);
// Normalised cross-correlation of the two shots' coarse gradient magnitudes over the overlap, in [-1, 1]: near 1
// for one scene (whatever the exposure, tone curve and blur), near 0 for two unrelated scenes.
double sameSceneCorrelation(const cv::Mat& sharp_g, const cv::Mat& blurred_g_in_sharp, const cv::Mat& overlap);
// Below this the pair is refused as two different scenes at once. Measured (docs/RESULTS.md, "two different
// scenes"): unrelated pairs that register 0.08 at most; real and semi-real pairs 0.67 and more with Levin kernels
// 1, 3, 8, but 0.28 for a semi-real pair with the long straight Levin kernel 4 (a linear blur wipes the edges along
// it, which no isotropic smoothing of the sharp shot reproduces) and 0.25–0.26 for two planted signal-dependent-noise
// pairs of `bench effects` — so the floor stays well below those.
constexpr double min_same_scene_correlation = 0.15;
// Between the floor and this, a pair is only doubtful: when a later stage fails (the kernel grows to its size
// limit, no edges), the failure is reported as two different scenes with the stage's own reason.
constexpr double doubtful_same_scene_correlation = 0.5;

// ---- kernel (pair_stage_kernel.cpp)
// Monotone map of `source` values (CV_64F in [0,1]) so that their histogram inside `mask` matches `target`'s.
cv::Mat histogramMatch(const cv::Mat& source, const cv::Mat& target, const cv::Mat& mask);
// The first kernel (or the given one) with the kernel-aware registration refinement; sets state.kernel.
void estimateFirstKernel(PairCalibrationState& state);
// estimateFirstKernel at the size given; when it fails (no usable windows, or the kernel at its size limit) and the
// sharp shot has black areas, made again with them admitted to the kernel's usable pixels (the estimate works on
// gradients: a black region is flat and dropped by the estimator's texture test, an edge into black loses only the
// black threshold of its step), and result.kernel_sharp_black_admitted set; when that fails too (or there is no
// black), made again with the kernel allowed to grow (state.kernel_may_grow; result.kernel_grown_to), from the
// registration the failed attempts left and then from the first attempt's. A pair that runs at the size given without
// its black is unchanged. When the retries fail, throws the growth's first failure (the first attempt's when nothing
// grew) with the first attempt's usablePixelsNote.
void estimateFirstKernelAdmittingBlack(PairCalibrationState& state);
// Where the kernel's pixels went, for a failed estimate's message: the share of the overlap that is usable and
// what removed the rest (the sharp shot's black, either shot's clipped highlights), e.g. "usable: 18 % of the
// overlap; the sharp shot is black over 66 %, clipped over 1 %, the blurred one clipped over 9 %" (and, black over
// half of it or more, that a brighter short exposure would leave more).
std::string usablePixelsNote(const PairCalibrationState& state);
// The largest size the first kernel may grow to (PairCalibrationOptions::max_kernel_size; 0, automatic: a quarter of
// the sharp shot's shorter side, odd, at most kAutomaticLargestKernel, never below the size it starts at).
// Measured: a 119 px kernel on an 800 px frame took 17 min (the kernel <-> phi rounds), a 79 px one 4 min at most.
constexpr int kAutomaticLargestKernel = 79;
int largestKernelSize(const PairCalibrationState& state);
// One kernel estimate on the canvas (s, b: canvas images); per_tile: also the tiles' own kernels.
KernelEstimate estimateCanvasKernel(PairCalibrationState& state, const cv::Mat& s, const cv::Mat& b, bool per_tile,
                                    double lambda, const cv::Mat& weights);

// ---- fit window (pair_stage_fit.cpp)
void chooseFitWindow(PairCalibrationState& state);
// The sharp shot's chroma error bound per fitted channel (R, B) when its JPEG chroma is subsampled; `sharp_in` is the shot
// as given (its blocks are aligned with its own origin), turned like state.sharp. After the orientation is known.
void markChromaDetail(PairCalibrationState& state, const cv::Mat& sharp_in);
// The chroma check of the verdict: each R or B fitted pointwise from a sharp shot whose JPEG chroma is subsampled is
// fitted once more where that shot's chroma is flat (its error bound, as --chroma-model auto does), and the two fits'
// shape difference and scale over the range both cover are recorded (state.chroma_check); a fit biased by the lost
// chroma is replaced (options.replace_chroma_biased_fits). After the final fits, before the summaries and bands.
void checkPointwiseChroma(PairCalibrationState& state);
// φ of channel `name` on the fit window with `kernel` (state.fit_options).
CrfFitResult fitChannel(const PairCalibrationState& state, const std::string& name, const cv::Mat& kernel);
// fitChannel for several channels at once, one per core (the fits are independent; each splits its sums into as
// many stripes as OpenCV has threads whether it runs beside the others or alone, so the results equal a serial
// loop's at the same thread count). A channel fitted with the chroma model (a subsampled sharp
// JPEG) that leaves too few pixels falls back to the pointwise model; `fallback_warnings` then gets a line (the
// rounds stage reports it, the ratio stage does not repeat it). Any other failure is rethrown, in channel order.
// choose_chroma_model (the rounds stage, with options.chroma_choice enabled): a modelled channel is also fitted
// pointwise, in the same parallel batch, and keeps the model only if ChromaModelChoice says so; otherwise its bound
// is dropped (later refits use the pointwise model too). The scale is recorded in result.chroma_model_scale.
std::map<std::string, CrfFitResult> fitChannels(PairCalibrationState& state, const std::vector<std::string>& names,
                                                const cv::Mat& kernel, bool fallback_warnings,
                                                bool choose_chroma_model = false);

// ---- kernel↔φ rounds (pair_stage_rounds.cpp)
void fitKernelPhiRounds(PairCalibrationState& state);

// ---- ratio evidence (pair_stage_ratio.cpp): r combined with the nominal ratio; all channels refitted when it moves
void combineRatioWithNominal(PairCalibrationState& state);

// ---- effects (pair_stage_effects.cpp)
void diagnoseResidualEffects(PairCalibrationState& state);

// ---- verdict (pair_stage_verdict.cpp): the fits' diagnostic maps, warnings and covered ranges (before the band,
// which is built over those ranges), then the verdict per channel (after it: the band's width is one of its grounds)
void summariseFits(PairCalibrationState& state);
void computeVerdict(PairCalibrationState& state);
// The shots' brightness ratio in channel `name` over the fit window (quantile matching with the EMoR mean curve, as
// `crfcal study ratio`); 0 when too few usable levels.
double brightnessRatio(const PairCalibrationState& state, const std::string& name);

// ---- band (pair_stage_band.cpp): the pointwise band of φ per channel over its covered range (curve_band.hpp)
void estimateBands(PairCalibrationState& state);

}  // namespace crfcal::detail
