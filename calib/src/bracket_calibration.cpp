#include "crfcal/bracket_calibration.hpp"

#include <algorithm>
#include <exception>
#include <cstdio>
#include <limits>
#include <map>
#include <cmath>
#include <numeric>
#include <random>
#include <sstream>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "crfcal/curve_comparison.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/exposure_fit.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/scaled_fit_band.hpp"
#include "image_units.hpp"
#include "parallel_jobs.hpp"

namespace crfcal {

void BracketSamplingOptions::check() const {
  if (points < 10) throw InvalidInput("bracket sampling: points must be ≥ 10", ErrorSubject::options);
  if (brightness_classes < 1) throw InvalidInput("bracket sampling: brightness_classes must be ≥ 1", ErrorSubject::options);
  if (window < 1 || window % 2 == 0) throw InvalidInput("bracket sampling: window must be odd and ≥ 1", ErrorSubject::options);
  if (!(flat_fraction > 0 && flat_fraction <= 1))
    throw InvalidInput("bracket sampling: flat_fraction must be in (0, 1]", ErrorSubject::options);
  if (candidates < points) throw InvalidInput("bracket sampling: candidates must be ≥ points", ErrorSubject::options);
  if (!(low >= 0 && low < high && high <= 1))
    throw InvalidInput("bracket sampling: need 0 ≤ low < high ≤ 1", ErrorSubject::options);
  if (!(top > low && top <= 1)) throw InvalidInput("bracket sampling: need low < top ≤ 1", ErrorSubject::options);
  if (!(plateau_floor > low && plateau_floor < top))
    throw InvalidInput("bracket sampling: need low < plateau_floor < top", ErrorSubject::options);
  if (margin < 0) throw InvalidInput("bracket sampling: margin must be ≥ 0", ErrorSubject::options);
  if (!(max_saturation > 0 && max_saturation <= 1))
    throw InvalidInput("bracket sampling: max_saturation must be in (0, 1]", ErrorSubject::options);
}

void BracketCalibrationOptions::check() const {
  registration.check();
  sampling.check();
  fit.check();
  band.check();
  if (max_dimension < 0 || (max_dimension > 0 && max_dimension < 64))
    throw InvalidInput("bracket: max_dimension must be 0 or ≥ 64", ErrorSubject::options);
  if (exposure_rounds < 0) throw InvalidInput("bracket: exposure_rounds must be ≥ 0", ErrorSubject::options);
  if (!(min_scene_correlation >= -1 && min_scene_correlation <= 1))
    throw InvalidInput("bracket: min_scene_correlation must be in [-1, 1]", ErrorSubject::options);
  if (!(max_exposure_deviation >= 0))
    throw InvalidInput("bracket: max_exposure_deviation must be ≥ 0", ErrorSubject::options);
  if (channels.empty()) throw InvalidInput("bracket: no channels", ErrorSubject::options);
  for (int c : channels)
    if (c < 0 || c > 2) throw InvalidInput("bracket: channel must be 0, 1 or 2", ErrorSubject::options);
}

std::string BracketCalibrationResult::summary() const {
  std::ostringstream out;
  out << points << " scene points; exposures (" << exposure_source << ", relative to the reference):";
  for (const auto& f : frames) out << ' ' << f.fitted_exposure << (f.reference ? "*" : "");
  out << "\n";
  for (const auto& c : channels) {
    out << channelName(c.channel) << ": " << c.fit.summary() << ", " << c.points << " points, GGCM deviation "
        << c.ggcm_rmse << "\n";
    if (!c.band.empty())
      out << "   " << c.band.summary() << "; shape half-width (median, covered range) " << medianShapeHalfWidth(c.band)
          << "\n";
  }
  return out.str();
}

namespace {

// The frames in the reference frame's geometry, unit scale, CV_32F, plus where all of them have data.
struct AlignedBracket {
  std::vector<cv::Mat> images;  // CV_32FC1 or CV_32FC3 (BGR)
  cv::Mat valid;                // CV_8U, 255 where every frame has data (eroded by the margin)
};

cv::Mat unitFloat(const cv::Mat& image) {
  cv::Mat out;
  image.convertTo(out, CV_32F, 1.0 / detail::fullScale(image));
  return out;
}

AlignedBracket alignFrames(const std::vector<BracketFrame>& frames, int reference,
                           const BracketCalibrationOptions& options, std::vector<BracketFrameResult>& results,
                           const BracketProgress& progress) {
  const cv::Mat& ref = frames[static_cast<size_t>(reference)].image;
  AlignedBracket aligned;
  aligned.valid = cv::Mat(ref.size(), CV_8U, cv::Scalar(255));
  const int margin = options.sampling.margin;
  if (margin > 0) {
    aligned.valid.setTo(0);
    const cv::Rect inner(margin, margin, ref.cols - 2 * margin, ref.rows - 2 * margin);
    if (inner.width > 0 && inner.height > 0) aligned.valid(inner).setTo(255);
  }
  for (const BracketFrame& frame : frames) {
    if (frame.image.channels() != ref.channels())
      throw InvalidInput("has " + std::to_string(frame.image.channels()) + " channels, " +
                             frames[static_cast<size_t>(reference)].name + " has " + std::to_string(ref.channels()),
                         ErrorSubject::pair, frame.name);
    if (!options.register_frames && frame.image.size() != ref.size())
      throw InvalidInput("differs in size from " + frames[static_cast<size_t>(reference)].name +
                             " (unregistered frames must have the same size)",
                         ErrorSubject::pair, frame.name);
  }
  // Each frame is registered onto the reference independently: one per core (a failure is reported for the first
  // failing frame in order, as a serial loop would).
  // The reference's side of the registration (normalised copy, AKAZE features) is prepared once for the frames of
  // its size (a bracket's frames all are): the same result as registerPair(frame, reference) with a third of its
  // feature detections gone for 4 frames (docs/RESULTS.md#bracket: features were 48 % of a call). With
  // translation_first (the default here) the frames are first aligned by phase correlation + ECC, and the features,
  // the reference's included, are detected only if a frame is not settled that way (handheld with a larger turn).
  const int n = static_cast<int>(frames.size());
  const RegistrationOptions& registration = options.registration;
  RegistrationTarget target;
  if (options.register_frames)
    target = prepareRegistrationTarget(ref, ref.size(), registration, !registration.translation_first);
  const auto same_size = [&](int j) { return frames[static_cast<size_t>(j)].image.size() == ref.size(); };
  std::vector<char> settled(static_cast<size_t>(n), 0);  // char, not bool: written by the jobs concurrently
  settled[static_cast<size_t>(reference)] = 1;
  if (options.register_frames && registration.translation_first)
    detail::runInParallel(n, [&](int j) {
      if (j == reference || !same_size(j)) return;
      if (auto fast = registerByTranslation(frames[static_cast<size_t>(j)].image, target, registration)) {
        results[static_cast<size_t>(j)].registration = *fast;
        settled[static_cast<size_t>(j)] = 1;
      }
    });
  RegistrationOptions full = registration;
  full.translation_first = false;  // tried above
  if (options.register_frames && std::count(settled.begin(), settled.end(), 0) > 0) addTargetFeatures(target, full);
  const std::vector<std::exception_ptr> errors = detail::runInParallel(options.register_frames ? n : 0, [&](int j) {
    const size_t k = static_cast<size_t>(j);
    if (j == reference || settled[k]) return;
    results[k].registration = same_size(j) ? registerPair(frames[k].image, target, full)
                                           : registerPair(frames[k].image, ref, registration);
  });
  for (int j = 0; j < n; ++j) {
    const BracketFrame& frame = frames[static_cast<size_t>(j)];
    if (j == reference || !options.register_frames) {
      aligned.images.push_back(unitFloat(frame.image));
      continue;
    }
    if (errors[static_cast<size_t>(j)]) {
      try {
        std::rethrow_exception(errors[static_cast<size_t>(j)]);
      } catch (const InvalidInput& e) {
        throw InvalidInput("not the same scene as " + frames[static_cast<size_t>(reference)].name + " (" + e.reason() +
                               ")",
                           ErrorSubject::pair, frame.name);
      }
    }
    const RegistrationResult& registration = results[static_cast<size_t>(j)].registration;
    aligned.images.push_back(unitFloat(warpToBlurred(frame.image, registration.homography, ref.size())));
    aligned.valid &= overlapMask(frame.image.size(), registration.homography, ref.size(), std::max(margin, 1));
    if (progress) progress("register", double(j + 1) / double(frames.size()), frame.name);
  }
  return aligned;
}

cv::Mat greyOf(const cv::Mat& unit_image) {
  if (unit_image.channels() == 1) return unit_image;
  cv::Mat grey;
  cv::cvtColor(unit_image, grey, cv::COLOR_BGR2GRAY);
  return grey;
}

// Ranks of v, ties given their mean rank (Spearman's definition: an 8-bit frame has many equal values, whose arbitrary
// order would otherwise add noise to the correlation).
std::vector<double> tiedRanks(const std::vector<float>& v) {
  std::vector<std::pair<float, std::uint32_t>> sorted(v.size());
  for (std::size_t k = 0; k < v.size(); ++k) sorted[k] = {v[k], std::uint32_t(k)};
  std::sort(sorted.begin(), sorted.end());
  std::vector<double> rank(v.size());
  for (std::size_t first = 0; first < sorted.size();) {
    std::size_t last = first;
    while (last + 1 < sorted.size() && sorted[last + 1].first == sorted[first].first) ++last;
    const double mean_rank = 0.5 * double(first + last);
    for (std::size_t k = first; k <= last; ++k) rank[sorted[k].second] = mean_rank;
    first = last + 1;
  }
  return rank;
}

// Spearman rank correlation of two aligned grey frames over the pixels where both are well exposed and `valid`
// (a regular subsample of at most ~40,000 pixels: the verdict needs ρ to ±0.01, not every pixel, and the sort was
// 9 % of a call): the frames of one scene are related by a monotone map (φ and the exposure ratio), so their ranks
// agree (≈ 1 up to noise); another scene gives ≈ 0. NaN with fewer than 200 such pixels.
double rankCorrelation(const cv::Mat& a, const cv::Mat& b, const cv::Mat& valid, double low, double high) {
  std::vector<float> va, vb;
  const int step = std::max(1, int(std::ceil(std::sqrt(double(a.total()) / 40000.0))));
  for (int y = 0; y < a.rows; y += step)
    for (int x = 0; x < a.cols; x += step) {
      const float p = a.at<float>(y, x), q = b.at<float>(y, x);
      if (!valid.at<uchar>(y, x) || p <= low || p >= high || q <= low || q >= high) continue;
      va.push_back(p);
      vb.push_back(q);
    }
  if (va.size() < 200) return std::numeric_limits<double>::quiet_NaN();
  const std::vector<double> ra = tiedRanks(va), rb = tiedRanks(vb);
  double ma = 0, mb = 0;
  for (std::size_t k = 0; k < ra.size(); ++k) ma += ra[k], mb += rb[k];
  ma /= double(ra.size());
  mb /= double(rb.size());
  double sab = 0, saa = 0, sbb = 0;
  for (std::size_t k = 0; k < ra.size(); ++k) {
    sab += (ra[k] - ma) * (rb[k] - mb);
    saa += (ra[k] - ma) * (ra[k] - ma);
    sbb += (rb[k] - mb) * (rb[k] - mb);
  }
  return sab / std::sqrt(saa * sbb);
}

// Each frame against its neighbour in brightness: the same scene, or refused naming the frame.
void requireSameScene(const std::vector<cv::Mat>& greys, const cv::Mat& valid, const std::vector<BracketFrame>& frames,
                      int reference, const BracketCalibrationOptions& options, std::vector<BracketFrameResult>& results) {
  std::vector<std::size_t> order(greys.size());
  std::iota(order.begin(), order.end(), 0);
  std::vector<double> mean(greys.size());
  for (std::size_t j = 0; j < greys.size(); ++j) mean[j] = cv::mean(greys[j], valid)[0];
  std::sort(order.begin(), order.end(), [&](auto a, auto b) { return mean[a] < mean[b]; });
  for (std::size_t k = 1; k < order.size(); ++k) {
    const std::size_t a = order[k - 1], b = order[k];
    const double rho = rankCorrelation(greys[a], greys[b], valid, options.sampling.low, options.sampling.high);
    results[b].scene_correlation = rho;
    if (k == 1) results[a].scene_correlation = rho;
    if (!(rho < options.min_scene_correlation)) continue;  // NaN (too few common pixels): no verdict
    // Blame the frame that is not the reference (or the brighter one).
    const std::size_t blamed = int(b) == reference ? a : b;
    const std::size_t other = blamed == a ? b : a;
    char text[160];
    std::snprintf(text, sizeof text, "not the same scene as %s (rank correlation %.2f of the pixels both expose well, "
                                     "after registration; the same scene gives > %.2f)",
                  frames[other].name.c_str(), rho, options.min_scene_correlation);
    throw InvalidInput(text, ErrorSubject::pair, frames[blamed].name);
  }
}

// Start exposures relative to the reference frame without EXIF: consecutive frames (ordered by mean brightness)
// compared through the EMoR mean curve (estimateExposureRatio on registered pixels), chained.
std::vector<double> exposuresFromImages(const std::vector<cv::Mat>& greys, int reference) {
  const std::size_t n = greys.size();
  std::vector<double> mean(n);
  for (std::size_t j = 0; j < n; ++j) mean[j] = cv::mean(greys[j])[0];
  std::vector<std::size_t> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](auto a, auto b) { return mean[a] < mean[b]; });
  const auto mean_curve = emor::inverseMean();
  const ResponseCurve curve = ResponseCurve::fromSamples(std::vector<double>(mean_curve.begin(), mean_curve.end()));
  std::vector<double> exposure(n, 1.0);
  for (std::size_t k = 1; k < n; ++k) {
    ExposureRatioOptions ratio_options;
    double ratio = 1;
    try {
      ratio = estimateExposureRatio(greys[order[k - 1]], greys[order[k]], curve, ratio_options).ratio;
    } catch (const InvalidInput&) {
      ratio_options.registered = false;  // too few pixels well exposed in both: histogram specification
      ratio = estimateExposureRatio(greys[order[k - 1]], greys[order[k]], curve, ratio_options).ratio;
    }
    exposure[order[k]] = exposure[order[k - 1]] * std::max(ratio, 1.0001);
  }
  const double at_reference = exposure[static_cast<std::size_t>(reference)];
  for (double& e : exposure) e /= at_reference;
  return exposure;
}

// The sampled scene points: position and, per frame, the local mean of each plane (BGR order, or grey).
struct Samples {
  std::vector<cv::Point> positions;
  std::vector<std::vector<cv::Vec3f>> values;  // [point][frame]
  std::vector<float> saturation;               // [point]: pointSaturation
  std::vector<float> roughness;                // [point]: largest local std of the grey over its informative frames
  std::vector<int> brightness_class;           // [point]: its class of scene brightness (0 … classes−1)
  cv::Vec3f limit{1, 1, 1};                    // per plane: a value at or above this is clipped (clippingLimits)
};

// Whether plane `plane` of point p in frame j is an exact observation: above the noise floor, below the plane's
// clipping limit.
bool isObservation(const Samples& samples, std::size_t p, std::size_t j, int plane, const BracketSamplingOptions& options) {
  const float z = samples.values[p][j][plane];
  return z >= options.low && z < samples.limit[plane];
}

// Each plane's clipping limit, measured where the frames show it: a channel is clipped where its value stops rising
// with the exposure. For every point and pair of frames neighbouring in exposure (the brighter ≥ 5 % more exposed),
// a value above `plateau_floor` that the brighter frame does not exceed by more than 0.5 % is on the plateau; with
// enough such values (≥ max(5, 1 % of the points)) the limit is their lowest decile minus 0.01, never above `top`.
// Cameras differ: many JPEGs clip at code 255, some (the Nikon E995 window set) at ≈ 0.97–0.98, so a fixed mean
// limit either drops the unclipped top of a channel (blue of a white patch at 0.97–0.99 on the Middlebury cameras)
// or lets a lower plateau in (docs/RESULTS.md#bracket, issue 21's fourth round).
void clippingLimits(Samples& samples, const std::vector<double>& exposure, const BracketSamplingOptions& options) {
  std::vector<std::size_t> order(exposure.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return exposure[a] < exposure[b]; });
  const std::size_t enough = std::max<std::size_t>(5, samples.values.size() / 100);
  for (int plane = 0; plane < 3; ++plane) {
    std::vector<float> plateau;
    for (const auto& values : samples.values)
      for (std::size_t k = 1; k < order.size(); ++k) {
        if (!(exposure[order[k]] >= 1.05 * exposure[order[k - 1]])) continue;
        const float dark = values[order[k - 1]][plane], bright = values[order[k]][plane];
        if (dark > options.plateau_floor && bright <= dark * 1.005f) plateau.push_back(dark);
      }
    float limit = float(options.top);
    if (plateau.size() >= enough) {
      std::nth_element(plateau.begin(), plateau.begin() + long(plateau.size() / 10), plateau.end());
      limit = std::min(limit, plateau[plateau.size() / 10] - 0.01f);
    }
    samples.limit[plane] = std::max(limit, float(options.plateau_floor));
  }
}

// A point's colour saturation, (max − min)/max over its planes, in the frame where its brightest plane is highest
// while below `high` (the least noisy unclipped view of its colour; a dark view's noise would make any colour look
// vivid). A camera's JPEG pipeline maps saturated colours further (gamut mapping and saturation after the tone
// curve; Kim et al., "A new in-camera imaging model for color computer vision", PAMI 2012), so z_pj = f(E_p t_j)
// with one curve per channel holds for near-neutral points, not for vivid ones.
float pointSaturation(const std::vector<cv::Vec3f>& frames, double high) {
  float best = -1, saturation = 0;
  for (const cv::Vec3f& v : frames) {
    const float brightest = std::max({v[0], v[1], v[2]}), darkest = std::min({v[0], v[1], v[2]});
    if (brightest >= high || brightest <= best) continue;
    best = brightest;
    saturation = brightest > 0 ? (brightest - darkest) / brightest : 0.0f;
  }
  return saturation;
}

Samples samplePoints(const AlignedBracket& aligned, const BracketSamplingOptions& options) {
  const cv::Size size = aligned.images.front().size();
  const cv::Size window(options.window, options.window);
  std::vector<cv::Mat> means, grey_means, deviations;  // per frame: local mean of the planes, of the grey, its std
  for (const cv::Mat& image : aligned.images) {
    cv::Mat mean, grey_mean, grey_sq;
    cv::boxFilter(image, mean, CV_32F, window, {-1, -1}, true, cv::BORDER_REFLECT);
    const cv::Mat grey = greyOf(image);
    cv::boxFilter(grey, grey_mean, CV_32F, window, {-1, -1}, true, cv::BORDER_REFLECT);
    cv::boxFilter(grey.mul(grey), grey_sq, CV_32F, window, {-1, -1}, true, cv::BORDER_REFLECT);
    cv::Mat variance = grey_sq - grey_mean.mul(grey_mean);
    cv::max(variance, 0, variance);
    cv::Mat deviation;
    cv::sqrt(variance, deviation);
    means.push_back(mean);
    grey_means.push_back(grey_mean);
    deviations.push_back(deviation);
  }
  // Candidates on a regular grid inside the valid area: brightness key (Σ_j grey mean, monotone in E) and the
  // largest local std over the frames where the point is neither dark nor clipped (there the std is meaningless).
  const double step = std::max(1.0, std::sqrt(double(size.area()) / options.candidates));
  struct Candidate {
    cv::Point p;
    float key, roughness;
  };
  std::vector<Candidate> candidates;
  for (double y = step / 2; y < size.height; y += step)
    for (double x = step / 2; x < size.width; x += step) {
      const cv::Point p{int(x), int(y)};
      if (!aligned.valid.at<uchar>(p)) continue;
      float key = 0, roughness = 0;
      int informative = 0;
      for (std::size_t j = 0; j < means.size(); ++j) {
        const float g = grey_means[j].at<float>(p);
        key += g;
        if (g > options.low && g < options.high) {
          roughness = std::max(roughness, deviations[j].at<float>(p));
          ++informative;
        }
      }
      if (informative >= 2) candidates.push_back({p, key, roughness});
    }
  if (candidates.size() < 10) throw InvalidInput("too few positions are well exposed in two frames", ErrorSubject::pair);
  // Brightness classes of equal width in the key; in each, the flattest fraction, drawn evenly.
  float lo = candidates.front().key, hi = lo;
  for (const auto& c : candidates) lo = std::min(lo, c.key), hi = std::max(hi, c.key);
  const int classes = options.brightness_classes;
  std::vector<std::vector<Candidate>> bins(static_cast<std::size_t>(classes));
  for (const auto& c : candidates) {
    const int b = hi > lo ? std::min(classes - 1, int((c.key - lo) / (hi - lo) * classes)) : 0;
    bins[static_cast<std::size_t>(b)].push_back(c);
  }
  std::mt19937_64 rng(options.seed);
  std::vector<Candidate> chosen;
  std::vector<int> chosen_class;
  int remaining_bins = 0;
  for (const auto& bin : bins) remaining_bins += !bin.empty();
  int budget = options.points;
  for (auto& bin : bins) {
    if (bin.empty()) continue;
    const int quota = budget / std::max(remaining_bins, 1);
    --remaining_bins;
    std::sort(bin.begin(), bin.end(), [](const auto& a, const auto& b) { return a.roughness < b.roughness; });
    const std::size_t flat = std::max<std::size_t>(1, std::size_t(std::ceil(bin.size() * options.flat_fraction)));
    std::vector<Candidate> pool(bin.begin(), bin.begin() + long(flat));
    std::shuffle(pool.begin(), pool.end(), rng);
    const int take = std::min<int>(quota, int(pool.size()));
    chosen.insert(chosen.end(), pool.begin(), pool.begin() + take);
    chosen_class.insert(chosen_class.end(), std::size_t(take), int(&bin - bins.data()));
    budget -= take;
  }
  Samples samples;
  samples.brightness_class = chosen_class;
  const auto at = [](const cv::Mat& m, cv::Point p) {
    if (m.channels() == 1) return cv::Vec3f::all(m.at<float>(p));
    return m.at<cv::Vec3f>(p);
  };
  for (const Candidate& c : chosen) {
    const cv::Point p = c.p;
    std::vector<cv::Vec3f> v;
    for (const cv::Mat& m : means) v.push_back(at(m, p));
    samples.positions.push_back(p);
    samples.saturation.push_back(pointSaturation(v, options.high));
    samples.roughness.push_back(c.roughness);
    samples.values.push_back(std::move(v));
  }
  return samples;
}

// Weight of an observation t_j = s_p φ(z): the residual in exposure units is relative to t_j, and for a camera-like
// φ (local exponent γ) a constant noise σ on z gives a relative irradiance error ≈ γσ/z, so w ∝ (z/t_j)²; tapered to
// 0.1 over the last 0.1 below the clipping limit (a channel about to clip first bends, then saturates).
double observationWeight(double z, double exposure, double high) {
  const double taper = std::clamp((high - z) / 0.1, 0.1, 1.0);
  return taper * (z / exposure) * (z / exposure);
}

// `point_of_group` (optional): the scene point (index into samples) behind each group.
std::vector<ScaledObservation> channelObservations(const Samples& samples, int plane, const std::vector<double>& exposure,
                                                   const BracketSamplingOptions& options, int& points,
                                                   std::vector<std::size_t>* point_of_group = nullptr) {
  std::vector<ScaledObservation> observations;
  points = 0;
  for (std::size_t p = 0; p < samples.values.size(); ++p) {
    if (samples.saturation[p] > options.max_saturation) continue;  // vivid: rendered beyond the channel's curve
    std::vector<ScaledObservation> own;
    for (std::size_t j = 0; j < exposure.size(); ++j) {
      if (!isObservation(samples, p, j, plane, options)) continue;
      const double z = samples.values[p][j][plane];
      ScaledObservation o;
      o.x = z;
      o.y = exposure[j];
      o.group = points;
      // Folds by brightness class, not by point: the points of one flat region (a wall, a chart patch) are near
      // copies of each other, so holding out every other point tests the curve on the intensities it was fitted
      // on and K follows the region's own misfit; holding out every other brightness class asks the curve for
      // values between those it saw (docs/RESULTS.md#bracket, issue 21's fourth round).
      o.fold = samples.brightness_class[p] % 2;
      o.weight = observationWeight(z, exposure[j], options.high);
      own.push_back(o);
    }
    if (own.size() < 2) continue;  // one value of a point says nothing about φ (its own scale absorbs it)
    observations.insert(observations.end(), own.begin(), own.end());
    if (point_of_group) point_of_group->push_back(p);
    ++points;
  }
  return observations;
}

// Inner frames' exposures: the median over points and channels of φ(z_pj)·s_p (= t_j when the model holds),
// within ±max_deviation stops of the start; the darkest and brightest frames keep theirs (the span).
void refineExposures(const Samples& samples, const std::vector<BracketChannelResult>& channels,
                     const std::vector<int>& planes, const std::vector<double>& start, double max_deviation,
                     const BracketSamplingOptions& options, std::vector<double>& exposure) {
  const auto [darkest, brightest] = std::minmax_element(start.begin(), start.end());
  for (std::size_t j = 0; j < exposure.size(); ++j) {
    if (&start[j] == &*darkest || &start[j] == &*brightest) continue;
    std::vector<double> estimates;
    for (std::size_t ci = 0; ci < channels.size(); ++ci) {
      const ScaledFitResult& fit = channels[ci].fit;
      int group = 0;
      for (std::size_t p = 0; p < samples.values.size(); ++p) {
        if (samples.saturation[p] > options.max_saturation) continue;
        int usable = 0;
        for (std::size_t k = 0; k < exposure.size(); ++k) {
          usable += isObservation(samples, p, k, planes[ci], options);
        }
        if (usable < 2) continue;  // the same points, in the same order, as channelObservations
        const double z = samples.values[p][j][planes[ci]];
        const double s = fit.scales[static_cast<std::size_t>(group)];
        ++group;
        if (!isObservation(samples, p, j, planes[ci], options) || !(s > 0)) continue;
        estimates.push_back(s * interpolateSamples(fit.inverse, z));
      }
    }
    if (estimates.size() < 10) continue;
    std::nth_element(estimates.begin(), estimates.begin() + long(estimates.size() / 2), estimates.end());
    const double estimate = estimates[estimates.size() / 2];
    const double bound = std::pow(2.0, max_deviation);
    if (estimate > 0) exposure[j] = std::clamp(estimate, start[j] / bound, start[j] * bound);
  }
}

BracketChannelResult fitChannel(const Samples& samples, int channel, int plane, const std::vector<double>& exposure,
                                const BracketCalibrationOptions& options, int terms) {
  BracketChannelResult result;
  result.channel = channel;
  const std::vector<ScaledObservation> observations =
      channelObservations(samples, plane, exposure, options.sampling, result.points);
  if (result.points < 8)
    throw InvalidInput("channel " + channelName(channel) + ": only " + std::to_string(result.points) +
                           " scene points are well exposed in two frames (need ≥ 8; are the exposures too far apart?)",
                       ErrorSubject::pair);
  ScaledFitOptions fit_options = options.fit;
  if (terms > 0) fit_options.terms = terms;
  result.fit = fitScaledInverse(observations, fit_options);
  return result;
}

// The fit on the flatter half of the scene points (local roughness at most its median): a point's value is the mean of
// a window of intensities, and mean f(E) ≠ f(mean E) where the window holds texture (Jensen), a bias that resampling
// the same points cannot see but that shrinks on flatter points, so the difference is the band's model term for it.
std::vector<double> flatterHalfFit(const std::vector<ScaledObservation>& observations,
                                   const std::vector<std::size_t>& point_of_group, const Samples& samples,
                                   const BracketCalibrationOptions& options, int terms) {
  std::vector<float> roughness;
  for (std::size_t p : point_of_group) roughness.push_back(samples.roughness[p]);
  if (roughness.size() < 8) return {};
  std::nth_element(roughness.begin(), roughness.begin() + long(roughness.size() / 2), roughness.end());
  const float median = roughness[roughness.size() / 2];
  std::vector<ScaledObservation> flatter;
  std::map<int, int> group_of;
  for (ScaledObservation o : observations) {
    if (samples.roughness[point_of_group[static_cast<std::size_t>(o.group)]] > median) continue;
    o.group = group_of.emplace(o.group, static_cast<int>(group_of.size())).first->second;
    flatter.push_back(o);
  }
  try {
    return fitScaledInverseFixed(flatter, terms, options.fit).inverse;
  } catch (const InvalidInput&) {
    return {};  // too few flat observations: no texture term
  }
}

// Each channel's band (scaled_fit_band.hpp) on the final exposures' observations, one cluster per scene point, with
// the flatter half's fit as a model term.
void addBands(const Samples& samples, const std::vector<int>& planes, const std::vector<double>& exposure,
              const BracketCalibrationOptions& options, std::vector<BracketChannelResult>& channels) {
  if (options.band.replicates == 0) return;
  for (std::size_t ci = 0; ci < channels.size(); ++ci) {
    int points = 0;
    std::vector<std::size_t> point_of_group;
    const std::vector<ScaledObservation> observations =
        channelObservations(samples, planes[ci], exposure, options.sampling, points, &point_of_group);
    std::vector<int> cluster(observations.size());
    std::transform(observations.begin(), observations.end(), cluster.begin(),
                   [](const ScaledObservation& o) { return o.group; });
    std::vector<std::vector<double>> alternatives;
    if (std::vector<double> flatter =
            flatterHalfFit(observations, point_of_group, samples, options, channels[ci].fit.terms);
        !flatter.empty())
      alternatives.push_back(std::move(flatter));
    channels[ci].band =
        scaledFitBand(observations, cluster, options.fit, channels[ci].fit, options.band, alternatives);
  }
}

// The frames' count, planes and exposures checked; returns whether their exposures are known (all or none).
bool checkFrames(const std::vector<BracketFrame>& frames) {
  if (frames.size() < 2) throw InvalidInput("a bracket needs at least 2 frames", ErrorSubject::pair);
  int known = 0;
  for (const auto& f : frames) {
    if (f.image.empty()) throw InvalidInput("empty image", ErrorSubject::pair, f.name);
    if (f.image.channels() != 1 && f.image.channels() != 3)
      throw InvalidInput("must be grey or colour (1 or 3 channels)", ErrorSubject::pair, f.name);
    known += f.exposure > 0;
  }
  if (known != 0 && known != int(frames.size()))
    throw InvalidInput("exposures are known for " + std::to_string(known) + " of " + std::to_string(frames.size()) +
                           " frames; give all or none",
                       ErrorSubject::pair);
  return known > 0;
}

// The reference frame — the middle exposure (given), else the middle frame; the others are registered onto it —
// and one result row per frame, with a warning for frames of the same exposure.
int listFrames(const std::vector<BracketFrame>& frames, bool known, BracketCalibrationResult& result) {
  std::vector<int> order(frames.size());
  std::iota(order.begin(), order.end(), 0);
  if (known)
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return frames[a].exposure < frames[b].exposure; });
  const int reference = order[order.size() / 2];
  for (std::size_t j = 0; j < frames.size(); ++j) {
    BracketFrameResult f;
    f.name = frames[j].name;
    f.nominal_exposure = frames[j].exposure;
    f.reference = int(j) == reference;
    f.registration.method = f.reference ? "reference" : "none";
    result.frames.push_back(f);
  }
  if (known)
    for (std::size_t j = 0; j < frames.size(); ++j)
      for (std::size_t k = 0; k < j; ++k)
        if (std::abs(std::log(frames[j].exposure / frames[k].exposure)) < std::log(1.05))
          result.warnings.push_back(frames[j].name + " and " + frames[k].name +
                                    " have the same exposure: the pair adds no range, only noise averaging");
  return reference;
}

// The start exposures relative to the reference frame: EXIF's when known, else estimated from the images.
std::vector<double> startExposures(const std::vector<BracketFrame>& frames, bool known, int reference,
                                   const std::vector<cv::Mat>& greys, BracketCalibrationResult& result) {
  std::vector<double> start(frames.size());
  if (known) {
    for (std::size_t j = 0; j < frames.size(); ++j) start[j] = frames[j].exposure / frames[static_cast<size_t>(reference)].exposure;
    return start;
  }
  result.warnings.push_back(
      "no EXIF exposures: the start exposures come from the images through the EMoR mean curve, one free scale "
      "per frame; the curve's overall exponent rests on that estimate (the bracket alone cannot fix it, Grossberg & "
      "Nayar 2003)");
  return exposuresFromImages(greys, reference);
}

// The channels' fits alternated with the exposures' refinement (options.exposure_rounds, with ≥ 3 frames); the
// number of EMoR terms is chosen by cross-validation in the first round and kept in the refits. Returns the
// refined exposures.
std::vector<double> fitChannelsAndExposures(const Samples& samples, const std::vector<int>& channels,
                                            const std::vector<int>& planes, const std::vector<double>& start,
                                            std::size_t frame_count, const BracketCalibrationOptions& options,
                                            const BracketProgress& progress, BracketCalibrationResult& result) {
  std::vector<double> exposure = start;
  const int rounds = frame_count > 2 ? options.exposure_rounds : 0;
  std::vector<int> terms(channels.size(), 0);
  for (int round = 0; round <= rounds; ++round) {
    result.channels.clear();
    for (std::size_t ci = 0; ci < channels.size(); ++ci) {
      result.channels.push_back(fitChannel(samples, channels[ci], planes[ci], exposure, options, terms[ci]));
      terms[ci] = result.channels.back().fit.terms;
      if (progress)
        progress("fit", double(round * channels.size() + ci + 1) / double((rounds + 1) * channels.size()),
                 channelName(channels[ci]) + (round > 0 ? " (refined exposures)" : ""));
    }
    if (round < rounds)
      refineExposures(samples, result.channels, planes, start, options.max_exposure_deviation, options.sampling,
                      exposure);
  }
  return exposure;
}

// Each channel's GGCM equivalent, and a warning where the data cover less than half of [0, 1].
void describeChannels(const BracketCalibrationOptions& options, BracketCalibrationResult& result) {
  for (auto& channel : result.channels) {
    const ggcm::FitResult g = ggcm::fitInverse(channel.fit.inverse, options.ggcm);
    channel.ggcm = g.model;
    channel.ggcm_valid = g.valid;
    channel.ggcm_rmse = curveRmse(sampleInverse(g.model, kCurveSamples), channel.fit.inverse);
    if (channel.fit.covered_range.second - channel.fit.covered_range.first < 0.5)
      result.warnings.push_back("channel " + channelName(channel.channel) + ": data cover only x in [" +
                                std::to_string(channel.fit.covered_range.first) + ", " +
                                std::to_string(channel.fit.covered_range.second) +
                                "]; the rest of the curve is the EMoR model's extrapolation");
  }
}

}  // namespace

BracketCalibrationResult calibrateBracket(const std::vector<BracketFrame>& frames,
                                          const BracketCalibrationOptions& options, const BracketProgress& progress) {
  options.check();
  const bool known = checkFrames(frames);
  BracketCalibrationResult result;
  result.exposure_source = known ? "exif" : "images";
  const int reference = listFrames(frames, known, result);

  // Working copies no larger than max_dimension (registration and sampling at that size).
  double scale = 1;
  std::vector<BracketFrame> working = frames;
  if (options.max_dimension > 0) {
    const cv::Size size = frames[static_cast<std::size_t>(reference)].image.size();
    scale = std::min(1.0, double(options.max_dimension) / std::max(size.width, size.height));
    if (scale < 1)
      for (auto& f : working) cv::resize(f.image, f.image, cv::Size(), scale, scale, cv::INTER_AREA);
  }
  if (progress) progress("register", 0, "");
  const AlignedBracket aligned = alignFrames(working, reference, options, result.frames, progress);
  std::vector<cv::Mat> greys;
  for (const cv::Mat& image : aligned.images) greys.push_back(greyOf(image));
  requireSameScene(greys, aligned.valid, frames, reference, options, result.frames);
  const std::vector<double> start = startExposures(frames, known, reference, greys, result);

  if (progress) progress("sample", 0, "");
  Samples samples = samplePoints(aligned, options.sampling);
  clippingLimits(samples, start, options.sampling);
  result.points = int(samples.positions.size());
  for (const cv::Point& p : samples.positions) result.point_positions.emplace_back(int(p.x / scale), int(p.y / scale));

  const bool grey = aligned.images.front().channels() == 1;
  std::vector<int> channels, planes;
  for (int c : options.channels)
    if (!grey || c == 1) channels.push_back(c), planes.push_back(grey ? 0 : 2 - c);
  if (channels.empty()) channels.push_back(1), planes.push_back(0);

  const std::vector<double> exposure =
      fitChannelsAndExposures(samples, channels, planes, start, frames.size(), options, progress, result);
  for (std::size_t j = 0; j < frames.size(); ++j) {
    result.frames[j].start_exposure = start[j];
    result.frames[j].fitted_exposure = exposure[j];
  }
  addBands(samples, planes, exposure, options, result.channels);
  describeChannels(options, result);
  return result;
}

}  // namespace crfcal
