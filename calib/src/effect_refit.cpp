// The pair corrected by an extended model and φ refitted (fitInverseCrf): what the effect search moves φ with, and
// where the reported φ of a detected effect comes from (effects.hpp).
#include <algorithm>
#include <cmath>
#include <exception>
#include <string>

#include "crfcal/error.hpp"
#include "crfcal/joint_crf_fit.hpp"
#include "crfcal/kernel_estimation.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_estimation.hpp"
#include "effect_problem.hpp"
#include "image_units.hpp"
#include "irradiance_kernel_inputs.hpp"
#include "parallel_jobs.hpp"

namespace crfcal::effect {

namespace {

// Whether a parallel job threw InvalidInput (its reason in *reason): a fit or kernel the data refuse. Any other
// exception is rethrown, as the serial loop let it through.
bool refusedByTheData(const std::exception_ptr& error, std::string* reason = nullptr) {
  if (!error) return false;
  try {
    std::rethrow_exception(error);
  } catch (const InvalidInput& refused) {
    if (reason) *reason = refused.reason();
  }
  return true;
}

CrfFitResult averageFits(const std::vector<CrfFitResult>& fits) {
  CrfFitResult out = fits.front();
  std::vector<double> phi(kCurveSamples, 0.0);
  double total = 0, ratio = 0;
  int used = 0;
  for (const auto& f : fits) {
    const double w = std::max(1, f.pixels.used);
    for (int i = 0; i < kCurveSamples; ++i) phi[i] += w * f.inverse_crf[i];
    ratio += w * f.ratio;
    total += w;
    used += f.pixels.used;
  }
  for (auto& v : phi) v /= total;
  phi.front() = 0;
  phi.back() = 1;
  for (int i = 1; i < kCurveSamples; ++i) phi[i] = std::max(phi[i], phi[i - 1]);
  out.inverse_crf = phi;
  out.model = TableModel{phi};
  out.ratio = ratio / total;
  out.pixels.used = used;
  out.chosen = "table";
  out.choice_reason = "weighted mean of " + std::to_string(fits.size()) + " per-tile fits (per-tile kernels)";
  return out;
}

// Each tile's own kernel, estimated on that tile alone in the irradiance domain around the refit's φ of the reported
// channel, as the pipeline's kernel↔φ rounds estimate the global one (denoised I, weights 1/φ'(B)): the blur there,
// whatever its form across the frame. The check's varying kernel K₀ + u K_x + v K_y + c R(u, v) is a second-order
// expansion of a roll; a depth-dependent kernel scale, or a roll too large for the expansion, is not. Measured on
// `bench effects --effect spatially_varying_blur --seeds 20` (with the first-order kernel then): φ ok 14 → 16 of 20,
// mean shape over the covered range 0.0103 → 0.0069 against the clean twins' 0.0066
// (docs/RESULTS.md#effects-tile-kernels). An empty kernel: that tile has too few edges of its own (the check's
// varying kernel is used).
std::vector<cv::Mat> ownTileKernels(const EffectSearch& search, const PairCorrection& pair) {
  const int gi = search.g_index;
  const ResponseCurve& curve = pair.ext[gi].curve;
  const cv::Mat blurred = curve.forward(cv::max(cv::min(pair.Y[gi], 1.0), 0.0));
  const cv::Mat i_irr = curve.inverse(detail::denoiseForKernel(detail::unit(pair.sharp[gi])));
  const cv::Mat weights = search.in.weighted_tile_kernels ? detail::intensityScaleWeights(curve, blurred) : cv::Mat();
  KernelEstimationOptions options = search.in.kernel_options;
  options.throw_on_size_limit = false;
  options.progress = nullptr;
  const std::vector<cv::Rect>& tiles = search.layout.tiles;
  std::vector<cv::Mat> kernels(tiles.size());
  const std::vector<std::exception_ptr> errors = detail::runInParallel(static_cast<int>(tiles.size()), [&](int i) {
    kernels[i] = estimateKernel(i_irr, pair.Y[gi], {tiles[i]}, search.p.usable, options, weights).kernel;
  });
  for (const std::exception_ptr& error : errors) refusedByTheData(error);  // that tile's kernel stays empty
  return kernels;
}

// One tile of the frame with its own kernel (or, without one, the check's varying kernel at its centre), grown by
// the kernel's reach.
JointFitPair tilePair(const EffectSearch& search, const cv::Rect& t, const cv::Mat& own_kernel, const cv::Mat& I,
                      const cv::Mat& B, const CrfFitOptions& fo) {
  const cv::Point2d tc(t.x + t.width / 2.0, t.y + t.height / 2.0);
  JointFitPair tile;
  tile.kernel = !own_kernel.empty() ? own_kernel
                                    : kernelAt(search.blur, (tc.x - search.centre.x) / search.radius,
                                               (tc.y - search.centre.y) / search.radius);
  const int m = std::max(tile.kernel.rows, tile.kernel.cols) / 2 + 1;
  const cv::Rect big = cv::Rect(t.x - m, t.y - m, t.width + 2 * m, t.height + 2 * m) &
                       cv::Rect(0, 0, search.size.width, search.size.height);
  tile.sharp = I(big);
  tile.blurred = B(big);
  tile.options = fo;
  tile.options.min_pixels = std::min(fo.min_pixels, 100);
  return tile;
}

// φ under a blur that varies across the frame: each tile fitted with its own kernel gives r (the tiles' pixel-weighted
// geometric mean), then one φ is fitted to all tiles' data at once with r held there (joint_crf_fit.hpp). The mean
// of the per-tile curves it replaces averaged curves each normalised by its own extrapolation above its own data:
// measured on `bench effects --effect spatially_varying_blur --seeds 20`, φ_G mean 0.0251 → 0.0219, and on the
// held-out rotation and depth blurs (docs/RESULTS.md#effects-joint-tiles). The mean stays the fallback when the joint
// fit refuses the tiles.
CrfFitResult perTileFit(const EffectSearch& search, const std::vector<cv::Mat>& kernels, const cv::Mat& I,
                        const cv::Mat& B, const CrfFitOptions& fo) {
  const int n = static_cast<int>(search.layout.tiles.size());
  std::vector<JointFitPair> all_tiles;
  for (int i = 0; i < n; ++i) all_tiles.push_back(tilePair(search, search.layout.tiles[i], kernels[i], I, B, fo));
  std::vector<CrfFitResult> all_fits(static_cast<std::size_t>(n));
  const std::vector<std::exception_ptr> errors = detail::runInParallel(n, [&](int i) {
    all_fits[i] = fitInverseCrf(all_tiles[i].sharp, all_tiles[i].blurred, all_tiles[i].kernel, all_tiles[i].options);
  });
  std::vector<CrfFitResult> tile_fits;
  std::vector<JointFitPair> tiles;
  double log_ratio = 0, weight = 0;
  for (int i = 0; i < n; ++i) {  // in tile order, as the serial loop summed them
    if (refusedByTheData(errors[i])) continue;  // a tile without edges: skipped
    tile_fits.push_back(std::move(all_fits[i]));
    const double w = std::max(1, tile_fits.back().pixels.used);
    log_ratio += w * std::log(tile_fits.back().ratio);
    weight += w;
    tiles.push_back(std::move(all_tiles[i]));
  }
  if (tile_fits.empty()) throw InvalidInput("no tile could be fitted");
  const double ratio = std::exp(log_ratio / weight);
  for (JointFitPair& tile : tiles) tile.ratio = ratio;
  JointCrfFitOptions joint;
  joint.model = fo;
  try {
    CrfFitResult fit = fitInverseCrfJointly(tiles, joint).fit;
    fit.ratio = ratio;
    fit.choice_reason += "; one curve fitted to " + std::to_string(tiles.size()) +
                         " tiles at once (each tile's own kernel, r held at the tiles' mean)";
    return fit;
  } catch (const InvalidInput&) {
    return averageFits(tile_fits);  // the tiles the joint fit refuses: the mean of their own curves
  }
}

// The refit's options for one channel: the base fit's, started from the extended model's r (or with r fixed).
CrfFitOptions refitOptions(const EffectSearch& search, const Coefficients& cf, const ChannelFit& ff,
                           double fixed_ratio) {
  CrfFitOptions fo = search.in.fit;
  fo.progress = nullptr;
  if (ff.ok && cf.scale > 0) fo.nominal_ratio = cf.scale;  // the extended model's r as the start
  if (fixed_ratio > 0) {
    fo.nominal_ratio = fixed_ratio;
    fo.fit_ratio = false;
  }
  return fo;
}

}  // namespace

PairRefit refitPair(const EffectSearch& search, const Spec& spec, const std::vector<Curve>& cur,
                    const std::vector<Coefficients>& cf, const std::vector<ChannelFit>& ff, bool with_blur,
                    bool with_noise, double fixed_ratio) {
  const int nc = search.nc;
  const EffectInputs& in = search.in;
  // φ_ext: the jointly re-fitted φ of the extended model; the corrections use it.
  std::vector<Curve> ext(nc);
  for (int c = 0; c < nc; ++c) ext[c] = ff[c].ok ? makeCurve(adjustedPhi(cur[c].phi, cf[c].alpha)) : cur[c];
  PairCorrection pair{search, ext, cf, ff, {}, {}, {}};
  for (int c = 0; c < nc; ++c) {
    pair.Y.push_back(ext[c].curve.inverse(search.p.B[c]));
    pair.sharp.push_back(in.sharp.at(in.channels[c]));
    pair.fit_options.push_back(refitOptions(search, cf[c], ff[c], fixed_ratio));
  }
  for (const LevelEffect* effect : levelEffects())
    if (effect->in(spec)) effect->correct(pair);
  const std::vector<cv::Mat> tile_kernels = with_blur ? ownTileKernels(search, pair) : std::vector<cv::Mat>{};
  // The channels' fits are independent: in parallel, as the base fits are (pair_stage_fit.cpp).
  std::vector<CrfFitResult> channel_fits(static_cast<std::size_t>(nc));
  const std::vector<std::exception_ptr> errors = detail::runInParallel(nc, [&](int c) {
    const cv::Mat Bc = store(ext[c].curve.forward(cv::max(cv::min(pair.Y[c], 1.0), 0.0)), search.p.depth[c]);
    const cv::Mat& Ic = pair.sharp[c];
    CrfFitOptions& fo = pair.fit_options[c];
    if (with_noise) {
      const int L = std::max(naturalLevels(Ic), naturalLevels(Bc));  // the fitter's level grid
      fo.noise_sigma_per_level = noiseSigmaPerLevel(search.noise_level[c], search.noise_sigma[c], L);
    }
    channel_fits[c] = with_blur ? perTileFit(search, tile_kernels, Ic, Bc, fo) : fitInverseCrf(Ic, Bc, search.K, fo);
  });
  PairRefit refit;
  std::string reason;
  for (int c = 0; c < nc; ++c)  // the first channel that fails, as a serial loop would meet it
    if (refusedByTheData(errors[c], &reason)) {
      refit.failure = "channel " + in.channels[c] + ": " + reason;
      return refit;
    }
  for (int c = 0; c < nc; ++c) refit.fits[in.channels[c]] = std::move(channel_fits[c]);
  return refit;
}

}  // namespace crfcal::effect
