#pragma once
// The camera's real response from a RAW and a JPEG of the SAME shot (`crfcal calibrate --raw-truth`).
//
// A RAW decoded linearly (io/raw_image.hpp: no gamma, no auto-brightness, black level subtracted) is proportional
// to irradiance, so the pixel-by-pixel relation RAW → JPEG of one shot is the camera's rendering itself: the truth
// against which a pair calibration of that camera is judged (seed Sec. 4–5 compare against a ground-truth CRF).
// Any linear image of the shot (a 16- or 8-bit linear PNG/TIFF rendering of the RAW) serves the same way.
//
// Steps:
// 1. Geometry. LibRaw's output and the camera JPEG differ in size (JPEG downscaling, sensor margins), crop and
//    possibly orientation. The linear image is scaled to the JPEG's working size (same pixel area), each
//    orientation that fits the aspect ratio is registered (registration.hpp, affine: features + RANSAC + ECC) on
//    photometrically normalised copies (rank equalisation at full precision, so a dark 16-bit linear frame keeps its
//    detail), the best-correlated one is kept and the linear image is resampled into the JPEG frame.
// 2. Low-pass both (area downscaling to ≤ max_dimension, then a Gaussian of σ = smoothing_sigma px): demosaicing
//    and JPEG block artefacts, in-camera sharpening and residual misregistration average out.
// 3. Keep locally flat pixels: the JPEG's gradient magnitude, maximised over a (2·flat_radius+1)² window, below its
//    own flat_quantile over the overlap (self-scaling: no absolute threshold). Near edges a fraction of a pixel of
//    misregistration or the camera's sharpening halo changes one image and not the other.
// 4. Clipping, from the images' own statistics: a channel clips where its pixels pile up at the channel's maximum
//    (≥ clip_pile of the frame within clip_tolerance of it). Censored pixels bound the curve
//    (chart_calibration.hpp ScaledObservation::Kind): JPEG clipped, RAW not → s·φ(1) ≤ y; RAW clipped, JPEG not →
//    s·φ(x) ≥ y; both → unused. A clipped pixel contaminates its low-pass neighbourhood, which is excluded too.
// 5. Colour. JPEG engines apply white balance and a 3×3 colour matrix to the linear data BEFORE the tone curve
//    (colour_mixing.hpp), so JPEG_c is a function of (M·RAW)_c, not of RAW_c: on coloured pixels the per-channel
//    relation scatters (2–6× the residual on the Middlebury charts, samples/camera_curves/PROVENANCE.md). With
//    colour_matrix the row M_c is found by alternation: fit φ_c with y = M_c·RAW; M_c ← least squares of
//    φ_c(JPEG_c) ≈ M_c·RAW over the exact pixels (ridge towards the current row along directions the pixels'
//    colours do not span). That per-channel curve after the matrix is exactly what a pair calibration measures
//    (M is linear, so it commutes with blur and the exposure ratio of Eq. 4).
// 6. Fit. Per channel and spatial fold, the pixels are binned by JPEG value (bins levels on [0,1]); a bin gives
//    one observation (x = mean JPEG value, y = median of M_c·RAW) weighted by its pixel count. φ_c = scaled EMoR
//    (fitScaledInverse: one unknown scale, monotone, censored bounds), K by cross-validation over the folds — the
//    fold_grid² spatial blocks dealt into 4 folds by (block column + 2·block row) mod 4, so a held-out fold is whole
//    regions spread over the frame. The φ ↔ M alternation uses K = 4; the final fit chooses K.
// 7. Checks (InvalidInput): the images do not register; too few flat usable pixels; the per-pixel relation explains
//    less than min_explained of the linear data's variance (a different shot); the curve's effective exponent
//    (least-squares slope of log φ against log x over the covered mid-tones and highlights) below min_gamma — the
//    "linear" image is itself tone-mapped (camera JPEGs encode linear light with an exponent ≈ 2 there, sRGB /
//    Rec. 709; a rendered image taken for linear gives ≈ 1).
// Pure computation: no file I/O, no printing.
#include <array>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/registration.hpp"

namespace crfcal {

struct RawTruthOptions {
  bool register_images = true;  // false: the two are pixel-aligned already (same size and orientation required)
  RegistrationOptions registration = [] {
    RegistrationOptions r;
    r.motion = RegistrationMotion::affine;  // LibRaw vs camera JPEG: scale and crop differ, no perspective
    return r;
  }();
  int max_dimension = 1024;       // working copies: longest side area-downscaled to this (also a low-pass)
  double smoothing_sigma = 1.0;   // Gaussian σ, working px, against demosaic/JPEG-block artefacts (step 2)
  int flat_radius = 2;            // window radius of the flatness test (step 3)
  double flat_quantile = 0.5;     // keep pixels flatter than this quantile of the JPEG's gradient magnitude
  int border = 3;                 // working px excluded along the overlap's edge (resampling, smoothing)
  double clip_pile = 1e-3;        // fraction of a channel at its maximum that makes the maximum a clip level
  double clip_tolerance = 2e-3;   // … within this fraction of full scale (and at least one code value)
  double dark_limit = 1.5 / 255;  // JPEG values below this are black-clipped (φ(0) = 0 is fixed by the model)
  int bins = 256;                 // JPEG levels per channel and fold (step 6)
  int min_bin_pixels = 5;         // a bin with fewer pixels is not an observation
  int fold_grid = 4;              // spatial blocks per side, dealt into 4 cross-validation folds
  bool colour_matrix = true;      // step 5; false: y = RAW_c (the pointwise, per-channel assumption)
  int matrix_rounds = 3;          // alternations φ ↔ M
  double matrix_ridge = 1e-3;     // ridge weight, relative to the mean squared linear value
  int max_pixels = 200000;        // per-pixel samples kept (a regular subsample beyond)
  double min_explained = 0.8;     // R² of y ≈ s·φ(x) per pixel below this: not the same shot
  // Linearity check (step 7): the effective exponent of φ over the covered range above gamma_from (measured when
  // that part spans ≥ gamma_span). Camera curves are near-linear in the darks (a toe: exponent ≈ 1 below x ≈ 0.3) and
  // steeper above: sRGB's local exponent is 2.0–2.3 on [0.3, 1]; the ten measured cameras of samples/camera_curves
  // give 1.53–1.79 on [0.3, 0.6] and 1.96–2.28 on [0.4, 0.9]. A rendered image taken for linear gives ≈ 1.
  // 1.25 ≈ √1.53 sits halfway (in log) between the two.
  double gamma_from = 0.3;
  double gamma_span = 0.25;
  double min_gamma = 1.25;
  // Channels wanted ("R", "G", "B"); a grey JPEG has only "G". Unknown names are an error.
  std::vector<std::string> channels{"R", "G", "B"};
  ScaledFitOptions fit;           // EMoR fit (chart_calibration.hpp), K by cross-validation
  void check() const;             // throws InvalidInput
};

struct RawTruthChannel {
  std::string channel;             // "R", "G", "B"
  ScaledFitResult fit;             // φ (fit.inverse at x = i/1023), K, scale, covered range, bin residuals
  std::vector<double> mix;         // the row M_c (linear planes in R, G, B order, or one plane), fit.scales absorbed
  double pixel_rmse = 0;           // per-pixel residual y/s − φ(x) of the exact pixels, φ units
  double explained = 0;            // per-pixel R² of y ≈ s·φ(x)
  double effective_gamma = 0;      // slope of log φ vs log x over the covered range above gamma_from (NaN: too dark)
  long long pixels = 0;            // exact pixels used
  long long censored_pixels = 0;   // pixels entering as bounds
  int bins = 0;                    // observations given to the fitter
};

struct RawTruthResult {
  std::vector<RawTruthChannel> channels;
  RegistrationResult registration;  // linear (scaled, turned) → JPEG, working frame
  int rotation_degrees = 0;         // clockwise turn applied to the linear image before registering
  double linear_scale = 1;          // linear image → JPEG working size
  cv::Size working_size;            // JPEG working copy
  long long overlap_pixels = 0, flat_pixels = 0;
  double flat_threshold = 0;        // gradient magnitude (JPEG units per working px) at flat_quantile
  std::map<std::string, double> jpeg_clip, linear_clip;  // per channel clip level in [0,1] (absent: no clipping)
  std::vector<std::string> warnings;

  std::map<std::string, std::vector<double>> inverse() const;  // channel → φ samples
  std::map<std::string, IntensityRange> covered() const;       // channel → covered range
  std::string summary() const;
};

// `jpeg`: the camera's rendered image (8/16-bit, grey or BGR). `linear`: the RAW of the same shot decoded
// linearly, or any linear image of it (8/16-bit or float, grey or BGR). Throws InvalidInput (see step 7).
RawTruthResult computeRawTruth(const cv::Mat& jpeg, const cv::Mat& linear, const RawTruthOptions& options = {});

}  // namespace crfcal
