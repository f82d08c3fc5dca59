#pragma once
// Static multi-exposure calibration of any scene (`crfcal bracket`): the method of Debevec & Malik 1997, Mitsunaga &
// Nayar 1999 and Robertson et al. 2003 (the seed's [1]) — the same scene at several exposures t_j, each scene point p
// with one unknown irradiance E_p, z_pj = f(E_p t_j) — fitted with crfcal's own model and fitter.
//
// Model. φ(z_pj) = E_p · t_j, φ = f⁻¹ the EMoR inverse model (Grossberg & Nayar 2004; φ(0) = 0, φ(1) = 1,
// monotone). Written as t_j = s_p · φ(z_pj) with s_p = 1/E_p, this is exactly the chart fit of
// chart_calibration.hpp (reference y = s_g φ(x), one unknown scale per group) with one group per scene point and the
// frames' relative exposures as the reference: fitScaledInverse with profiled scales (variable projection) does it.
//
// Exposures. The relative exposures ISO·t/N² from EXIF are the start; the darkest and the brightest frame stay at
// their EXIF ratio (the span), which fixes the exponential ambiguity φ^γ, t^γ (Grossberg & Nayar 2003); the frames
// between are refined (each the median of φ(z_pj)/(E_p t_j) over its points, within ±max_exposure_deviation stops)
// and φ refitted. Without EXIF the start comes from the images (consecutive frames' ratio through the EMoR mean
// curve, estimateExposureRatio) and the warning says so: the curve's overall exponent then rests on that estimate.
//
// Frames. Handheld frames are registered onto the middle exposure (registration.hpp; the histogram equalisation
// there removes the exposure difference), translation first (phase correlation + ECC; AKAZE features only for a frame
// that path does not settle); a frame that does not register is refused (not the same scene).
// Samples. Scene points on flat areas (the largest local standard deviation over the frames is among the lowest of
// their brightness class), spread over the brightness range; a point's value is the local mean of each channel;
// values near 0 (noise floor) or at the channel's clipping limit (measured from the frames where they show a
// plateau) are not data, nor are points of a vivid colour (max_saturation). Cross-validation folds are alternate brightness classes (a flat region's points are near copies).
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/registration.hpp"

namespace crfcal {

// One frame of the bracket: an image (8/16-bit or float in [0,1], grey or BGR) and its relative exposure.
struct BracketFrame {
  std::string name;     // for messages (e.g. the file)
  cv::Mat image;
  double exposure = 0;  // relative exposure ISO·t/N² (any common unit); 0 = unknown (then all are estimated)
};

struct BracketSamplingOptions {
  int points = 700;              // scene points drawn (Debevec & Malik: N(P−1) > Zmax − Zmin; 700 ≫ 256/(P−1))
  int brightness_classes = 48;   // points are spread evenly over this many classes of scene brightness
  int window = 7;                // side (pixels, odd) of the square a point's value is averaged over
  // Of each brightness class, only the flattest fraction of candidates is drawn. A point's value is the mean of its
  // window, and mean f(E) ≠ f(mean E) where the window holds texture (Jensen): a bias shared by every point of a
  // textured scene, which more points do not average away. 0.08 chosen on the "choose" cameras of `crfcal bench
  // bracket` and `crfcal bench references` against 0.3 and 0.15 (semi-real RGB 0.0064 / 0.0047 / 0.0033, Middlebury
  // 0.0040 / 0.0040 / 0.0041; docs/RESULTS.md#reference-bands).
  double flat_fraction = 0.08;
  int candidates = 60000;        // candidate positions on a regular grid of the reference frame
  double low = 0.02;             // a channel value below this (unit scale) is the noise floor: not data
  // A channel value at or above this is clipped, not data — unless the frames show the channel's clipping plateau
  // lower (values that stop rising with the exposure; the limit is then just below it): cameras clip at different
  // codes. 0.97 before issue 21's fourth round (= `high`), which dropped the unclipped top of the channel that
  // renders brightest (JPEG blue of a white patch) so its shoulder was extrapolated (docs/RESULTS.md#bracket).
  double top = 0.99;
  double plateau_floor = 0.9;    // values above this that a brighter frame does not exceed are the plateau
  // A grey (channel mean) at or above this is too near clipping to judge a candidate's flatness or a point's colour
  // there; observations are weighted down over the last 0.1 below it (a channel about to clip bends).
  double high = 0.97;
  // A scene point is data only while its colour is at most this saturated, (max − min)/max over R, G, B in its
  // brightest unclipped frame: cameras render vivid colours through gamut mapping / saturation that no per-channel
  // curve describes. 1: every colour. Chosen on the "choose" cameras of `crfcal bench references`
  // (docs/RESULTS.md#bracket).
  double max_saturation = 0.3;
  int margin = 8;                // pixels kept away from the frame and the registered overlap's border
  std::uint64_t seed = 1;        // deterministic draw
  void check() const;            // throws InvalidInput
};

struct BracketCalibrationOptions {
  bool register_frames = true;   // false: the frames are already aligned (tripod); sizes must agree
  // Frames whose longest side exceeds this are reduced to it first (area averaging, like the local means the samples
  // are anyway): the curve needs a few hundred flat points, not megapixels; 6 MP frames took 20 s to register and
  // sample at full size. 0: full size.
  int max_dimension = 1024;
  // Translation first (phase correlation + ECC; AKAZE only for frames it does not settle): a bracket is usually shot
  // from a tripod or a steady hand, and the features were ¾ of the registration's cost.
  RegistrationOptions registration = [] {
    RegistrationOptions r;
    r.translation_first = true;
    return r;
  }();
  BracketSamplingOptions sampling;
  // The EMoR fit (chart_calibration.hpp). K by 2-fold cross-validation over scene points up to max_terms; the scales
  // (one per point) are profiled out.
  ScaledFitOptions fit = [] {
    ScaledFitOptions f;
    f.max_terms = 6;
    f.profile_scales = true;
    f.monotone_grid = 256;  // φ' ≥ 0 between 256 nodes (the table is made exactly monotone afterwards)
    f.max_evaluations = 400;
    // The chart's penalties (0.01, 1e-4) were set against 24 patches; a bracket gives thousands of samples over
    // nearly the whole range, where they only bend the curve: on the Canon 5D frames they moved φ(0.5)/φ(0.8) by
    // 15 % away from Debevec's. 100× lower keeps the ends tame at no cost on synthetic brackets.
    f.smoothness = 1e-4;
    f.exponent_smoothness = 1e-6;
    return f;
  }();
  // Each frame's Spearman rank correlation with its neighbour in brightness (registered, over the pixels both expose
  // well) must reach this: the frames of one scene are related by a monotone map (≈ 0.95–1 with JPEG noise),
  // another scene gives ≈ 0 even when the registration reports success.
  double min_scene_correlation = 0.6;
  int exposure_rounds = 1;             // refinements of the inner frames' exposures (each followed by a refit)
  double max_exposure_deviation = 1;   // stops a refined exposure may move away from its start
  ggcm::FitOptions ggcm;               // the EMoR result converted to GGCM (seed Eq. 19) for the report's models
  // The pointwise band of each channel's φ (scaled_fit_band.hpp): refits on halves of the scene points with K and
  // the exposures held, then curve_band.hpp's bounds beyond the covered range. replicates = 0: no band. The refits
  // fit only the K the full fit chose, so no model term (include_model_spread has no alternative to add).
  CurveBandOptions band;
  std::vector<int> channels{0, 1, 2};  // R, G, B (grey frames: channel 1 only)
  void check() const;                  // throws InvalidInput
};

struct BracketChannelResult {
  int channel = 0;
  ScaledFitResult fit;   // φ (fit.inverse), K, covered range, residuals in exposure units
  GgcmModel ggcm;
  double ggcm_rmse = 0;  // RMSE between the GGCM and the EMoR curve
  bool ggcm_valid = true;
  int points = 0;        // scene points with ≥ 2 usable observations in this channel
  CurveBand band;        // empty when options.band.replicates = 0 or too few scene points to halve
};

struct BracketFrameResult {
  std::string name;
  double nominal_exposure = 0;  // as given (0 = unknown)
  double start_exposure = 0;    // relative to the reference frame: EXIF ratio, or estimated from the images
  double fitted_exposure = 0;   // relative to the reference frame, after refinement
  bool reference = false;       // the frame the others are registered onto
  double scene_correlation = 0; // rank correlation with its neighbour in brightness (NaN: too few common pixels)
  RegistrationResult registration;  // frame → reference (identity for the reference or without registration)
};

struct BracketCalibrationResult {
  std::vector<BracketChannelResult> channels;
  std::vector<BracketFrameResult> frames;  // input order
  std::string exposure_source;             // "exif" or "images"
  int points = 0;                          // scene points drawn
  std::vector<cv::Point> point_positions;  // in the reference frame, full-size pixels (for the figure)
  std::vector<std::string> warnings;
  std::string summary() const;
};

using BracketProgress = std::function<void(const std::string& stage, double fraction, const std::string& detail)>;

// Throws InvalidInput (subject pair, file = the frame's name) for fewer than 2 frames, frames that are not the same
// scene, exposures given for some frames only, or too few usable samples.
BracketCalibrationResult calibrateBracket(const std::vector<BracketFrame>& frames,
                                          const BracketCalibrationOptions& options = {},
                                          const BracketProgress& progress = {});

}  // namespace crfcal
