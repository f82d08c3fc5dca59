#include "crfcal/pair_calibration.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>

#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/noise_estimation.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal {
namespace {

using Clock = std::chrono::steady_clock;
double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

double fullScale(const cv::Mat& m) { return m.depth() == CV_16U ? 65535.0 : m.depth() == CV_8U ? 255.0 : 1.0; }

cv::Mat unit(const cv::Mat& channel) {
  cv::Mat out;
  channel.convertTo(out, CV_64F, 1.0 / fullScale(channel));
  return out;
}

std::vector<cv::Mat> splitChannels(const cv::Mat& image) {
  std::vector<cv::Mat> planes;
  cv::split(image, planes);
  return planes;  // BGR order
}

// Monotone map of `source` values so that their histogram (inside mask) matches `target`'s.
cv::Mat histogramMatch(const cv::Mat& source, const cv::Mat& target, const cv::Mat& mask) {
  constexpr int bins = 4096;
  std::vector<double> hs(bins, 0), ht(bins, 0);
  for (int y = 0; y < source.rows; ++y) {
    const double* s = source.ptr<double>(y);
    const double* t = target.ptr<double>(y);
    const uchar* m = mask.ptr<uchar>(y);
    for (int x = 0; x < source.cols; ++x) {
      if (!m[x]) continue;
      hs[std::clamp(static_cast<int>(s[x] * (bins - 1) + 0.5), 0, bins - 1)] += 1;
      ht[std::clamp(static_cast<int>(t[x] * (bins - 1) + 0.5), 0, bins - 1)] += 1;
    }
  }
  for (int i = 1; i < bins; ++i) {
    hs[i] += hs[i - 1];
    ht[i] += ht[i - 1];
  }
  std::vector<double> lut(bins);
  const double ns = std::max(1.0, hs.back()), nt = std::max(1.0, ht.back());
  int j = 0;
  for (int i = 0; i < bins; ++i) {
    const double q = (i == 0 ? hs[0] / 2 : 0.5 * (hs[i] + hs[i - 1])) / ns;
    while (j < bins - 1 && ht[j] / nt < q) ++j;
    lut[i] = static_cast<double>(j) / (bins - 1);
  }
  cv::Mat out(source.size(), CV_64F);
  for (int y = 0; y < source.rows; ++y) {
    const double* s = source.ptr<double>(y);
    double* o = out.ptr<double>(y);
    for (int x = 0; x < source.cols; ++x) o[x] = lut[std::clamp(static_cast<int>(s[x] * (bins - 1) + 0.5), 0, bins - 1)];
  }
  return out;
}

cv::Mat dilateBy(const cv::Mat& mask, int n) {
  cv::Mat out;
  cv::dilate(mask, out, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(n, n)));
  return out;
}

// The sharp image is the noisy (high-ISO) one; noise in ∂I biases the gradient-domain kernel regression
// (errors in variables: the kernel shrinks and spreads). As in [27], it is denoised first — an edge-preserving
// bilateral filter scaled to the estimated noise level — for kernel estimation only (the φ fit uses the raw I).
cv::Mat denoiseForKernel(const cv::Mat& image) {
  const double sigma = estimateNoiseSigma(image).sigma;
  if (!(sigma > 0.002)) return image;
  cv::Mat f, out;
  image.convertTo(f, CV_32F);
  cv::bilateralFilter(f, out, 7, static_cast<float>(std::max(3 * sigma, 0.02)), 2.0);
  out.convertTo(out, CV_64F);
  return out;
}

// Weights of the irradiance-domain kernel equations: 1 / φ'(B). The pixels' errors (noise, JPEG, the chroma of
// 4:2:0 edges) are intensity errors, which φ multiplies by its slope; unweighted, the bright edges, where a convex φ
// is steepest, would dominate the regression with their amplified errors. φ' is a central difference over ±5 levels
// of 8 bits (the fitted φ is smooth; the step only has to see past quantisation), floored at 1/50 of φ's mean slope
// (which is 1: φ(0) = 0, φ(1) = 1) so that the flat dark toe of a convex φ cannot take all the weight.
cv::Mat intensityScaleWeights(const ResponseCurve& curve, const cv::Mat& blurred) {
  constexpr double step = 5.0 / 255, min_slope = 0.02;
  const cv::Mat upper = curve.inverse(cv::min(blurred + step, 1.0)), lower = curve.inverse(cv::max(blurred - step, 0.0));
  const cv::Mat slope = (upper - lower) / (2 * step);
  return 1.0 / cv::max(slope, min_slope);
}

PairCalibrationResult calibrateAligned(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options,
                                       PairCalibrationResult result, bool registered, Clock::time_point t0);

}  // namespace

void PairCalibrationOptions::check() const {
  registration.check();
  kernel.check();
  tiles.check();
  fit.check();
  if (rounds < 0 || rounds > 10) throw InvalidInput("rounds must be in 0..10");
  if (!(saturated_frame_limit > 0 && saturated_frame_limit <= 1)) throw InvalidInput("saturated_frame_limit in (0,1]");
  if (max_fit_side < 128) throw InvalidInput("max_fit_side must be >= 128");
  if (!(min_blur_radius >= 0)) throw InvalidInput("min_blur_radius must be >= 0");
  if (!(min_covered_span >= 0 && min_covered_span <= 1)) throw InvalidInput("min_covered_span must be in [0, 1]");
  if (!(irradiance_kernel_lambda >= 0)) throw InvalidInput("irradiance_kernel_lambda must be >= 0");
  effects.check();
}

std::string PairCalibrationResult::summary() const {
  std::string text = "registration: " + registration.summary() + "\nkernel: " + kernel.summary();
  if (tile_kernels.size() > 1) text += "\nspatial variation: " + disagreement.summary();
  for (const auto& round : rounds) {
    char buffer[200];
    std::snprintf(buffer, sizeof buffer, "\nround %d: kernel change %.3f, phi change %.4f, r %.4f", round.round,
                  round.kernel_change, round.phi_change, round.ratio);
    text += buffer;
  }
  for (const auto& [name, fit] : fits) text += "\n" + name + ": " + fit.summary();
  if (!effects.entries.empty()) text += "\n" + effects.summary();
  return text;
}

PairCalibrationResult calibratePair(const cv::Mat& sharp_in, const cv::Mat& blurred, const PairCalibrationOptions& options) {
  options.check();
  auto report = [&](const std::string& stage, double fraction, const std::string& detail = {}) {
    if (options.progress) options.progress(stage, fraction, detail);
  };
  if (sharp_in.empty() || blurred.empty()) throw InvalidInput("empty image");
  const bool transposed = sharp_in.size() != blurred.size() && sharp_in.size() == cv::Size(blurred.rows, blurred.cols);
  if (transposed && !options.register_pair)
    throw InvalidInput("the images differ in orientation (portrait vs landscape): registration is needed");
  const cv::Mat& sharp = sharp_in;  // replaced by its rotated copy below when the frames are transposed
  if (sharp.size() != blurred.size() && !transposed)
    throw InvalidInput("the images differ in size (" + std::to_string(sharp.cols) + "x" + std::to_string(sharp.rows) +
                       " vs " + std::to_string(blurred.cols) + "x" + std::to_string(blurred.rows) + ")");
  if (sharp.type() != blurred.type()) throw InvalidInput("the images differ in bit depth or channel count");
  if (sharp.depth() != CV_8U && sharp.depth() != CV_16U) throw InvalidInput("8- or 16-bit images expected");
  PairCalibrationResult result;
  auto t0 = Clock::now();
  cv::Mat rotated;
  if (transposed) {
    // One shot held in portrait, the other in landscape (EXIF orientation not recorded): the sharp shot is turned
    // by ±90° (a lossless pixel permutation, no resampling of the noisy image) — whichever registers.
    report("register", 0, "frames transposed: trying the sharp shot turned by +90 and -90 degrees");
    double best = -1;
    std::string failures;
    for (const int code : {cv::ROTATE_90_CLOCKWISE, cv::ROTATE_90_COUNTERCLOCKWISE}) {
      cv::Mat candidate;
      cv::rotate(sharp_in, candidate, code);
      try {
        const RegistrationResult r = registerPair(candidate, blurred, options.registration);
        // The features are rotation invariant, so the wrong turn may still register as a ~180° rotation: a
        // handheld pair differs by a small angle, and that is the turn to keep.
        if (std::abs(r.rotationDegrees()) > 45) continue;
        if (r.ecc_correlation * r.overlap_fraction > best) {
          best = r.ecc_correlation * r.overlap_fraction;
          rotated = candidate;
          result.registration = r;
          result.sharp_rotation_deg = code == cv::ROTATE_90_CLOCKWISE ? -90 : 90;
        }
      } catch (const InvalidInput& e) {
        failures = e.what();
      }
    }
    if (rotated.empty())
      throw InvalidInput("the images differ in orientation and neither 90-degree turn aligns them: " + failures);
    result.warnings.push_back("the sharp shot is framed in the other orientation; it was turned by " +
                              std::to_string(static_cast<int>(result.sharp_rotation_deg)) +
                              " degrees (outputs are in the blurred shot's orientation)");
  }
  return calibrateAligned(transposed ? rotated : sharp, blurred, options, std::move(result), transposed, t0);
}

namespace {

// The kernel's working set: the edge-rich tiles (each grown by the kernel's reach) side by side in one small
// mosaic, so that denoising, tone matching and the φ transforms of every round touch a few megapixels, not the
// whole 24 MP frame. A one-pixel unusable gutter separates the crops (no equation straddles two of them). Small
// frames (one region) use the frame itself.
struct Canvas {
  cv::Mat sharp, sharp_denoised, blurred, usable;  // CV_64F in [0,1] (usable CV_8U)
  std::vector<cv::Rect> regions;                   // the tiles in canvas coordinates
};

Canvas makeCanvas(const cv::Mat& sharp8, const cv::Mat& blurred8, const cv::Mat& usable, const std::vector<Tile>& tiles,
                  int margin) {
  Canvas c;
  const cv::Rect frame(0, 0, sharp8.cols, sharp8.rows);
  std::vector<cv::Rect> crops;
  for (const auto& t : tiles)
    crops.push_back(cv::Rect(t.rect.x - margin, t.rect.y - margin, t.rect.width + 2 * margin, t.rect.height + 2 * margin) &
                    frame);
  int width = 0, height = 0;
  for (const auto& r : crops) {
    width += r.width + 1;
    height = std::max(height, r.height);
  }
  if (crops.size() == 1 && crops[0] == frame) {
    c.sharp = unit(sharp8);
    c.blurred = unit(blurred8);
    c.usable = usable.clone();
    c.regions = {tiles[0].rect};
  } else {
    c.sharp = cv::Mat::zeros(height, width, CV_64F);
    c.blurred = cv::Mat::zeros(height, width, CV_64F);
    c.usable = cv::Mat::zeros(height, width, CV_8U);
    int x = 0;
    for (std::size_t i = 0; i < crops.size(); ++i) {
      const cv::Rect& r = crops[i];
      const cv::Rect at(x, 0, r.width, r.height);
      unit(sharp8(r)).copyTo(c.sharp(at));
      unit(blurred8(r)).copyTo(c.blurred(at));
      usable(r).copyTo(c.usable(at));
      c.regions.push_back(tiles[i].rect - r.tl() + at.tl());
      x += r.width + 1;
    }
  }
  c.sharp_denoised = denoiseForKernel(c.sharp);
  return c;
}

// The rest of calibratePair once both frames have the same orientation (registration done when `registered`).
PairCalibrationResult calibrateAligned(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options,
                                       PairCalibrationResult result, bool registered, Clock::time_point t0) {
  auto report = [&](const std::string& stage, double fraction, const std::string& detail = {}) {
    if (options.progress) options.progress(stage, fraction, detail);
  };
  const bool colour = sharp.channels() == 3;
  result.channels = colour && options.rgb ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"G"};
  const double top = fullScale(sharp);
  const std::vector<cv::Mat> sharp_planes = splitChannels(sharp), blurred_planes_own = splitChannels(blurred);
  auto plane = [&](const std::vector<cv::Mat>& planes, const std::string& name) {
    if (planes.size() == 1) return planes[0];
    return planes[name == "B" ? 0 : name == "G" ? 1 : 2];
  };
  // Full-frame work stays in the images' own 8/16-bit depth (masks, tiles, warps); only the kernel's tiles and
  // the fit window are converted to floating point.
  const cv::Mat sharp_g8 = plane(sharp_planes, "G");
  const double clip_high = options.fit.saturation_high * top, clip_low = options.fit.saturation_low * top;

  // Saturated frames.
  const cv::Mat blurred_own_g8 = plane(blurred_planes_own, "G");
  for (const auto& [name, image] : {std::pair<const char*, const cv::Mat&>{"blurred", blurred_own_g8}, {"sharp", sharp_g8}}) {
    const double f = cv::countNonZero(image >= clip_high) / static_cast<double>(image.total());
    if (f > options.saturated_frame_limit) {
      char buffer[200];
      std::snprintf(buffer, sizeof buffer, "saturated frame: %.0f%% of the %s image is clipped (over-exposed)", 100 * f,
                    name);
      throw InvalidInput(buffer);
    }
  }

  // No edges at all (a flat frame): say so before the registration would call it a non-overlapping pair. An edge
  // pixel: a step between neighbours (on a noise-smoothed ≤ 1024 px copy) of more than 5 % of the image's own
  // range (1st–99th percentile; a dark, underexposed frame still has edges) and more than 1.5 levels of 8 bits.
  {
    cv::Mat small = unit(sharp_g8);
    const double s = std::min(1.0, 1024.0 / std::max(small.cols, small.rows));
    if (s < 1) cv::resize(small, small, cv::Size(), s, s, cv::INTER_AREA);
    cv::GaussianBlur(small, small, cv::Size(3, 3), 0);
    std::vector<double> values(small.begin<double>(), small.end<double>());
    std::sort(values.begin(), values.end());
    const double range = values[values.size() * 99 / 100] - values[values.size() / 100];
    cv::Mat gx, gy, magnitude;
    cv::Sobel(small, gx, CV_64F, 1, 0, 3, 1.0 / 8);
    cv::Sobel(small, gy, CV_64F, 0, 1, 3, 1.0 / 8);
    cv::magnitude(gx, gy, magnitude);
    const double step = std::max(0.05 * range, 1.5 / 255.0);
    if (cv::countNonZero(magnitude > step) < 0.001 * magnitude.total())
      throw InvalidInput("no edges: the sharp image is nearly uniform (nothing to measure the blur or the response on)");
  }

  // Registration. Everything downstream works in the SHARP frame: the smooth blurred shot is resampled, the
  // noisy sharp shot is left untouched (see warpToSharp).
  report("register", 0);
  if (registered) {
    // registered while finding the orientation
  } else if (options.register_pair) {
    t0 = Clock::now();
    result.registration = registerPair(sharp, blurred, options.registration);
  } else {
    result.registration.method = "none (given as aligned)";
    result.registration.overlap_fraction = 1;
    result.registration.ecc_correlation = 1;
  }
  result.timings["register"] = since(t0);
  report("register", 1, result.registration.summary());

  // I's clipped regions, by its local median (a per-pixel test would select pixels by their noise).
  const cv::Mat sharp_clipped = [&] {
    cv::Mat med;
    cv::medianBlur(sharp_g8, med, 3);
    return cv::Mat((med >= clip_high) | (med <= clip_low));
  }();

  // Everything that depends on the alignment (re-done after the kernel-aware refinement).
  cv::Mat overlap, blurred_g8, usable;
  Canvas canvas;
  auto align = [&]() {
    const cv::Mat& H = result.registration.homography;
    blurred_g8 = options.register_pair ? warpToSharp(blurred_own_g8, H, sharp.size()) : blurred_own_g8;
    overlap = overlapMaskInSharp(sharp.size(), H, blurred.size(), options.register_pair ? 2 : 0);
    if (cv::countNonZero(overlap) < 0.2 * overlap.total())
      throw InvalidInput("the pair does not overlap enough after registration");
    // Pixels usable for the kernel: inside the overlap and unclipped in both shots. The estimator itself keeps
    // only equations whose whole window is usable.
    const cv::Mat bad = (blurred_g8 >= clip_high) | (blurred_g8 <= clip_low) | sharp_clipped;
    cv::bitwise_and(overlap, ~dilateBy(bad, 3), usable);
    result.tiles = selectTiles(sharp_g8, usable, options.tiles);
    canvas = makeCanvas(sharp_g8, blurred_g8, usable, result.tiles, options.kernel.kernel_size + 2);
  };
  align();

  t0 = Clock::now();
  const double register_before_kernel = result.timings["register"];
  // The first estimate (intensity domain, options.kernel) or an irradiance-domain round (its own λ and weights).
  auto estimate = [&](const cv::Mat& s, const cv::Mat& b, bool per_tile, double lambda, const cv::Mat& weights) {
    KernelEstimationOptions ko = options.kernel;
    ko.lambda = lambda;
    ko.progress = [&](double f, const std::string& stage) { report("kernel", f, stage); };
    KernelEstimate k = estimateKernel(s, b, canvas.regions, canvas.usable, ko, weights);
    if (per_tile && canvas.regions.size() > 1) {
      result.tile_kernels.clear();
      KernelEstimationOptions to = ko;
      to.progress = nullptr;
      to.throw_on_size_limit = false;
      for (const auto& r : canvas.regions) {
        try {
          result.tile_kernels.push_back(estimateKernel(s, b, {r}, canvas.usable, to, weights).kernel);
        } catch (const InvalidInput&) {
          // a tile without usable edges: no per-tile kernel
        }
      }
      result.disagreement = kernelDisagreement(result.tile_kernels, k.kernel);
    }
    return k;
  };
  // Kernel-aware refinement of the alignment: ECC of I ⊗ K against B (equally blurred), then re-align.
  auto refine = [&](const cv::Mat& kernel) {
    if (!options.register_pair || !options.refine_registration) return;
    const auto tr = Clock::now();
    cv::Mat sharp_ok;
    cv::bitwise_and(~sharp_clipped, overlap, sharp_ok);
    const RegistrationResult refined = refineRegistration(sharp_g8, blurred_own_g8, result.registration,
                                                          kernel, sharp_ok, options.registration);
    if (refined.kernel_refined) {
      result.registration = refined;
      align();
    }
    result.timings["register"] += since(tr);
    report("register", 1, result.registration.summary());
  };

  cv::Mat K;
  if (!options.given_kernel.empty()) {
    K = normalizeKernel(options.given_kernel);
    result.kernel.kernel = K;
    result.kernel.support = cv::countNonZero(K);
    result.kernel.centroid = kernelCentroid(K);
    result.kernel_estimated = false;
    refine(K);  // a given kernel cannot absorb a residual shift: the alignment must be right
  } else {
    report("kernel", 0);
    // Round 0: no φ yet. The sharp image's levels are mapped to the blurred one's by histogram matching (a monotone
    // map that removes most of the exposure and tone difference), so B ≈ g · (I' ⊗ K) holds approximately.
    auto intensityKernel = [&](bool per_tile) {
      return estimate(histogramMatch(canvas.sharp_denoised, canvas.blurred, canvas.usable), canvas.blurred, per_tile,
                      options.kernel.lambda, cv::Mat());
    };
    result.kernel = intensityKernel(false);
    K = result.kernel.kernel;
    if (options.register_pair && options.refine_registration) {
      refine(K);
      result.kernel = intensityKernel(options.rounds == 0);
      K = result.kernel.kernel;
    }
  }
  result.timings["kernel"] = since(t0) - (result.timings["register"] - register_before_kernel);

  // The fit window: the whole frame for moderate sizes, else a window around the best tile.
  cv::Rect window(0, 0, sharp.cols, sharp.rows);
  if (std::max(sharp.cols, sharp.rows) > options.max_fit_side) {
    const cv::Point centre = (result.tiles.front().rect.tl() + result.tiles.front().rect.br()) / 2;
    const int w = std::min(options.max_fit_side, sharp.cols), h = std::min(options.max_fit_side, sharp.rows);
    window = cv::Rect(std::clamp(centre.x - w / 2, 0, sharp.cols - w), std::clamp(centre.y - h / 2, 0, sharp.rows - h), w, h);
  }
  result.fit_window = window;
  // Both shots inside the window, every channel (the blurred one resampled into the sharp frame: the window's
  // origin composed into the homography). No data outside the overlap: 0, i.e. censored for the fitter.
  std::map<std::string, cv::Mat> window_sharp, window_blurred;
  {
    const cv::Mat T = (cv::Mat_<double>(3, 3) << 1, 0, window.x, 0, 1, window.y, 0, 0, 1);
    const cv::Mat blurred_window =
        options.register_pair ? warpToSharp(blurred, result.registration.homography * T, window.size()) : blurred(window);
    const std::vector<cv::Mat> planes = splitChannels(blurred_window);
    const cv::Mat outside = ~overlap(window);
    for (const auto& name : result.channels) {
      cv::Mat s = plane(sharp_planes, name)(window).clone(), b = plane(planes, name).clone();
      s.setTo(0, outside);
      b.setTo(0, outside);
      window_sharp[name] = s;
      window_blurred[name] = b;
    }
  }

  CrfFitOptions fit_options = options.fit;
  const double first_blur_radius = kernelRmsRadius(K);

  auto fitChannel = [&](const std::string& name, const cv::Mat& kernel_full) {
    // The smallest centred window holding the kernel's mass: the fitter dilates clipped regions and the frame
    // border by the kernel's window, so empty margins (the estimation window's, or a given file's) would only
    // cost pixels.
    const cv::Mat kernel = cropKernel(kernel_full, 0.0);
    CrfFitOptions fo = fit_options;
    fo.progress = [&](double f, const std::string& stage) { report("fit " + name, f, stage); };
    return fitInverseCrf(window_sharp.at(name), window_blurred.at(name), kernel, fo);
  };

  t0 = Clock::now();
  double fit_time = 0;
  {
    const auto tf = Clock::now();
    result.fits["G"] = fitChannel("G", K);
    // With a blur too small to separate φ^γ, r^γ from φ, r the images cannot give r (log r moves with γ·log r):
    // if theirs disagrees with EXIF / --ratio beyond the tolerance of nominal EXIF values, r is held at that value.
    const double disagreement = std::abs(result.fits["G"].ratio / fit_options.nominal_ratio - 1);
    if (fit_options.fit_ratio && options.fix_ratio_when_blur_is_small && first_blur_radius < options.min_blur_radius &&
        disagreement > options.effects.ratio_tolerance) {
      result.ratio_images_small_blur = result.fits["G"].ratio;
      fit_options.fit_ratio = false;
      result.ratio_fixed_by_small_blur = true;
      result.fits["G"] = fitChannel("G", K);
    }
    fit_time += since(tf);
  }
  result.rounds.push_back({0, 0, 0, result.fits["G"].ratio, result.kernel.relative_residual});
  for (int round = 1; round <= options.rounds && options.given_kernel.empty(); ++round) {
    const ResponseCurve curve = ResponseCurve::fromSamples(result.fits["G"].inverse_crf);
    // Irradiance domain (Eq. 4 is linear there): φ of the denoised I (denoising first avoids Jensen's bias of φ
    // applied to noise) against φ(B).
    const cv::Mat i_irr = curve.inverse(canvas.sharp_denoised), b_irr = curve.inverse(canvas.blurred);
    const cv::Mat weights = options.weight_irradiance_kernel ? intensityScaleWeights(curve, canvas.blurred) : cv::Mat();
    KernelEstimate k;
    try {
      k = estimate(i_irr, b_irr, round == options.rounds, options.irradiance_kernel_lambda, weights);
    } catch (const InvalidInput& e) {
      result.warnings.push_back(std::string("irradiance-domain kernel round ") + std::to_string(round) +
                                " failed (" + e.what() + "); kept the previous kernel");
      break;
    }
    const double change = kernelRelativeError(k.kernel, K);
    K = k.kernel;
    result.kernel = k;
    const auto previous = result.fits["G"].inverse_crf;
    const auto tf = Clock::now();
    result.fits["G"] = fitChannel("G", K);
    fit_time += since(tf);
    result.rounds.push_back({round, change, curveRmse(result.fits["G"].inverse_crf, previous), result.fits["G"].ratio,
                             k.relative_residual});
  }
  for (const auto& name : result.channels) {
    if (name == "G") continue;
    const auto tf = Clock::now();
    result.fits[name] = fitChannel(name, K);
    fit_time += since(tf);
  }
  result.timings["fit"] = fit_time;
  result.timings["kernel_phi_rounds"] = since(t0) - fit_time;

  // Named effects on the residuals (effects.hpp); a detected effect's extended model supplies φ.
  if (options.effects.enabled) {
    const auto te = Clock::now();
    report("effects", 0);
    EffectInputs ei;
    ei.channels = result.channels;
    ei.sharp = window_sharp;
    ei.blurred = window_blurred;
    ei.fits = result.fits;
    ei.kernel = K;
    ei.kernel_estimated = result.kernel_estimated;
    ei.exif_ratio = fit_options.nominal_ratio;
    ei.centre = cv::Point2d((sharp.cols - 1) / 2.0 - window.x, (sharp.rows - 1) / 2.0 - window.y);
    ei.corner_radius = 0.5 * std::hypot(sharp.cols, sharp.rows);
    ei.valid = overlap(window);
    ei.fit = fit_options;
    ei.kernel_options = options.kernel;
    try {
      result.effects = diagnoseEffects(ei, options.effects);
      if (!result.effects.fits.empty()) {
        result.base_fits = result.fits;
        for (const auto& [name, fit] : result.effects.fits) {
          // A fixed r (--fix-ratio) is the user's constraint: an extended model that moved it is not adopted.
          if (!fit_options.fit_ratio && std::abs(fit.ratio - fit_options.nominal_ratio) > 1e-9 * fit_options.nominal_ratio) {
            result.warnings.push_back("channel " + name + ": the effects' refit changed the fixed r (" +
                                      std::to_string(fit.ratio) + "); kept the fit with the fixed r");
            continue;
          }
          result.fits[name] = fit;
        }
      }
    } catch (const InvalidInput& e) {
      result.warnings.push_back(std::string("effect diagnostics skipped: ") + e.what());
    }
    result.timings["effects"] = since(te);
    report("effects", 1, result.effects.detected().empty() ? "none detected" : "detected");
  }

  // Diagnostics on G.
  result.gamma_map = blurInconsistency(unit(window_blurred.at("G")), convolve(unit(window_sharp.at("G")), K));
  {
    cv::Mat inside;  // Γ only where both shots have data under the whole kernel
    cv::erode(overlap(window), inside, cv::getStructuringElement(cv::MORPH_RECT, K.size()), cv::Point(-1, -1), 1,
              cv::BORDER_CONSTANT, cv::Scalar(0));
    result.gamma_map.setTo(0, ~inside);
  }
  result.weights = result.fits["G"].pixels.used_mask;
  {
    // Blur extent: with almost no blur only a weak blur inconsistency (Sec. 3) separates φ^γ, r^γ from φ, r.
    result.blur_radius = kernelRmsRadius(K);
    char buffer[400];
    if (result.ratio_fixed_by_small_blur) {
      std::snprintf(buffer, sizeof buffer,
                    "the blur is small (kernel RMS radius %.2f px): phi^g with r^g fit alike, and the images' r (%.3g) "
                    "disagrees with %.4g (EXIF or --ratio) by more than %.0f %%: r is held at %.4g "
                    "(--always-fit-ratio to fit it)",
                    first_blur_radius, result.ratio_images_small_blur, fit_options.nominal_ratio,
                    100 * options.effects.ratio_tolerance, fit_options.nominal_ratio);
      result.warnings.push_back(buffer);
    } else if (result.blur_radius < options.min_blur_radius && fit_options.fit_ratio) {
      std::snprintf(buffer, sizeof buffer,
                    "the blur is small (kernel RMS radius %.2f px): phi and r are nearly ambiguous (phi^g with r^g fit "
                    "alike); the fitted r (%.3g) is weakly determined - consider fixing r to the EXIF value "
                    "(--fix-ratio)",
                    result.blur_radius, result.fits.at("G").ratio);
      result.warnings.push_back(buffer);
    }
  }
  if (result.kernel_estimated && result.tile_kernels.size() > 1 && result.disagreement.mean_relative > 0.6)
    result.warnings.push_back("the tiles' kernels disagree (" + result.disagreement.summary() +
                              "): the blur varies across the frame; one global kernel is an approximation");
  for (const auto& [name, fit] : result.fits) {
    if (fit.pixels.used < 2000)
      result.warnings.push_back("channel " + name + ": only " + std::to_string(fit.pixels.used) + " edge pixels used");
    // The intensities the data actually constrain: those of B and I at the used pixels (0.5 % tails dropped);
    // outside, φ is the model's extrapolation.
    const cv::Mat& used = fit.pixels.used_mask;
    if (used.empty() || used.size() != window.size() || cv::countNonZero(used) == 0) continue;
    std::vector<float> values;
    for (const cv::Mat* image : {&window_sharp.at(name), &window_blurred.at(name)}) {
      const cv::Mat u = unit(*image);
      for (int y = 0; y < u.rows; ++y)
        for (int x = 0; x < u.cols; ++x)
          if (used.at<uchar>(y, x)) values.push_back(static_cast<float>(u.at<double>(y, x)));
    }
    auto quantile = [&](double q) {
      auto it = values.begin() + static_cast<std::ptrdiff_t>(q * (values.size() - 1));
      std::nth_element(values.begin(), it, values.end());
      return static_cast<double>(*it);
    };
    const std::pair<double, double> range{quantile(0.005), quantile(0.995)};
    {
      // The sharp shot alone: an underexposed I carries few levels, each stretched over a wide range of B.
      std::vector<float> sharp_values;
      const cv::Mat u = unit(window_sharp.at(name));
      for (int y = 0; y < u.rows; ++y)
        for (int x = 0; x < u.cols; ++x)
          if (used.at<uchar>(y, x)) sharp_values.push_back(static_cast<float>(u.at<double>(y, x)));
      auto it = sharp_values.begin() + static_cast<std::ptrdiff_t>(0.995 * (sharp_values.size() - 1));
      std::nth_element(sharp_values.begin(), it, sharp_values.end());
      const double top_level = *it * (window_sharp.at(name).depth() == CV_16U ? 65535.0 : 255.0);
      if (top_level < 64) {
        char buffer[300];
        std::snprintf(buffer, sizeof buffer,
                      "channel %s: the sharp shot is underexposed (99.5 %% of its used pixels below level %.0f of %s): "
                      "few distinct levels constrain phi",
                      name.c_str(), top_level, window_sharp.at(name).depth() == CV_16U ? "65535" : "255");
        result.warnings.push_back(buffer);
      }
    }
    result.covered_range[name] = range;
    if (range.second - range.first < options.min_covered_span) {
      char buffer[300];
      std::snprintf(buffer, sizeof buffer,
                    "channel %s: the data cover intensities %.2f-%.2f only; phi outside that range is extrapolated",
                    name.c_str(), range.first, range.second);
      result.warnings.push_back(buffer);
    }
  }
  return result;
}

}  // namespace

}  // namespace crfcal
