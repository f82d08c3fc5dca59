// Stage "kernel" of calibratePair: the first blur kernel K of Eq. 4, B = g·(I ⊗ K), estimated before any φ is known
// (kernel_estimation.hpp) between the histogram-matched sharp shot and the blurred one, and the kernel-aware
// refinement of the registration (ECC of I ⊗ K against B, registration.hpp) with K estimated again on the result.
#include <algorithm>
#include <cstdio>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "pair_stages.hpp"

namespace crfcal::detail {

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

int largestKernelSize(const PairCalibrationState& state) {
  const int start = state.options.kernel.kernel_size;
  if (state.options.max_kernel_size > 0) return state.options.max_kernel_size;
  int quarter = std::min(state.sharp.cols, state.sharp.rows) / 4;
  if (quarter % 2 == 0) --quarter;
  return std::max(start, std::min(kAutomaticLargestKernel, quarter));
}

KernelEstimate estimateCanvasKernel(PairCalibrationState& state, const cv::Mat& s, const cv::Mat& b, bool per_tile,
                                    double lambda, const cv::Mat& weights) {
  const Canvas& canvas = state.canvas;
  PairCalibrationResult& result = state.result;
  KernelEstimationOptions ko = state.kernel_options;
  ko.lambda = lambda;
  ko.progress = [&state](double f, const std::string& stage) { state.report("kernel", f, stage); };
  KernelEstimate k = estimateKernel(s, b, canvas.regions, canvas.usable, ko, weights);
  if (per_tile && canvas.regions.size() > 1) {
    result.tile_kernels.clear();
    KernelEstimationOptions to = ko;
    to.progress = nullptr;
    to.throw_on_size_limit = false;
    std::vector<cv::Mat> kernels;
    for (std::size_t i = 0; i < canvas.regions.size(); ++i) {  // canvas.regions[i] is result.tiles[i] (pair_canvas.cpp)
      try {
        kernels.push_back(estimateKernel(s, b, {canvas.regions[i]}, canvas.usable, to, weights).kernel);
        result.tile_kernels.push_back({static_cast<int>(i), kernels.back()});
      } catch (const InvalidInput&) {
        // a tile without usable edges: no per-tile kernel
      }
    }
    result.disagreement = kernelDisagreement(kernels, k.kernel);
  }
  return k;
}

namespace {

// Kernel-aware refinement of the alignment: ECC of I ⊗ K against B (equally blurred), then re-align.
void refineRegistrationWithKernel(PairCalibrationState& state, const cv::Mat& kernel) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  if (!options.register_pair || !options.refine_registration) return;
  const auto start = Clock::now();
  cv::Mat sharp_ok;
  cv::bitwise_and(~state.sharp_clipped, state.overlap, sharp_ok);
  const RegistrationResult refined = refineRegistration(state.sharp_g8, state.blurred_own_g8, result.registration,
                                                        kernel, sharp_ok, options.registration);
  if (refined.kernel_refined) {
    result.registration = refined;
    alignToRegistration(state);
  }
  result.timings["register"] += secondsSince(start);
  state.report("register", 1, result.registration.summary());
}

// Round 0: no φ yet. The sharp image's levels are mapped to the blurred one's by histogram matching (a monotone
// map that removes most of the exposure and tone difference), so B ≈ g · (I' ⊗ K) holds approximately.
KernelEstimate intensityDomainKernel(PairCalibrationState& state, bool per_tile) {
  const Canvas& canvas = state.canvas;
  return estimateCanvasKernel(state, histogramMatch(canvas.sharp_denoised, canvas.blurred, canvas.usable),
                              canvas.blurred, per_tile, state.kernel_options.lambda, cv::Mat());
}


// intensityDomainKernel, made again 1.5× larger (odd) while it reaches its size limit and may grow
// (state.kernel_may_grow, up to largestKernelSize); the size it ends at stays in state.kernel_options for every later
// estimate and the canvas.
KernelEstimate intensityDomainKernelGrowing(PairCalibrationState& state) {
  const int largest = state.kernel_may_grow ? largestKernelSize(state) : state.kernel_options.kernel_size;
  const bool throws = state.kernel_options.throw_on_size_limit;
  while (true) {
    KernelEstimationOptions& ko = state.kernel_options;
    const bool can_grow = ko.kernel_size < largest;
    ko.throw_on_size_limit = throws && !can_grow;  // the last size tried fails as it always did
    KernelEstimate k;
    try {
      k = intensityDomainKernel(state, false);
    } catch (...) {
      ko.throw_on_size_limit = throws;
      throw;
    }
    ko.throw_on_size_limit = throws;
    if (!k.hit_size_limit || !can_grow) return k;
    const int grown = std::min(largest, (ko.kernel_size * 3 / 2) | 1);
    char detail[160];
    std::snprintf(detail, sizeof detail,
                  "at its %d px limit (%.0f %% of its mass on the border): estimated again at %d px", ko.kernel_size,
                  100 * k.border_mass, grown);
    state.report("kernel", 0, detail);
    ko.kernel_size = grown;
    selectKernelTiles(state);  // the canvas's margin follows the kernel's size
  }
}

}  // namespace

std::string usablePixelsNote(const PairCalibrationState& state) {
  const double overlap = std::max(1, cv::countNonZero(state.overlap));
  const auto share = [&](const cv::Mat& mask) {
    cv::Mat inside;
    cv::bitwise_and(mask, state.overlap, inside);
    return 100.0 * cv::countNonZero(inside) / overlap;
  };
  const cv::Mat& sharp_black = state.sharp_black;
  const double black = share(sharp_black);
  char buffer[300];
  std::snprintf(buffer, sizeof buffer,
                "usable: %.0f %% of the overlap; the sharp shot is black over %.0f %%, clipped over %.0f %%, the "
                "blurred one clipped over %.0f %%%s",
                share(state.usable), black, share(state.sharp_clipped & ~sharp_black),
                share(state.blurred_g8 >= state.clip_high),
                black >= 50 ? ": a brighter short exposure (a smaller exposure ratio) would leave more" : "");
  return buffer;
}

namespace {

// The black share of the overlap recorded, and the warning, once a kernel was estimated with it admitted.
void recordSharpBlackAdmitted(PairCalibrationState& state, int black) {
  state.result.kernel_sharp_black_admitted = double(black) / std::max(1, cv::countNonZero(state.overlap));
  char buffer[300];
  std::snprintf(buffer, sizeof buffer,
                "the kernel estimate failed without the sharp shot's black areas (black over %.0f %% of the "
                "overlap): it was estimated with them admitted (an edge into black loses its dark side); the "
                "verdict is at most weak. A brighter short exposure (a smaller exposure ratio) would avoid this",
                100 * state.result.kernel_sharp_black_admitted);
  state.result.warnings.push_back(buffer);
}

// A first kernel grown past the size given: recorded (the verdict reads it) and said.
void recordKernelGrowth(PairCalibrationState& state) {
  const int start = state.options.kernel.kernel_size, size = state.kernel_options.kernel_size;
  if (size <= start) return;
  state.result.kernel_grown_to = size;
  char buffer[200];
  std::snprintf(buffer, sizeof buffer,
                "the blur is large: the kernel reached its %d px limit and was estimated at %dx%d px", start, size,
                size);
  state.result.warnings.push_back(buffer);
}

// estimateFirstKernel once more; false when it fails too, with its reason in `failure` when given.
bool retried(PairCalibrationState& state, std::string* failure = nullptr) {
  try {
    estimateFirstKernel(state);
    return true;
  } catch (const InvalidInput& e) {
    if (failure) *failure = e.reason();
    return false;
  }
}

// The first kernel made again, allowed to grow (a blur beyond the window: the estimate at its size limit; an estimate
// without edges fails again at once), without the sharp shot's black (measured: admitted, it made three large-blur
// pairs fail that grow without it) and then, where `may_admit_black`, with it. A failed attempt leaves the
// registration its kernels refined: the growth starts from that registration and, where it fails there, once more
// from `first_registration` (measured on the large-blur run: each rescues two pairs the other loses); a second pass
// that would repeat the first is skipped. False when every attempt fails, with the first one's reason in `failure`
// (at the largest size that attempt reached).
bool grownFirstKernel(PairCalibrationState& state, const RegistrationResult& first_registration, int black,
                      bool may_admit_black, std::string& failure) {
  state.kernel_may_grow = true;
  bool started_elsewhere = false;  // some first-pass attempt started from a registration a failure refined
  for (const bool from_first_registration : {false, true}) {
    if (from_first_registration && !started_elsewhere) break;
    for (const bool admit : {false, true}) {
      if (admit && !may_admit_black) continue;
      if (from_first_registration)
        state.result.registration = first_registration;
      else
        started_elsewhere = started_elsewhere || cv::norm(state.result.registration.homography,
                                                           first_registration.homography, cv::NORM_INF) > 0;
      state.kernel_admits_sharp_black = admit;
      state.kernel_options.kernel_size = state.options.kernel.kernel_size;  // each attempt grows from the start
      alignToRegistration(state);
      if (retried(state, failure.empty() ? &failure : nullptr)) {
        recordKernelGrowth(state);
        if (admit) recordSharpBlackAdmitted(state, black);
        return true;
      }
    }
  }
  return false;
}

}  // namespace

void estimateFirstKernelAdmittingBlack(PairCalibrationState& state) {
  state.kernel_may_grow = false;
  const RegistrationResult first_registration = state.result.registration;
  try {
    estimateFirstKernel(state);
    return;
  } catch (const InvalidInput& e) {
    const std::string note = usablePixelsNote(state);  // of the first attempt, for the message if the retries fail
    cv::Mat black_in_overlap;
    cv::bitwise_and(state.sharp_black, state.overlap, black_in_overlap);
    const int black = cv::countNonZero(black_in_overlap);
    // The sharp shot's black is admitted only on a pair whose two shots show one scene (a doubtful one keeps its
    // two-scenes message, pair_calibration.cpp).
    const bool may_admit_black = black > 0 && state.same_scene_correlation >= doubtful_same_scene_correlation;
    // First the black admitted at the size given (a night frame: no usable windows without it) ...
    if (!state.kernel_admits_sharp_black && may_admit_black) {
      state.kernel_admits_sharp_black = true;
      state.report("kernel", 0, "failed without the sharp shot's black areas: estimated again with them");
      alignToRegistration(state);
      if (retried(state)) return recordSharpBlackAdmitted(state, black);
    }
    // ... then a larger kernel. Not gated by the same-scene correlation: a large blur lowers it (0.34 for a 42 px blur
    // of a Levin image), and a kernel that fits at no size still ends in the two-scenes message. When every growth
    // fails, the stop names the growth's failure (at the size it reached) instead of the first attempt's.
    std::string growth_failure;
    if (largestKernelSize(state) > state.options.kernel.kernel_size &&
        grownFirstKernel(state, first_registration, black, may_admit_black, growth_failure))
      return;
    throw InvalidInput((growth_failure.empty() ? e.reason() : growth_failure) + " (" + note + ")", e.subject());
  }
}

void estimateFirstKernel(PairCalibrationState& state) {
  const PairCalibrationOptions& options = state.options;
  PairCalibrationResult& result = state.result;
  const auto start = Clock::now();
  const double register_before_kernel = result.timings["register"];
  if (!options.given_kernel.empty()) {
    state.kernel = normalizeKernel(options.given_kernel);
    result.kernel.kernel = state.kernel;
    result.kernel.support = cv::countNonZero(state.kernel);
    result.kernel.centroid = kernelCentroid(state.kernel);
    result.kernel_estimated = false;
    // A given kernel cannot absorb a residual shift: the alignment must be right.
    refineRegistrationWithKernel(state, state.kernel);
  } else {
    state.report("kernel", 0);
    result.kernel = intensityDomainKernelGrowing(state);
    state.kernel = result.kernel.kernel;
    if (options.register_pair && options.refine_registration) {
      refineRegistrationWithKernel(state, state.kernel);
      result.kernel = intensityDomainKernel(state, options.rounds == 0);
      state.kernel = result.kernel.kernel;
    }
  }
  // The refinement's time counts as registration.
  result.timings["kernel"] = secondsSince(start) - (result.timings["register"] - register_before_kernel);
}

}  // namespace crfcal::detail
