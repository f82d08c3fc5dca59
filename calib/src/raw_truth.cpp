#include "crfcal/raw_truth.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <limits>
#include <mutex>
#include <optional>
#include <sstream>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "image_units.hpp"

namespace crfcal {
namespace {

using detail::fullScale;

// Planes in R, G, B order (one plane for grey), CV_32F in [0,1] of full scale.
std::vector<cv::Mat> unitPlanes(const cv::Mat& image) {
  std::vector<cv::Mat> planes;
  cv::split(image, planes);
  if (planes.size() == 4) planes.pop_back();  // alpha
  if (planes.size() == 3) std::swap(planes[0], planes[2]);
  const double top = fullScale(image);
  for (auto& p : planes) p.convertTo(p, CV_32F, 1.0 / top);
  return planes;
}

// Clip level of one native plane (unit scale, `top` = full-scale code), or nullopt: the plane's maximum when at least
// `pile` of its pixels sit within `tolerance` (and at least one code) of it — a pile-up at the top is clipping, a few
// bright pixels are not.
std::optional<double> clipLevel(const cv::Mat& plane, double top, double pile, double tolerance) {
  double lo = 0, hi = 0;
  cv::minMaxLoc(plane, &lo, &hi);
  if (!(hi > 0)) return std::nullopt;
  const double level = hi - std::max(tolerance, top > 1 ? 1.0 / top : 0.0) - 1e-6;
  const double count = cv::countNonZero(plane >= level);
  if (count < pile * static_cast<double>(plane.total())) return std::nullopt;
  return level;
}

// Rank equalisation of a grey float image at 4096 levels (photometric normalisation that keeps the detail of a dark
// linear frame, which an 8-bit conversion would crush into a few codes).
cv::Mat equalise(const cv::Mat& grey) {
  double lo = 0, hi = 0;
  cv::minMaxLoc(grey, &lo, &hi);
  if (!(hi > lo)) return cv::Mat::zeros(grey.size(), CV_32F);
  constexpr int kLevels = 4096;
  std::vector<double> cdf(kLevels + 1, 0.0);
  const double scale = (kLevels - 1) / (hi - lo);
  for (int y = 0; y < grey.rows; ++y) {
    const float* row = grey.ptr<float>(y);
    for (int x = 0; x < grey.cols; ++x) cdf[static_cast<size_t>((row[x] - lo) * scale) + 1] += 1;
  }
  for (int i = 1; i <= kLevels; ++i) cdf[i] += cdf[i - 1];
  for (auto& v : cdf) v /= cdf.back();
  cv::Mat out(grey.size(), CV_32F);
  for (int y = 0; y < grey.rows; ++y) {
    const float* in = grey.ptr<float>(y);
    float* o = out.ptr<float>(y);
    for (int x = 0; x < grey.cols; ++x) {
      const double p = (in[x] - lo) * scale;
      const auto i = std::min(static_cast<int>(p), kLevels - 1);
      o[x] = static_cast<float>(cdf[static_cast<size_t>(i)] + (p - i) * (cdf[static_cast<size_t>(i) + 1] - cdf[static_cast<size_t>(i)]));
    }
  }
  return out;
}

cv::Mat greyOf(const std::vector<cv::Mat>& planes) {
  if (planes.size() == 1) return planes[0];
  return 0.299 * planes[0] + 0.587 * planes[1] + 0.114 * planes[2];
}

cv::Mat turn(const cv::Mat& m, int degrees) {
  if (degrees == 0) return m;
  cv::Mat out;
  cv::rotate(m, out, degrees == 90 ? cv::ROTATE_90_CLOCKWISE : degrees == 180 ? cv::ROTATE_180 : cv::ROTATE_90_COUNTERCLOCKWISE);
  return out;
}

// Shrinks a native 8-bit mask to `size` keeping every set pixel (max-pooling: dilate by the scale, then nearest).
cv::Mat shrinkMask(const cv::Mat& mask, cv::Size size) {
  if (mask.size() == size) return mask.clone();
  const int r = static_cast<int>(std::ceil(std::max(double(mask.cols) / size.width, double(mask.rows) / size.height) / 2));
  cv::Mat grown = mask, out;
  if (r > 0) cv::dilate(mask, grown, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 1, 2 * r + 1)));
  cv::resize(grown, out, size, 0, 0, cv::INTER_NEAREST);
  return out;
}

cv::Mat resizeTo(const cv::Mat& m, cv::Size size) {
  if (m.size() == size) return m.clone();
  cv::Mat out;
  const bool shrink = size.area() < m.size().area();
  cv::resize(m, out, size, 0, 0, shrink ? cv::INTER_AREA : cv::INTER_LINEAR);
  return out;
}

double median(std::vector<float>& v) {
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  double m = *mid;
  if (v.size() % 2 == 0) m = 0.5 * (m + *std::max_element(v.begin(), mid));
  return m;
}

double interpolate(const std::vector<double>& phi, double x) { return interpolateSamples(phi, x); }

struct Pixel {
  std::array<float, 3> jpeg{};    // R, G, B (or grey in [1])
  std::array<float, 3> linear{};  // R, G, B (or grey in [0])
  std::uint8_t fold = 0;
  std::uint8_t jpeg_contaminated = 0;  // bit c: a clipped JPEG pixel of channel c within the low-pass support
  std::uint8_t jpeg_plateau = 0;       // bit c: JPEG channel c clipped here
  bool linear_contaminated = false;    // any linear channel clipped within the support
  std::uint8_t linear_plateau = 0;     // bit k: linear plane k clipped here
};

struct ChannelJob {
  std::string name;
  int jpeg_index = 0;  // index into Pixel::jpeg
};

// Fit of one channel with a given mixing row: binned observations → fitScaledInverse.
struct ChannelFit {
  ScaledFitResult fit;
  int bins = 0;
  long long exact = 0, censored = 0;
};

ChannelFit fitChannel(const std::vector<Pixel>& pixels, const ChannelJob& job, const std::vector<double>& mix,
                      double jpeg_clip, const RawTruthOptions& options, int fixed_terms) {
  const int c = job.jpeg_index;
  const int planes = static_cast<int>(mix.size());
  constexpr int kFolds = 4;
  const int bins = options.bins;
  enum { kExact = 0, kAtMost = 1, kAtLeast = 2 };
  // (kind, fold, bin) → y values and Σx.
  std::vector<std::vector<float>> values(static_cast<size_t>(3 * kFolds * bins));
  std::vector<double> sum_x(values.size(), 0.0);
  ChannelFit out;
  for (const Pixel& p : pixels) {
    const double x = p.jpeg[static_cast<size_t>(c)];
    double y = 0;
    for (int k = 0; k < planes; ++k) y += mix[static_cast<size_t>(k)] * p.linear[static_cast<size_t>(k)];
    const bool jc = (p.jpeg_contaminated >> c) & 1, jp = (p.jpeg_plateau >> c) & 1;
    int kind = -1;
    double xo = x;
    if (!jc && !p.linear_contaminated && x >= options.dark_limit) {
      kind = kExact;
    } else if (jp && !p.linear_contaminated) {
      kind = kAtMost;  // JPEG clipped: the true intensity is ≥ the clip level, so s·φ(clip) ≤ y
      xo = jpeg_clip;
    } else if (p.linear_plateau && !jc && x >= options.dark_limit) {
      // RAW clipped: the true linear value is ≥ the recorded one as long as the clipped planes enter with w ≥ 0.
      bool positive = true;
      for (int k = 0; k < planes; ++k)
        if (((p.linear_plateau >> k) & 1) && mix[static_cast<size_t>(k)] < 0) positive = false;
      if (positive) kind = kAtLeast;
    }
    if (kind < 0) continue;
    const int bin = std::clamp(static_cast<int>(xo * bins), 0, bins - 1);
    const size_t key = static_cast<size_t>((kind * kFolds + p.fold) * bins + bin);
    values[key].push_back(static_cast<float>(y));
    sum_x[key] += xo;
    (kind == kExact ? out.exact : out.censored) += 1;
  }
  std::vector<ScaledObservation> obs;
  for (int kind = 0; kind < 3; ++kind)
    for (int fold = 0; fold < kFolds; ++fold)
      for (int bin = 0; bin < bins; ++bin) {
        const size_t key = static_cast<size_t>((kind * kFolds + fold) * bins + bin);
        auto& v = values[key];
        if (static_cast<int>(v.size()) < options.min_bin_pixels) continue;
        const double y = median(v);
        if (!(y > 0)) continue;
        ScaledObservation o;
        o.kind = kind == kExact ? ScaledObservation::Kind::Exact
                 : kind == kAtMost ? ScaledObservation::Kind::AtMost
                                   : ScaledObservation::Kind::AtLeast;
        o.x = std::clamp(sum_x[key] / static_cast<double>(v.size()), 0.0, 1.0);
        o.y = y;
        o.fold = fold;
        o.weight = static_cast<double>(v.size());
        obs.push_back(o);
      }
  int exact_bins = 0, folds_seen = 0;
  std::array<bool, kFolds> seen{};
  for (const auto& o : obs)
    if (o.kind == ScaledObservation::Kind::Exact) {
      ++exact_bins;
      seen[static_cast<size_t>(o.fold)] = true;
    }
  for (bool s : seen) folds_seen += s;
  if (exact_bins < 8)
    throw InvalidInput("too few flat, unclipped pixels to measure the response of channel " + job.name + " (" +
                       std::to_string(out.exact) + " pixels in " + std::to_string(exact_bins) + " JPEG levels)");
  out.bins = static_cast<int>(obs.size());
  if (fixed_terms > 0) out.fit = fitScaledInverseFixed(obs, fixed_terms, options.fit);
  else if (options.fit.terms > 0 || folds_seen < 2) {
    ScaledFitOptions fixed = options.fit;
    out.fit = fitScaledInverseFixed(obs, fixed.terms > 0 ? fixed.terms : std::min(3, fixed.max_terms), fixed);
  } else {
    out.fit = fitScaledInverse(obs, options.fit);
  }
  return out;
}

// M_c ← argmin Σ (φ(x_i) − M_c·L_i)² + ridge, over the exact pixels (step 5).
std::vector<double> fitMix(const std::vector<Pixel>& pixels, const ChannelJob& job, const std::vector<double>& mix,
                           const ScaledFitResult& fit, const RawTruthOptions& options) {
  const int c = job.jpeg_index;
  const int planes = static_cast<int>(mix.size());
  const double s = fit.scales.empty() || !(fit.scales[0] > 0) ? 1.0 : fit.scales[0];
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(planes, planes);
  Eigen::VectorXd b = Eigen::VectorXd::Zero(planes);
  for (const Pixel& p : pixels) {
    const double x = p.jpeg[static_cast<size_t>(c)];
    if (((p.jpeg_contaminated >> c) & 1) || p.linear_contaminated || x < options.dark_limit) continue;
    Eigen::VectorXd l(planes);
    for (int k = 0; k < planes; ++k) l[k] = p.linear[static_cast<size_t>(k)];
    A += l * l.transpose();
    b += interpolate(fit.inverse, x) * l;
  }
  Eigen::VectorXd anchor(planes);
  for (int k = 0; k < planes; ++k) anchor[k] = mix[static_cast<size_t>(k)] / s;
  const double lambda = options.matrix_ridge * A.trace() / planes;
  A += lambda * Eigen::MatrixXd::Identity(planes, planes);
  b += lambda * anchor;
  const Eigen::VectorXd m = A.ldlt().solve(b);
  if (!m.allFinite()) return std::vector<double>(anchor.data(), anchor.data() + planes);
  return std::vector<double>(m.data(), m.data() + planes);
}

// Per-pixel diagnostics of the final fit and the effective exponent.
void diagnose(const std::vector<Pixel>& pixels, const ChannelJob& job, RawTruthChannel& out,
              const RawTruthOptions& options) {
  const int c = job.jpeg_index;
  const int planes = static_cast<int>(out.mix.size());
  const double s = out.fit.scales.empty() || !(out.fit.scales[0] > 0) ? 1.0 : out.fit.scales[0];
  double sum_y = 0, sum_yy = 0, sum_rr = 0;
  long long n = 0;
  for (const Pixel& p : pixels) {
    const double x = p.jpeg[static_cast<size_t>(c)];
    if (((p.jpeg_contaminated >> c) & 1) || p.linear_contaminated || x < options.dark_limit) continue;
    double y = 0;
    for (int k = 0; k < planes; ++k) y += out.mix[static_cast<size_t>(k)] * p.linear[static_cast<size_t>(k)];
    const double r = y - s * interpolate(out.fit.inverse, x);
    sum_y += y;
    sum_yy += y * y;
    sum_rr += r * r;
    ++n;
  }
  out.pixels = n;
  if (n > 0) {
    const double var = sum_yy / n - (sum_y / n) * (sum_y / n);
    out.pixel_rmse = std::sqrt(sum_rr / n) / s;
    out.explained = var > 0 ? 1 - (sum_rr / n) / var : 0;
  }
  // Effective exponent: slope of log φ against log x over the covered range above gamma_from (φ > 0); not measured
  // when that part is narrower than gamma_span.
  const auto [lo, hi] = out.fit.covered_range;
  const double from = std::max(lo, options.gamma_from);
  out.effective_gamma = std::numeric_limits<double>::quiet_NaN();
  if (hi - from < options.gamma_span) return;
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int m = 0;
  for (int i = 1; i < kCurveSamples; ++i) {
    const double x = double(i) / (kCurveSamples - 1);
    if (x < from || x > hi) continue;
    const double phi = out.fit.inverse[static_cast<size_t>(i)];
    if (!(phi > 1e-9)) continue;
    const double u = std::log(x), v = std::log(phi);
    sx += u;
    sy += v;
    sxx += u * u;
    sxy += u * v;
    ++m;
  }
  const double d = m * sxx - sx * sx;
  if (m >= 2 && d > 0) out.effective_gamma = (m * sxy - sx * sy) / d;
}

}  // namespace

void RawTruthOptions::check() const {
  registration.check();
  fit.check();
  if (max_dimension < 64) throw InvalidInput("raw truth: max_dimension must be ≥ 64");
  if (!(smoothing_sigma >= 0 && smoothing_sigma <= 10)) throw InvalidInput("raw truth: smoothing_sigma must be in [0, 10]");
  if (flat_radius < 0 || flat_radius > 20) throw InvalidInput("raw truth: flat_radius must be in 0..20");
  if (!(flat_quantile > 0 && flat_quantile <= 1)) throw InvalidInput("raw truth: flat_quantile must be in (0, 1]");
  if (border < 0) throw InvalidInput("raw truth: border must be ≥ 0");
  if (!(clip_pile > 0 && clip_pile < 1)) throw InvalidInput("raw truth: clip_pile must be in (0, 1)");
  if (!(clip_tolerance >= 0 && clip_tolerance < 0.1)) throw InvalidInput("raw truth: clip_tolerance must be in [0, 0.1)");
  if (!(dark_limit >= 0 && dark_limit < 0.5)) throw InvalidInput("raw truth: dark_limit must be in [0, 0.5)");
  if (bins < 16 || bins > 4096) throw InvalidInput("raw truth: bins must be in 16..4096");
  if (min_bin_pixels < 1) throw InvalidInput("raw truth: min_bin_pixels must be ≥ 1");
  if (fold_grid < 2 || fold_grid > 16) throw InvalidInput("raw truth: fold_grid must be in 2..16");
  if (matrix_rounds < 0 || matrix_rounds > 20) throw InvalidInput("raw truth: matrix_rounds must be in 0..20");
  if (!(matrix_ridge >= 0)) throw InvalidInput("raw truth: matrix_ridge must be ≥ 0");
  if (max_pixels < 1000) throw InvalidInput("raw truth: max_pixels must be ≥ 1000");
  if (!(min_explained <= 1)) throw InvalidInput("raw truth: min_explained must be ≤ 1");
  if (!(min_gamma >= 0)) throw InvalidInput("raw truth: min_gamma must be ≥ 0");
  if (!(gamma_from >= 0 && gamma_from < 1 && gamma_span > 0 && gamma_span <= 1))
    throw InvalidInput("raw truth: gamma_from must be in [0, 1) and gamma_span in (0, 1]");
  if (channels.empty()) throw InvalidInput("raw truth: no channels");
  for (const auto& c : channels)
    if (c != "R" && c != "G" && c != "B") throw InvalidInput("raw truth: unknown channel '" + c + "' (R, G or B)");
}

std::map<std::string, std::vector<double>> RawTruthResult::inverse() const {
  std::map<std::string, std::vector<double>> out;
  for (const auto& c : channels) out[c.channel] = c.fit.inverse;
  return out;
}

std::map<std::string, IntensityRange> RawTruthResult::covered() const {
  std::map<std::string, IntensityRange> out;
  for (const auto& c : channels) out[c.channel] = c.fit.covered_range;
  return out;
}

std::string RawTruthResult::summary() const {
  std::ostringstream out;
  char line[320];
  std::snprintf(line, sizeof line, "registered %s (turned %d deg, linear scaled x%.3g, correlation %.3f); %lld flat of %lld overlap px\n",
                registration.method.c_str(), rotation_degrees, linear_scale, registration.ecc_correlation, flat_pixels,
                overlap_pixels);
  out << line;
  for (const auto& c : channels) {
    std::snprintf(line, sizeof line,
                  "%s: EMoR K=%d, covered x in [%.3f, %.3f], %lld px (+%lld censored) in %d bins, bin rmse %.4f, "
                  "pixel rmse %.4f, R^2 %.4f, effective exponent %.2f%s\n",
                  c.channel.c_str(), c.fit.terms, c.fit.covered_range.first, c.fit.covered_range.second, c.pixels,
                  c.censored_pixels, c.bins, c.fit.rmse, c.pixel_rmse, c.explained, c.effective_gamma, std::isfinite(c.effective_gamma) ? "" : " (too dark to measure)");
    out << line;
  }
  return out.str();
}

namespace {

void checkInputs(const cv::Mat& jpeg, const cv::Mat& linear) {
  if (jpeg.empty()) throw InvalidInput("raw truth: the JPEG is empty");
  if (linear.empty()) throw InvalidInput("raw truth: the linear image is empty");
  for (const cv::Mat* m : {&jpeg, &linear}) {
    const int ch = m->channels();
    if (ch != 1 && ch != 3 && ch != 4) throw InvalidInput("raw truth: images must be grey or colour");
    if (m->depth() != CV_8U && m->depth() != CV_16U && m->depth() != CV_32F && m->depth() != CV_64F)
      throw InvalidInput("raw truth: images must be 8/16-bit or floating point");
  }
}

// The channels wanted, each with its slot in Pixel::jpeg (a grey JPEG has only G).
std::vector<ChannelJob> channelJobs(bool jpeg_colour, const RawTruthOptions& options) {
  std::vector<ChannelJob> jobs;
  for (const std::string name : {"R", "G", "B"}) {
    if (std::find(options.channels.begin(), options.channels.end(), name) == options.channels.end()) continue;
    if (!jpeg_colour && name != "G") continue;
    jobs.push_back({name, name == "R" ? 0 : name == "G" ? 1 : 2});  // slot in Pixel::jpeg (grey: G)
  }
  if (jobs.empty()) throw InvalidInput("raw truth: a grey JPEG has only the channel G");
  return jobs;
}

// The state shared by the steps of computeRawTruth: the planes of both images, native and at the working size, their
// clip levels and masks, the registration and the flat-pixel map.
struct RawTruthFrames {
  std::vector<cv::Mat> jpeg_native, linear_native;  // unit scale, native resolution
  std::vector<std::optional<double>> jpeg_clip, linear_clip;
  cv::Size jw;                                      // JPEG working size
  std::vector<cv::Mat> J, jpeg_mask;                // JPEG planes and clip masks at jw
  double ls = 1;                                    // linear working scale (same pixel area as the JPEG's)
  std::vector<cv::Mat> L, linear_mask;              // linear planes and clip masks (turned; after step 2 in jw)
  cv::Mat H = cv::Mat::eye(3, 3, CV_64F);           // linear working → JPEG working
  cv::Mat overlap, gradient;
};

// Native planes, unit scale; clip levels at native resolution (a single clipped pixel matters).
void readNativePlanes(const cv::Mat& jpeg, const cv::Mat& linear, const RawTruthOptions& options, RawTruthFrames& f,
                      RawTruthResult& result) {
  f.jpeg_native = unitPlanes(jpeg);
  f.linear_native = unitPlanes(linear);
  const double jpeg_top = fullScale(jpeg), linear_top = fullScale(linear);
  f.jpeg_clip.assign(f.jpeg_native.size(), std::nullopt);
  f.linear_clip.assign(f.linear_native.size(), std::nullopt);
  static const char* kNames[] = {"R", "G", "B"};
  auto planeName = [](size_t count, size_t i) { return count == 1 ? std::string("G") : std::string(kNames[i]); };
  for (size_t i = 0; i < f.jpeg_native.size(); ++i) {
    f.jpeg_clip[i] = clipLevel(f.jpeg_native[i], jpeg_top, options.clip_pile, options.clip_tolerance);
    if (f.jpeg_clip[i]) result.jpeg_clip[planeName(f.jpeg_native.size(), i)] = *f.jpeg_clip[i];
  }
  for (size_t i = 0; i < f.linear_native.size(); ++i) {
    f.linear_clip[i] = clipLevel(f.linear_native[i], linear_top, options.clip_pile, options.clip_tolerance);
    if (f.linear_clip[i]) result.linear_clip[planeName(f.linear_native.size(), i)] = *f.linear_clip[i];
  }
}

// Working sizes: JPEG area-downscaled to ≤ max_dimension; the linear image to the same pixel area.
void makeWorkingJpeg(const cv::Mat& jpeg, const cv::Mat& linear, const RawTruthOptions& options, RawTruthFrames& f,
                     RawTruthResult& result) {
  const double js = std::min(1.0, double(options.max_dimension) / std::max(jpeg.cols, jpeg.rows));
  const cv::Size jw(std::max(1, int(std::lround(jpeg.cols * js))), std::max(1, int(std::lround(jpeg.rows * js))));
  f.jw = jw;
  result.working_size = jw;
  f.J.resize(f.jpeg_native.size());
  for (size_t i = 0; i < f.J.size(); ++i) f.J[i] = resizeTo(f.jpeg_native[i], jw);
  f.jpeg_mask.resize(f.J.size());
  for (size_t i = 0; i < f.J.size(); ++i)
    f.jpeg_mask[i] = f.jpeg_clip[i] ? shrinkMask((f.jpeg_native[i] >= *f.jpeg_clip[i]), jw) : cv::Mat::zeros(jw, CV_8U);
  f.ls = std::sqrt(double(jw.area()) / double(linear.size().area()));
  result.linear_scale = f.ls;
}

// The linear planes and clip masks at the working scale, turned by `degrees` (scaled before turning: the turned copy
// keeps the JPEG's pixel area).
std::pair<std::vector<cv::Mat>, std::vector<cv::Mat>> linearWorking(const RawTruthFrames& f, cv::Size linear_size,
                                                                     int degrees) {
  const cv::Size size(std::max(1, int(std::lround(linear_size.width * f.ls))),
                      std::max(1, int(std::lround(linear_size.height * f.ls))));
  std::vector<cv::Mat> planes(f.linear_native.size()), masks(f.linear_native.size());
  for (size_t i = 0; i < planes.size(); ++i) {
    planes[i] = turn(resizeTo(f.linear_native[i], size), degrees);
    masks[i] = turn(f.linear_clip[i] ? shrinkMask((f.linear_native[i] >= *f.linear_clip[i]), size) : cv::Mat::zeros(size, CV_8U),
                    degrees);
  }
  return std::pair{planes, masks};
}

// Orientation and registration (step 1): the turns that fit the aspect ratio, tried in turn until one registers.
void orientAndRegister(const cv::Mat& jpeg, const cv::Mat& linear, const RawTruthOptions& options, RawTruthFrames& f,
                       RawTruthResult& result) {
  if (!options.register_images) {
    if (linear.size() != jpeg.size())
      throw InvalidInput("raw truth: without registration the linear image must have the JPEG's size");
    std::tie(f.L, f.linear_mask) = linearWorking(f, linear.size(), 0);
    result.registration.method = "none (given as aligned)";
    result.registration.ecc_correlation = 1;
    result.registration.overlap_fraction = 1;
    return;
  }
  const double aj = double(jpeg.cols) / jpeg.rows, al = double(linear.cols) / linear.rows;
  std::vector<int> candidates;
  const bool upright = std::abs(std::log(aj / al)) <= std::abs(std::log(aj * al));
  if (std::abs(std::log(aj)) < 0.1) candidates = {0, 90, 270, 180};  // square-ish: any turn fits the aspect
  else if (upright) candidates = {0, 180};
  else candidates = {90, 270};
  const cv::Mat jpeg_eq = equalise(greyOf(f.J));
  RegistrationOptions reg = options.registration;
  reg.max_dimension = std::max(reg.max_dimension, std::max(f.jw.width, f.jw.height));
  std::string failure;
  bool found = false;
  for (int degrees : candidates) {
    auto [planes, masks] = linearWorking(f, linear.size(), degrees);
    try {
      const RegistrationResult r = registerPair(equalise(greyOf(planes)), jpeg_eq, reg);
      result.registration = r;
      result.rotation_degrees = degrees;
      f.H = r.homography;
      f.L = std::move(planes);
      f.linear_mask = std::move(masks);
      found = true;
      break;
    } catch (const InvalidInput& e) {
      if (failure.empty()) failure = e.reason();
    }
  }
  if (!found) throw InvalidInput("the linear image does not register with the JPEG (not the same shot?): " + failure);
  if (result.rotation_degrees != 0)
    result.warnings.push_back("the linear image was turned by " + std::to_string(result.rotation_degrees) +
                              " degrees to match the JPEG");
}

void smooth(cv::Mat& m, double sigma, int support) {
  if (sigma > 0) cv::GaussianBlur(m, m, cv::Size(2 * support + 1, 2 * support + 1), sigma);
}

// Into the JPEG frame; low-pass (step 2). Clip masks grow by the low-pass support.
void intoJpegFrame(const RawTruthOptions& options, RawTruthFrames& f, RawTruthResult& result) {
  const cv::Size linear_working = f.L[0].size();
  const int support = static_cast<int>(std::ceil(3 * options.smoothing_sigma));
  for (auto& p : f.L) {
    p = warpToBlurred(p, f.H, f.jw);
    smooth(p, options.smoothing_sigma, support);
  }
  for (auto& p : f.J) smooth(p, options.smoothing_sigma, support);
  const cv::Mat grow = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * support + 1, 2 * support + 1));
  for (auto& m : f.linear_mask) {
    m = warpToBlurred(m, f.H, f.jw) > 0;
    cv::dilate(m, m, grow);
  }
  for (auto& m : f.jpeg_mask) cv::dilate(m, m, grow);
  f.overlap = overlapMask(linear_working, f.H, f.jw, std::max(options.border, support) + 1);
  result.overlap_pixels = cv::countNonZero(f.overlap);
  if (result.overlap_pixels == 0) throw InvalidInput("the linear image does not overlap the JPEG");
}

// Flatness (step 3): the JPEG's gradient magnitude, maximised over the window, against its own quantile over the
// unclipped overlap.
void measureFlatness(const RawTruthOptions& options, RawTruthFrames& f, RawTruthResult& result) {
  {
    const cv::Mat grey = greyOf(f.J);
    cv::Mat gx, gy;
    cv::Sobel(grey, gx, CV_32F, 1, 0, 3, 1.0 / 8);
    cv::Sobel(grey, gy, CV_32F, 0, 1, 3, 1.0 / 8);
    cv::magnitude(gx, gy, f.gradient);
    if (options.flat_radius > 0)
      cv::dilate(f.gradient, f.gradient,
                 cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * options.flat_radius + 1, 2 * options.flat_radius + 1)));
  }
  cv::Mat any_clip = cv::Mat::zeros(f.jw, CV_8U);
  for (const auto& m : f.jpeg_mask) any_clip |= m;
  for (const auto& m : f.linear_mask) any_clip |= m;
  std::vector<float> values;
  values.reserve(static_cast<size_t>(result.overlap_pixels));
  for (int y = 0; y < f.jw.height; ++y) {
    const auto* o = f.overlap.ptr<std::uint8_t>(y);
    const auto* c = any_clip.ptr<std::uint8_t>(y);
    const float* g = f.gradient.ptr<float>(y);
    for (int x = 0; x < f.jw.width; ++x)
      if (o[x] && !c[x]) values.push_back(g[x]);
  }
  if (values.size() < 100) throw InvalidInput("the linear image and the JPEG share too few unclipped pixels");
  const auto q = values.begin() + static_cast<std::ptrdiff_t>(options.flat_quantile * (values.size() - 1));
  std::nth_element(values.begin(), q, values.end());
  result.flat_threshold = *q;
}

// One flat overlap pixel with its clip flags and spatial fold.
Pixel samplePixel(const RawTruthFrames& f, int x, int y, int bw, int bh) {
  Pixel p;
  for (size_t i = 0; i < f.J.size(); ++i) {
    const size_t slot = f.J.size() == 1 ? 1 : i;  // a grey JPEG is the channel G
    const float v = f.J[i].at<float>(y, x);
    p.jpeg[slot] = v;
    if (f.jpeg_mask[i].at<std::uint8_t>(y, x)) p.jpeg_contaminated |= std::uint8_t(1u << slot);
    if (f.jpeg_clip[i] && v >= *f.jpeg_clip[i] - 1e-4) p.jpeg_plateau |= std::uint8_t(1u << slot);
  }
  if (f.J.size() == 1) p.jpeg[0] = p.jpeg[2] = p.jpeg[1];
  for (size_t k = 0; k < f.L.size(); ++k) {
    const float v = f.L[k].at<float>(y, x);
    p.linear[k] = v;
    if (f.linear_mask[k].at<std::uint8_t>(y, x)) p.linear_contaminated = true;
    if (f.linear_clip[k] && v >= *f.linear_clip[k] - 1e-4) p.linear_plateau |= std::uint8_t(1u << k);
  }
  p.fold = static_cast<std::uint8_t>((x / bw + 2 * (y / bh)) % 4);
  return p;
}

// Samples (step 4): every flat overlap pixel, thinned by a regular stride to at most max_pixels.
std::vector<Pixel> samplePixels(const RawTruthOptions& options, const RawTruthFrames& f, RawTruthResult& result) {
  std::vector<Pixel> pixels;
  const int bw = (f.jw.width + options.fold_grid - 1) / options.fold_grid;
  const int bh = (f.jw.height + options.fold_grid - 1) / options.fold_grid;
  for (int y = 0; y < f.jw.height; ++y) {
    const auto* o = f.overlap.ptr<std::uint8_t>(y);
    const float* g = f.gradient.ptr<float>(y);
    for (int x = 0; x < f.jw.width; ++x) {
      if (!o[x] || g[x] > result.flat_threshold) continue;
      pixels.push_back(samplePixel(f, x, y, bw, bh));
    }
  }
  result.flat_pixels = static_cast<long long>(pixels.size());
  if (static_cast<int>(pixels.size()) > options.max_pixels) {
    const size_t stride = (pixels.size() + options.max_pixels - 1) / options.max_pixels;
    std::vector<Pixel> kept;
    kept.reserve(pixels.size() / stride + 1);
    for (size_t i = 0; i < pixels.size(); i += stride) kept.push_back(pixels[i]);
    pixels.swap(kept);
  }
  return pixels;
}

// One channel (steps 5–6): fit, alternate with the mixing row, diagnose.
RawTruthChannel measureChannel(const std::vector<Pixel>& pixels, const ChannelJob& job, int linear_planes, double clip,
                               const RawTruthOptions& options) {
  RawTruthChannel out;
  out.channel = job.name;
  std::vector<double> mix(static_cast<size_t>(linear_planes), 0.0);
  const int own = linear_planes == 1 ? 0 : (job.name == "R" ? 0 : job.name == "G" ? 1 : 2);
  mix[static_cast<size_t>(own)] = 1;
  // The alternation works with a fixed K = 4 curve (Grossberg & Nayar: 3–5 terms reach DoRF accuracy); the
  // final fit chooses K by cross-validation over the spatial folds.
  const int rounds = options.colour_matrix && linear_planes == 3 ? options.matrix_rounds : 0;
  const int alternation_terms = std::clamp(4, std::max(1, options.fit.min_terms), options.fit.max_terms);
  ChannelFit fit = fitChannel(pixels, job, mix, clip, options, rounds > 0 ? alternation_terms : 0);
  for (int round = 0; round < rounds; ++round) {
    mix = fitMix(pixels, job, mix, fit.fit, options);
    fit = fitChannel(pixels, job, mix, clip, options, round + 1 < rounds ? alternation_terms : 0);
  }
  const double s = fit.fit.scales.empty() || !(fit.fit.scales[0] > 0) ? 1.0 : fit.fit.scales[0];
  out.fit = fit.fit;
  out.mix = mix;
  out.bins = fit.bins;
  out.censored_pixels = fit.censored;
  diagnose(pixels, job, out, options);
  for (auto& m : out.mix) m /= s;  // M_c·RAW ≈ φ(JPEG_c)
  return out;
}

// Per channel (steps 5–6), in parallel: the channels are independent. The first failure is rethrown.
void measureChannels(const std::vector<Pixel>& pixels, const std::vector<ChannelJob>& jobs, const RawTruthFrames& f,
                     bool jpeg_colour, const RawTruthOptions& options, RawTruthResult& result) {
  result.channels.resize(jobs.size());
  const int linear_planes = static_cast<int>(f.linear_native.size());
  std::exception_ptr failure;
  std::mutex failure_lock;
  cv::parallel_for_(cv::Range(0, static_cast<int>(jobs.size())), [&](const cv::Range& range) {
    for (int j = range.start; j < range.end; ++j) {
      try {
        const ChannelJob& job = jobs[static_cast<size_t>(j)];
        const auto jc = f.jpeg_clip[static_cast<size_t>(jpeg_colour ? job.jpeg_index : 0)];
        result.channels[static_cast<size_t>(j)] = measureChannel(pixels, job, linear_planes, jc ? *jc : 1.0, options);
      } catch (...) {
        std::lock_guard<std::mutex> lock(failure_lock);
        if (!failure) failure = std::current_exception();
      }
    }
  });
  if (failure) std::rethrow_exception(failure);
}

// Checks (step 7): every channel explains the linear values, and the mean effective exponent is a camera's.
void checkLinearity(const RawTruthOptions& options, RawTruthResult& result) {
  double gamma_sum = 0;
  int gamma_count = 0;
  for (const auto& c : result.channels) {
    if (c.explained < options.min_explained) {
      char buffer[300];
      std::snprintf(buffer, sizeof buffer,
                    "the linear image does not match the JPEG pixel by pixel (channel %s: the response explains %.0f%% "
                    "of the linear values, need %.0f%%): not the same shot, or not linear data",
                    c.channel.c_str(), 100 * c.explained, 100 * options.min_explained);
      throw InvalidInput(buffer);
    }
    if (std::isfinite(c.effective_gamma)) {
      gamma_sum += c.effective_gamma;
      ++gamma_count;
    }
  }
  if (gamma_count == 0) {
    result.warnings.push_back("the JPEG values covered are too dark to confirm that the linear image is linear");
  } else if (gamma_sum / gamma_count < options.min_gamma) {
    char buffer[300];
    std::snprintf(buffer, sizeof buffer,
                  "the \"linear\" image looks non-linear: above x = %.2f the JPEG relates to it with an exponent of "
                  "%.2f (< %.2f; cameras encode linear light with 1.5-2.4 there): give the RAW or a linear rendering",
                  options.gamma_from, gamma_sum / gamma_count, options.min_gamma);
    throw InvalidInput(buffer);
  }
}

}  // namespace

RawTruthResult computeRawTruth(const cv::Mat& jpeg, const cv::Mat& linear, const RawTruthOptions& options) {
  options.check();
  checkInputs(jpeg, linear);
  RawTruthResult result;
  const bool jpeg_colour = jpeg.channels() >= 3;
  const std::vector<ChannelJob> jobs = channelJobs(jpeg_colour, options);
  RawTruthFrames frames;
  readNativePlanes(jpeg, linear, options, frames, result);
  makeWorkingJpeg(jpeg, linear, options, frames, result);
  orientAndRegister(jpeg, linear, options, frames, result);
  intoJpegFrame(options, frames, result);
  measureFlatness(options, frames, result);
  const std::vector<Pixel> pixels = samplePixels(options, frames, result);
  measureChannels(pixels, jobs, frames, jpeg_colour, options, result);
  checkLinearity(options, result);
  return result;
}

}  // namespace crfcal
