#include "crfcal/pair_calibration.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

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

}  // namespace

void PairCalibrationOptions::check() const {
  registration.check();
  kernel.check();
  tiles.check();
  fit.check();
  if (rounds < 0 || rounds > 10) throw InvalidInput("rounds must be in 0..10");
  if (!(saturated_frame_limit > 0 && saturated_frame_limit <= 1)) throw InvalidInput("saturated_frame_limit in (0,1]");
  if (max_fit_side < 128) throw InvalidInput("max_fit_side must be >= 128");
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

PairCalibrationResult calibratePair(const cv::Mat& sharp, const cv::Mat& blurred, const PairCalibrationOptions& options) {
  options.check();
  auto report = [&](const std::string& stage, double fraction, const std::string& detail = {}) {
    if (options.progress) options.progress(stage, fraction, detail);
  };
  if (sharp.empty() || blurred.empty()) throw InvalidInput("empty image");
  if (sharp.size() != blurred.size())
    throw InvalidInput("the images differ in size (" + std::to_string(sharp.cols) + "x" + std::to_string(sharp.rows) +
                       " vs " + std::to_string(blurred.cols) + "x" + std::to_string(blurred.rows) + ")");
  if (sharp.type() != blurred.type()) throw InvalidInput("the images differ in bit depth or channel count");
  if (sharp.depth() != CV_8U && sharp.depth() != CV_16U) throw InvalidInput("8- or 16-bit images expected");
  PairCalibrationResult result;
  const bool colour = sharp.channels() == 3;
  result.channels = colour && options.rgb ? std::vector<std::string>{"R", "G", "B"} : std::vector<std::string>{"G"};
  const double top = fullScale(sharp);

  // Saturated frames.
  {
    auto clippedFraction = [&](const cv::Mat& image) {
      cv::Mat gray = image.channels() == 3 ? splitChannels(image)[1] : image;
      return cv::countNonZero(gray >= options.fit.saturation_high * top) / static_cast<double>(gray.total());
    };
    for (const auto& [name, image] : {std::pair<const char*, const cv::Mat&>{"blurred", blurred}, {"sharp", sharp}}) {
      const double f = clippedFraction(image);
      if (f > options.saturated_frame_limit) {
        char buffer[200];
        std::snprintf(buffer, sizeof buffer, "saturated frame: %.0f%% of the %s image is clipped (over-exposed)",
                      100 * f, name);
        throw InvalidInput(buffer);
      }
    }
  }

  // Registration.
  auto t0 = Clock::now();
  report("register", 0);
  cv::Mat registered = sharp;
  if (options.register_pair) {
    result.registration = registerPair(sharp, blurred, options.registration);
    registered = warpToBlurred(sharp, result.registration.homography, blurred.size());
  } else {
    result.registration.method = "none (given as aligned)";
    result.registration.overlap_fraction = 1;
    result.registration.ecc_correlation = 1;
  }
  result.timings["register"] = since(t0);
  report("register", 1, result.registration.summary());

  // Working channels (G for the kernel).
  const std::vector<cv::Mat> sharp_planes = splitChannels(registered), blurred_planes = splitChannels(blurred);
  auto plane = [&](const std::vector<cv::Mat>& planes, const std::string& name) {
    if (planes.size() == 1) return planes[0];
    return planes[name == "B" ? 0 : name == "G" ? 1 : 2];
  };
  const cv::Mat sharp_g = unit(plane(sharp_planes, "G")), blurred_g = unit(plane(blurred_planes, "G"));
  const int n = options.given_kernel.empty() ? options.kernel.kernel_size : std::max(options.given_kernel.rows, options.given_kernel.cols);
  const cv::Mat overlap = overlapMask(sharp.size(), result.registration.homography, blurred.size(), n / 2 + 2);
  if (cv::countNonZero(overlap) < 0.2 * overlap.total())
    throw InvalidInput("the pair does not overlap enough after registration");
  auto unsaturated = [&](const cv::Mat& s, const cv::Mat& b) {
    cv::Mat bad = (b >= options.fit.saturation_high) | (b <= options.fit.saturation_low) |
                  (s >= options.fit.saturation_high) | (s <= options.fit.saturation_low);
    cv::Mat ok;
    cv::bitwise_and(overlap, ~dilateBy(bad, n), ok);
    return ok;
  };

  // Tiles.
  t0 = Clock::now();
  result.tiles = selectTiles(sharp_g, overlap, options.tiles);
  std::vector<cv::Rect> rects;
  for (const auto& t : result.tiles) rects.push_back(t.rect);

  auto estimate = [&](const cv::Mat& s, const cv::Mat& b, const cv::Mat& valid, bool per_tile) {
    KernelEstimationOptions ko = options.kernel;
    ko.progress = [&](double f, const std::string& stage) { report("kernel", f, stage); };
    KernelEstimate k = estimateKernel(s, b, rects, valid, ko);
    if (per_tile && rects.size() > 1) {
      result.tile_kernels.clear();
      KernelEstimationOptions to = options.kernel;
      to.throw_on_size_limit = false;
      for (const auto& r : rects) {
        try {
          result.tile_kernels.push_back(estimateKernel(s, b, {r}, valid, to).kernel);
        } catch (const InvalidInput&) {
          // a tile without usable edges: no per-tile kernel
        }
      }
      result.disagreement = kernelDisagreement(result.tile_kernels, k.kernel);
    }
    return k;
  };

  cv::Mat K;
  if (!options.given_kernel.empty()) {
    K = normalizeKernel(options.given_kernel);
    result.kernel.kernel = K;
    result.kernel_estimated = false;
  } else {
    report("kernel", 0);
    const cv::Mat matched = histogramMatch(denoiseForKernel(sharp_g), blurred_g, overlap);
    result.kernel = estimate(matched, blurred_g, unsaturated(sharp_g, blurred_g), true);
    K = result.kernel.kernel;
  }
  result.timings["kernel"] = since(t0);

  // The fit window: the whole frame for moderate sizes, else a window around the best tile.
  cv::Rect window(0, 0, blurred.cols, blurred.rows);
  if (std::max(blurred.cols, blurred.rows) > options.max_fit_side) {
    const cv::Point centre = (result.tiles.front().rect.tl() + result.tiles.front().rect.br()) / 2;
    const int w = std::min(options.max_fit_side, blurred.cols), h = std::min(options.max_fit_side, blurred.rows);
    window = cv::Rect(std::clamp(centre.x - w / 2, 0, blurred.cols - w), std::clamp(centre.y - h / 2, 0, blurred.rows - h), w, h);
  }
  result.fit_window = window;
  cv::Mat outside = ~overlapMask(sharp.size(), result.registration.homography, blurred.size(), 0);

  auto fitChannel = [&](const std::string& name, const cv::Mat& kernel) {
    cv::Mat s = plane(sharp_planes, name)(window).clone(), b = plane(blurred_planes, name)(window);
    s.setTo(0, outside(window));  // no data: censored (excluded with the kernel's support by the fitter)
    CrfFitOptions fo = options.fit;
    fo.progress = [&](double f, const std::string& stage) { report("fit " + name, f, stage); };
    return fitInverseCrf(s, b, kernel, fo);
  };

  t0 = Clock::now();
  double fit_time = 0;
  {
    const auto tf = Clock::now();
    result.fits["G"] = fitChannel("G", K);
    fit_time += since(tf);
  }
  result.rounds.push_back({0, 0, 0, result.fits["G"].ratio, result.kernel.relative_residual});
  for (int round = 1; round <= options.rounds && options.given_kernel.empty(); ++round) {
    const ResponseCurve curve = ResponseCurve::fromSamples(result.fits["G"].inverse_crf);
    const cv::Mat i_irr = denoiseForKernel(curve.inverse(sharp_g)), b_irr = curve.inverse(blurred_g);
    KernelEstimate k;
    try {
      k = estimate(i_irr, b_irr, unsaturated(sharp_g, blurred_g), round == options.rounds);
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
    for (const auto& name : result.channels) {
      cv::Mat s = plane(sharp_planes, name)(window).clone();
      s.setTo(0, outside(window));
      ei.sharp[name] = s;
      ei.blurred[name] = plane(blurred_planes, name)(window);
    }
    ei.fits = result.fits;
    ei.kernel = K;
    ei.kernel_estimated = result.kernel_estimated;
    ei.exif_ratio = options.fit.initial_ratio;
    ei.centre = cv::Point2d((blurred.cols - 1) / 2.0 - window.x, (blurred.rows - 1) / 2.0 - window.y);
    ei.corner_radius = 0.5 * std::hypot(blurred.cols, blurred.rows);
    ei.valid = overlap(window);
    ei.fit = options.fit;
    ei.kernel_options = options.kernel;
    try {
      result.effects = diagnoseEffects(ei, options.effects);
      if (!result.effects.fits.empty()) {
        result.base_fits = result.fits;
        for (const auto& [name, fit] : result.effects.fits) result.fits[name] = fit;
      }
    } catch (const InvalidInput& e) {
      result.warnings.push_back(std::string("effect diagnostics skipped: ") + e.what());
    }
    result.timings["effects"] = since(te);
    report("effects", 1, result.effects.detected().empty() ? "none detected" : "detected");
  }

  // Diagnostics on G.
  const cv::Mat sg = sharp_g(window), bg = blurred_g(window);
  result.gamma_map = blurInconsistency(bg, convolve(sg, K));
  result.weights = result.fits["G"].pixels.used_mask;
  if (result.kernel_estimated && result.tile_kernels.size() > 1 && result.disagreement.mean_relative > 0.6)
    result.warnings.push_back("the tiles' kernels disagree (" + result.disagreement.summary() +
                              "): the blur varies across the frame; one global kernel is an approximation");
  for (const auto& [name, fit] : result.fits)
    if (fit.pixels.used < 2000)
      result.warnings.push_back("channel " + name + ": only " + std::to_string(fit.pixels.used) + " edge pixels used");
  return result;
}

}  // namespace crfcal
