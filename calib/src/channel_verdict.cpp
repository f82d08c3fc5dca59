#include "crfcal/channel_verdict.hpp"
#include "crfcal/ratio_evidence.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"

// The verdict rules of channel_verdict.hpp. Each rule adds its sentence with the level it implies; the channel's
// level is the worst of them.

namespace crfcal {

const char* toString(VerdictLevel level) {
  switch (level) {
    case VerdictLevel::ok: return "ok";
    case VerdictLevel::weak: return "weak";
    case VerdictLevel::unreliable: return "unreliable";
  }
  return "unknown";
}

void VerdictOptions::check() const {
  if (!(max_ratio_factor > 1)) throw InvalidInput("verdict: max_ratio_factor must be > 1");
  if (!(brightness_ratio_exponent_min > 0 && brightness_ratio_exponent_max >= brightness_ratio_exponent_min))
    throw InvalidInput("verdict: need 0 < brightness_ratio_exponent_min <= brightness_ratio_exponent_max");
  if (!(ratio_side_tolerance >= 0)) throw InvalidInput("verdict: ratio_side_tolerance must be >= 0");
  if (!(max_channel_ratio_spread > 0)) throw InvalidInput("verdict: max_channel_ratio_spread must be > 0");
  if (!(min_covered_span >= 0 && min_covered_span <= 1)) throw InvalidInput("verdict: min_covered_span in [0, 1]");
  if (!(flat_local_exponent >= 0)) throw InvalidInput("verdict: flat_local_exponent must be >= 0");
  if (!(max_flat_fraction > 0 && max_flat_fraction <= 1)) throw InvalidInput("verdict: max_flat_fraction in (0, 1]");
  if (!(flat_slope_fraction >= 0 && flat_slope_fraction < 1)) throw InvalidInput("verdict: flat_slope_fraction in [0, 1)");
  if (!(max_shape_sigma > 0)) throw InvalidInput("verdict: max_shape_sigma must be > 0");
  if (!(max_chroma_shape_difference > 0)) throw InvalidInput("verdict: max_chroma_shape_difference must be > 0");
}

std::string ChannelVerdict::summary() const {
  std::string text = toString(level);
  for (std::size_t i = 0; i < reasons.size(); ++i) text += (i ? "; " : ": ") + reasons[i];
  return text;
}

VerdictLevel worstLevel(const std::map<std::string, ChannelVerdict>& verdicts) {
  VerdictLevel worst = VerdictLevel::ok;
  for (const auto& [name, v] : verdicts) worst = std::max(worst, v.level);
  return worst;
}

namespace {

double sampleAt(const std::vector<double>& phi, double x) {
  const double t = std::clamp(x, 0.0, 1.0) * double(phi.size() - 1);
  const auto i = std::min(static_cast<std::size_t>(t), phi.size() - 2);
  const double f = t - double(i);
  return phi[i] + f * (phi[i + 1] - phi[i]);
}

std::string format(const char* pattern, double a, double b = 0, double c = 0, double d = 0) {
  char buffer[300];
  std::snprintf(buffer, sizeof buffer, pattern, a, b, c, d);
  return buffer;
}

// "2.65x below" / "1.3x above": how far r is from a reference, as a factor.
std::string factorText(double r, double reference) {
  return r < reference ? format("%.2gx below", reference / r) : format("%.2gx above", r / reference);
}

// Collects the sentences of one channel: findings that set the level first, notes after.
struct Judgement {
  VerdictLevel level = VerdictLevel::ok;
  std::vector<std::string> findings, notes;
  void find(VerdictLevel l, const std::string& sentence) {
    level = std::max(level, l);
    findings.push_back(sentence);
  }
};

// r against the nominal ratio and the shots' brightness ratio; r on the wrong side of 1.
void judgeRatio(const ChannelEvidence& e, const VerdictOptions& o, Judgement& j) {
  const double r = e.ratio;
  if (!(std::isfinite(r) && r > 0)) {
    j.find(VerdictLevel::unreliable, "the fitted r is not a positive number");
    return;
  }
  const double n = e.nominal_ratio;
  if (n > 0 && ((n > 1 + o.ratio_side_tolerance && r < 1) || (n < 1 / (1 + o.ratio_side_tolerance) && r > 1)))
    j.find(VerdictLevel::unreliable, format("r %.3g puts more light in the other shot than ", r) + e.nominal_source +
                                         format(" (%.3g): physically impossible", n));
  const double limit = std::log(o.max_ratio_factor);
  // Sources of evidence about r: the nominal ratio (unless r was fixed to it: then it says nothing) and the shots'
  // regions' brightness ratio.
  int sources = 0, disagreeing = 0;
  std::string against;
  if (n > 0 && !e.ratio_fixed && !e.ratio_held_small_blur && !e.ratio_held_at_nominal) {
    ++sources;
    if (std::abs(std::log(r / n)) > limit) {
      ++disagreeing;
      against = "r " + format("%.3g is ", r) + factorText(r, n) + " " + e.nominal_source + format(" %.3g", n);
    }
  }
  if (e.brightness_ratio > 0) {
    ++sources;
    // log r from the shots' brightness: log r_b · k for k in [k_min, k_max] (the camera's curve against g0).
    const double log_b = std::log(e.brightness_ratio);
    const double a = log_b * o.brightness_ratio_exponent_min, b = log_b * o.brightness_ratio_exponent_max;
    const double lo = std::min(a, b), hi = std::max(a, b), log_r = std::log(r);
    if (log_r < lo - limit || log_r > hi + limit) {
      ++disagreeing;
      const double nearest = std::exp(log_r < lo ? lo : hi);
      against += (against.empty() ? "r " + format("%.3g is ", r) : std::string(" and ")) + factorText(r, nearest) +
                 format(" the shots' brightness ratio %.3g", e.brightness_ratio) +
                 (std::abs(nearest / e.brightness_ratio - 1) > 1e-9
                      ? format(" (%.3g for the most convex measured curve)", nearest)
                      : std::string());
    }
  }
  const std::string beyond = format(" (beyond a factor %.2g)", o.max_ratio_factor);
  if (disagreeing > 0 && disagreeing == sources)
    j.find(VerdictLevel::unreliable,
           against + beyond + ": " +
               (sources > 1 ? "the curve's exponent is likely wrong (phi^g with r^g fit alike)"
                            : "the only independent evidence about r contradicts the curve's r"));
  else if (disagreeing > 0)
    j.find(VerdictLevel::weak, against + beyond + ": the other evidence about r agrees, so one source is off");
  if (e.ratio_conflict)
    j.find(VerdictLevel::weak,
           format("the images' r %.3g and ", e.ratio_images) + e.nominal_source + format(" %.3g differ by %.1f sigma", n, e.ratio_conflict_sigmas) +
               (e.ratio_held_at_nominal
                    ? ": the shots' brightness sides with " + e.nominal_source + ", so r is held there (the blur did not fix the curve's exponent)"
                    : e.ratio_decision == toString(RatioDecision::images_kept)
                          ? ": the shots' brightness sides with the images, so " + e.nominal_source + " is set aside"
                    : e.ratio_decision.rfind("not adopted: ", 0) == 0
                          ? "; the combined r was " + e.ratio_decision + ", so the fits keep their own r"
                          : std::string(": the shots' brightness does not tell which is off; r is their precision-weighted combination")));
  if (e.ratio_held_small_blur)
    j.find(VerdictLevel::weak, "the blur is too small to fix r: held at " + e.nominal_source + format(" %.3g", n) +
                                   format(" (the images alone gave %.3g)", e.ratio_images_small_blur));
}

// Covered span and flat stretches of φ over it; a colour channel rebuilt from subsampled chroma.
void judgeCurve(const ChannelEvidence& e, const VerdictOptions& o, Judgement& j) {
  if (e.kernel_sharp_black_admitted > 0)
    j.find(VerdictLevel::weak,
           format("the kernel was estimated with the sharp shot's black areas admitted (black over %.0f %% of the "
                  "overlap; without them the estimate failed): an edge into black loses its dark side",
                  100 * e.kernel_sharp_black_admitted));
  if (e.kernel_grown_to > 0)
    j.find(VerdictLevel::weak,
           format("the blur outgrew the kernel's %.0f px limit and was estimated at %.0f px: r and phi rest on a "
                  "kernel at the estimator's reach (on such blurs most pairs' r came out more than 5 %% off)",
                  e.kernel_size_start, e.kernel_grown_to));
  if (e.chroma_check_replaced)
    j.notes.push_back(format("fitted where the sharp shot's subsampled chroma is flat: the pointwise fit differed "
                             "from this one in shape by %.4f (> %.2g) and lay below it (scale %.3f), the bias the "
                             "lost chroma puts in",
                             e.chroma_check_shape_difference, o.max_chroma_shape_difference, e.chroma_check_scale));
  if (!e.pointwise_from_subsampled_chroma.empty()) {
    const std::string subsampled = "fitted from a sharp JPEG with " + e.pointwise_from_subsampled_chroma +
                                   " chroma: its " + e.channel + " at edges is rebuilt from block-averaged chroma";
    const double d = e.chroma_check_shape_difference;
    const std::string without =
        format("its fit without the %.0f pixels where that chroma varies", e.chroma_check_pixels_left_out);
    if (d >= 0 && d <= o.max_chroma_shape_difference)
      j.notes.push_back(subsampled + (e.chroma_check_pixels_left_out == 0
                                          ? std::string(", but no block's stored chroma varies beyond the image's "
                                                        "typical block: nothing for the pointwise model to miss")
                                          : ", but " + without +
                                                format(" has the same shape (RMSE %.4f <= %.2g after the best scale)",
                                                       d, o.max_chroma_shape_difference)));
    else if (d >= 0 && e.chroma_check_scale > 0 && e.chroma_check_scale <= 1)
      // The lost chroma lowers a pointwise φ over the data (chroma_subsampling.hpp ChromaModelChoice): a fit freed
      // of it lies above. One that lies below moved against that bias, by the noise of its thinner data.
      j.notes.push_back(subsampled + ", but " + without +
                        format(", which differs in shape by %.4f, lies below it (scale %.3f <= 1): against the "
                               "sign of the bias the lost chroma puts in, so the difference is that thinner fit's own",
                               d, e.chroma_check_scale));
    else {
      std::string measured;  // what the check found, and why its fit is not the reported one
      if (d >= 0) {
        measured = ": " + without + format(" differs in shape by %.4f (> %.2g)", d, o.max_chroma_shape_difference);
        if (e.chroma_check_scale > 0)
          measured += format(" and lies above it (scale %.3f), as the lost chroma's bias predicts",
                             e.chroma_check_scale) +
                      (e.chroma_check_not_replaced.empty() ? std::string(" (--chroma-model check, the default, "
                                                                         "reports that fit)")
                                                           : "; " + e.chroma_check_not_replaced);
      }
      j.find(VerdictLevel::weak, subsampled + ", which the pointwise model does not represent" + measured);
    }
  }
  if (!e.covered) return;
  const auto [lo, hi] = *e.covered;
  if (hi - lo < o.min_covered_span)
    j.find(VerdictLevel::weak, format("the data cover intensities %.2f-%.2f only (span < %.2g): phi is mostly "
                                      "extrapolated",
                                      lo, hi, o.min_covered_span));
  if (e.shape_band_sigma > o.max_shape_sigma)
    j.find(VerdictLevel::weak, format("the band of phi's shape over the covered range is wide (median sigma %.3f > %.2g): "
                                      "the pair does not fix the curve's shape to that accuracy",
                                      e.shape_band_sigma, o.max_shape_sigma));
  if (e.inverse_crf.size() < 2) return;
  const double flat = flatFraction(e.inverse_crf, *e.covered, o);
  if (flat >= o.max_flat_fraction)
    j.find(VerdictLevel::unreliable,
           format("phi is nearly constant over %.0f %% of the covered range %.2f-%.2f (local exponent < %.2g or a rise "
                  "under a tenth of any real curve's)",
                  100 * flat, lo, hi, o.flat_local_exponent));
}

// Channels whose r leaves the band around the channels' median r.
void judgeChannelConsistency(const std::vector<ChannelEvidence>& channels, const VerdictOptions& o,
                             std::map<std::string, Judgement>& judgements) {
  std::vector<double> ratios;
  for (const auto& e : channels)
    if (std::isfinite(e.ratio) && e.ratio > 0) ratios.push_back(e.ratio);
  if (ratios.size() < 2) return;
  const auto [lo, hi] = std::minmax_element(ratios.begin(), ratios.end());
  const double spread = std::log(*hi / *lo);
  if (spread <= std::log(1 + o.max_channel_ratio_spread)) return;
  std::vector<double> sorted = ratios;
  std::sort(sorted.begin(), sorted.end());
  const std::size_t m = sorted.size();
  const double median = m % 2 ? sorted[m / 2] : std::sqrt(sorted[m / 2 - 1] * sorted[m / 2]);
  // Half the allowed spread on either side of the median: whenever the spread exceeds the limit, at least one
  // channel is outside.
  const double half_band = 0.5 * std::log(1 + o.max_channel_ratio_spread);
  for (const auto& e : channels) {
    if (!(e.ratio > 0) || std::abs(std::log(e.ratio / median)) <= half_band) continue;
    judgements[e.channel].find(VerdictLevel::weak,
                               format("r %.3g differs from the channels' median r %.3g by %.0f %%", e.ratio, median,
                                      100 * (e.ratio / median - 1)) +
                                   format(" (channels spread %.0f %%, > %.0f %%)", 100 * (*hi / *lo - 1),
                                          100 * o.max_channel_ratio_spread));
  }
}

std::string refitNote(const RefitEvidence& refit) {
  if (!refit.tried) return {};
  if (refit.adopted)
    return format("the effects' refit is reported: held-back pixels' error %.3g, the base fit's %.3g (not worse)",
                  refit.heldout_error_refit, refit.heldout_error_base_fit) +
           (refit.heldout_error_base_fit_selected_model > 0
                ? format(", %.3g with the base fit's phi under the extended model",
                         refit.heldout_error_base_fit_selected_model)
                : std::string());
  return "the effects' refit was rejected (" + refit.rejected_reason + "); the base fit is reported";
}

// The one sentence of a channel with no findings: the checks it passed.
std::string passedNote(const ChannelEvidence& e, const VerdictOptions& o) {
  std::string text = format("r %.3g", e.ratio);
  if (e.ratio_fixed)
    text += " fixed";
  else if (e.nominal_ratio > 0)
    text += " within a factor " + format("%.2g of ", o.max_ratio_factor) + e.nominal_source +
            format(" %.3g", e.nominal_ratio);
  if (e.brightness_ratio > 0) text += format(", consistent with the shots' brightness ratio %.3g", e.brightness_ratio);
  if (e.covered) text += format("; data cover %.2f-%.2f", e.covered->first, e.covered->second);
  if (e.shape_band_sigma >= 0) text += format(", shape band sigma %.3f there", e.shape_band_sigma);
  return text;
}

}  // namespace

double flatFraction(const std::vector<double>& phi, std::pair<double, double> covered, const VerdictOptions& o) {
  const double hi = std::min(covered.second, 1.0);
  const double lo = std::max(covered.first, 1.0 / double(phi.size() - 1));  // log x needs x > 0
  if (!(hi > lo) || phi.size() < 2) return 0;
  const std::vector<double> g0(emor::inverseMean().begin(), emor::inverseMean().end());
  // The smallest rise of g0^k over [a, b] for k in [k_min, k_max] (monotone in k at each end: check both ends).
  auto realRise = [&](double a, double b) {
    double rise = 1;
    for (const double k : {o.brightness_ratio_exponent_min, o.brightness_ratio_exponent_max})
      rise = std::min(rise, std::pow(sampleAt(g0, b), k) - std::pow(sampleAt(g0, a), k));
    return rise;
  };
  constexpr int intervals = 32;
  const double step = (hi - lo) / intervals;
  int flat = 0;
  for (int k = 0; k < intervals; ++k) {
    const double a = lo + k * step, b = a + step;
    const double fa = sampleAt(phi, a), fb = sampleAt(phi, b);
    if (!(fa > 0) || !(fb > 0)) {
      ++flat;
      continue;
    }
    const double exponent = (std::log(fb) - std::log(fa)) / (std::log(b) - std::log(a));
    flat += exponent < o.flat_local_exponent || fb - fa < o.flat_slope_fraction * realRise(a, b);
  }
  return double(flat) / intervals;
}

std::map<std::string, ChannelVerdict> judgeChannels(const std::vector<ChannelEvidence>& channels,
                                                    const RefitEvidence& refit, const VerdictOptions& options) {
  options.check();
  std::map<std::string, Judgement> judgements;
  for (const auto& e : channels) {
    Judgement& j = judgements[e.channel];
    judgeRatio(e, options, j);
    judgeCurve(e, options, j);
  }
  judgeChannelConsistency(channels, options, judgements);
  const std::string note = refitNote(refit);
  std::map<std::string, ChannelVerdict> verdicts;
  for (const auto& e : channels) {
    Judgement& j = judgements[e.channel];
    ChannelVerdict& v = verdicts[e.channel];
    v.level = j.level;
    v.reasons = j.findings;
    if (v.reasons.empty()) v.reasons.push_back(passedNote(e, options));
    v.reasons.insert(v.reasons.end(), j.notes.begin(), j.notes.end());
    if (!note.empty()) v.reasons.push_back(note);
  }
  return verdicts;
}

}  // namespace crfcal
