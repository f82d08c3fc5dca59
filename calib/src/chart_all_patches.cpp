// ReferenceSet::AllPatches: the whole ColorChecker, every patch in every channel, with no published colour.
//
// Model (the bracket model of bracket_calibration.hpp on a chart): in channel c, shot j of scene k, patch p,
//   φ_c(x_jpc) = E_kpc · t_j,
// t_j the shot's relative exposure (shared by R, G, B), E_kpc the patch's irradiance in that channel. A camera maps
// RAW to JPEG channel c by f_c((M·raw)_c) with its colour matrix M: (M·raw)_c of a patch scales with the exposure like
// any irradiance, so E_kpc is simply an unknown per patch, channel and scene — no assumption on M or the primaries.
// The six greys reflect Y_p in every band: for them E_kpc = Y_p / σ_kc with one unknown σ per scene and channel,
// which ties the curve's exponent down even when the exposures are unknown (otherwise φ^γ, t^γ would fit as well).
// Written as y = σ·φ(x) with y = t_j·Y_p (greys, group (k, grey)) or y = t_j (colours, group (k, p)), this is
// fitScaledInverse with profiled scales. Weights (x/y)²: a constant noise δ on x is an error ≈ γ·y·δ/x in y.
//
// Exposures: given (EXIF, --exposures) they are fixed. Otherwise they start from the greys through the EMoR mean
// curve and alternate with the curves: each round fits the three channels with K = 3 and sets t_j to the median over
// the shot's samples of σ_g·φ(x)/(y/t_j), the brightest shot at 1.
#include <algorithm>
#include <cmath>
#include <map>
#include <set>

#include "chart_stages.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/scaled_fit_band.hpp"

namespace crfcal::detail {
namespace {

struct ChannelData {
  std::vector<ScaledObservation> observations;  // the exact ones first, then the bounds
  size_t exact = 0;
  std::vector<std::pair<int, int>> origin;      // (shot, patch) of the exact ones
  std::vector<int> cluster;                     // per observation: its (scene, patch), numbered 0 … (the band's unit)
  int rejected = 0;                             // patch samples not used as exact data
};

struct Candidate {
  ScaledObservation observation;
  int shot = 0, patch = 0;
};

// Channel c's observations for the exposures t (one per shot). A coloured patch seen exactly in fewer than two shots
// of its scene says nothing about φ (its own irradiance absorbs it) and is left out.
using GroupKey = std::pair<int, int>;  // (scene, patch), patch −1 for the greys

ChannelData channelObservations(const std::vector<ChartShot>& shots, int c, const std::vector<double>& t,
                                const ChartCalibrationOptions& options, const std::set<GroupKey>& excluded = {}) {
  std::vector<Candidate> candidates;
  std::map<std::pair<int, int>, int> exact_count;  // (scene, patch or −1 for the greys) → exact samples
  ChannelData data;
  for (size_t s = 0; s < shots.size(); ++s)
    for (int p = 0; p < chart::kPatches; ++p) {
      const chart::PatchStats& m = shots[s].measured[static_cast<size_t>(p)];
      const bool neutral = chart::reference()[static_cast<size_t>(p)].neutral;
      const double x = std::clamp(m.median[static_cast<size_t>(c)], 0.0, 1.0);
      Candidate one;
      one.shot = int(s);
      one.patch = p;
      one.observation.x = x;
      one.observation.y = t[s] * (neutral ? chart::reference()[static_cast<size_t>(p)].Y : 1.0);
      one.observation.fold = p % chart::kColumns;  // 6 folds: a column (one grey, three colours) held out
      one.observation.weight = x > 0 ? (x / one.observation.y) * (x / one.observation.y) : 0.0;
      if (neutral) one.observation.weight *= options.grey_weight;
      if (m.clipped_high) one.observation.kind = ScaledObservation::Kind::AtMost;
      else if (!m.usable() || (!neutral && x < options.colour_floor)) {
        ++data.rejected;
        continue;
      } else {
        ++exact_count[{shots[s].scene, neutral ? -1 : p}];
      }
      candidates.push_back(one);
    }
  std::map<std::pair<int, int>, int> group, cluster;
  std::vector<Candidate> bounds;
  std::vector<int> bound_clusters;
  for (Candidate& one : candidates) {
    const bool neutral = chart::reference()[static_cast<size_t>(one.patch)].neutral;
    const std::pair<int, int> key{shots[static_cast<size_t>(one.shot)].scene, neutral ? -1 : one.patch};
    if (exact_count[key] < (neutral ? 1 : 2) || excluded.count(key)) {
      ++data.rejected;
      continue;
    }
    one.observation.group = group.emplace(key, int(group.size())).first->second;
    const int unit =
        cluster.emplace(std::pair{shots[static_cast<size_t>(one.shot)].scene, one.patch}, int(cluster.size())).first->second;
    if (one.observation.kind == ScaledObservation::Kind::Exact) {
      data.observations.push_back(one.observation);
      data.origin.emplace_back(one.shot, one.patch);
      data.cluster.push_back(unit);
    } else {
      bounds.push_back(one);
      bound_clusters.push_back(unit);
      ++data.rejected;
    }
  }
  data.exact = data.observations.size();
  for (const Candidate& one : bounds) data.observations.push_back(one.observation);
  data.cluster.insert(data.cluster.end(), bound_clusters.begin(), bound_clusters.end());
  return data;
}

// Coloured patches that do not follow the channel's curve (a camera's gamut mapping or hue-dependent rendering is not
// one curve per channel): per patch the RMS relative misfit (y/(σφ(x)) − 1, its own best σ against `fit`); those
// above options.colour_outlier_factor × the median over the coloured patches are left out of the next fit.
std::set<GroupKey> outlierPatches(const std::vector<ChartShot>& shots, const ChannelData& all, const ScaledFitResult& fit,
                                  const ChartCalibrationOptions& options) {
  std::set<GroupKey> excluded;
  if (options.colour_outlier_factor <= 0) return excluded;
  std::map<GroupKey, std::vector<std::pair<double, double>>> groups;  // key → (y, φ(x)) of its exact samples
  for (size_t i = 0; i < all.exact; ++i) {
    const auto [shot, patch] = all.origin[i];
    if (chart::reference()[static_cast<size_t>(patch)].neutral) continue;
    const ScaledObservation& o = all.observations[i];
    groups[{shots[static_cast<size_t>(shot)].scene, patch}].emplace_back(o.y, evaluateInverse(fit.model, o.x));
  }
  std::map<GroupKey, double> misfit;
  for (const auto& [key, samples] : groups) {
    double num = 0, den = 0;  // σ minimising Σ (log y − log σφ)²: the geometric mean of y/φ
    for (const auto& [y, phi] : samples)
      if (phi > 0) num += std::log(y / phi), den += 1;
    if (den < 2) continue;
    const double sigma = std::exp(num / den);
    double sum = 0;
    for (const auto& [y, phi] : samples)
      if (phi > 0) sum += std::pow(y / (sigma * phi) - 1, 2);
    misfit[key] = std::sqrt(sum / den);
  }
  if (misfit.size() < 4) return excluded;
  std::vector<double> values;
  for (const auto& [key, m] : misfit) values.push_back(m);
  std::nth_element(values.begin(), values.begin() + long(values.size() / 2), values.end());
  const double limit = options.colour_outlier_factor * std::max(values[values.size() / 2], 0.005);
  for (const auto& [key, m] : misfit)
    if (m > limit) excluded.insert(key);
  return excluded;
}

// Start: per shot the median over its usable greys and channels of g0(x)/Y (g0 = the EMoR mean curve).
std::vector<double> startExposures(const std::vector<ChartShot>& shots, const std::vector<int>& channels) {
  std::vector<double> t(shots.size(), 0.0);
  for (size_t s = 0; s < shots.size(); ++s) {
    std::vector<double> logs;
    for (int p = 0; p < chart::kPatches; ++p) {
      const chart::PatchStats& m = shots[s].measured[static_cast<size_t>(p)];
      if (!chart::reference()[static_cast<size_t>(p)].neutral || !m.usable()) continue;
      for (int c : channels) {
        const double phi = evaluateInverse(EmorModel{}, std::clamp(m.median[static_cast<size_t>(c)], 0.0, 1.0));
        if (phi > 1e-4) logs.push_back(std::log(phi / chart::reference()[static_cast<size_t>(p)].Y));
      }
    }
    if (logs.empty()) continue;
    std::nth_element(logs.begin(), logs.begin() + long(logs.size() / 2), logs.end());
    t[s] = std::exp(logs[logs.size() / 2]);
  }
  return t;
}

// The brightest shot at 1; shots without any estimate get the median of the others (they add no data anyway).
void normalise(std::vector<double>& t) {
  std::vector<double> known;
  for (double v : t)
    if (v > 0) known.push_back(v);
  if (known.empty()) throw InvalidInput("chart calibration: no usable grey patch in any shot");
  std::sort(known.begin(), known.end());
  const double top = known.back(), fill = known[known.size() / 2];
  for (double& v : t) v = (v > 0 ? v : fill) / top;
}

// One exposure round: t_j ← median over the shot's exact samples (all channels) of σ_g·φ(x)·t_j/y.
std::vector<double> refitExposures(const std::vector<ChannelData>& data, const std::vector<ScaledFitResult>& fits,
                                   const std::vector<double>& t) {
  std::vector<std::vector<double>> logs(t.size());
  for (size_t c = 0; c < data.size(); ++c)
    for (size_t i = 0; i < data[c].exact; ++i) {
      const ScaledObservation& o = data[c].observations[i];
      const double s = fits[c].scales[static_cast<size_t>(o.group)];
      const double phi = evaluateInverse(fits[c].model, o.x);
      const auto shot = static_cast<size_t>(data[c].origin[i].first);
      if (s > 0 && phi > 0) logs[shot].push_back(std::log(s * phi * t[shot] / o.y));
    }
  std::vector<double> next = t;
  for (size_t j = 0; j < t.size(); ++j) {
    if (logs[j].empty()) continue;
    std::nth_element(logs[j].begin(), logs[j].begin() + long(logs[j].size() / 2), logs[j].end());
    next[j] = std::exp(logs[j][logs[j].size() / 2]);
  }
  normalise(next);
  return next;
}

}  // namespace

ChartCalibrationResult calibrateChartAllPatches(const std::vector<ChartShot>& shots,
                                                const ChartCalibrationOptions& options,
                                                const ProgressCallback& progress) {
  bool all_exposures = true;
  for (const auto& shot : shots) {
    if (shot.measured.size() != size_t(chart::kPatches))
      throw InvalidInput("shot " + shot.name + ": expected 24 sampled patches");
    all_exposures = all_exposures && shot.exposure > 0;
  }
  ChartCalibrationResult result;
  ChartCalibrationOptions fitted = options;
  fitted.fit.profile_scales = true;  // one scale per coloured patch and scene: profiled out
  // Up to 96 observations per channel and 6 folds × K: the bracket's speed settings (φ' ≥ 0 between 256 nodes, the
  // table made exactly monotone afterwards; 400 evaluations) keep a call of 4 shots well under a second.
  fitted.fit.monotone_grid = std::min(fitted.fit.monotone_grid, 256);
  fitted.fit.max_evaluations = std::min(fitted.fit.max_evaluations, 400);
  std::vector<double> t(shots.size());
  if (all_exposures) {
    for (size_t j = 0; j < shots.size(); ++j) t[j] = shots[j].exposure;
    normalise(t);
  } else {
    t = startExposures(shots, options.channels);
    normalise(t);
    if (shots.size() > 1)
      result.warnings.push_back("no exposure ratios for all shots: the exposures are fitted from the patches");
  }
  // Rounds: the curves with K = 3 on the patches kept so far, the outlying coloured patches against them, and (without
  // given exposures) the exposures; one round with the exposures given, to find the outliers.
  const int rounds = all_exposures ? 1 : (shots.size() > 1 ? std::max(options.exposure_rounds, 1) : 1);
  std::vector<std::set<GroupKey>> excluded(options.channels.size());
  for (int round = 0; round < rounds; ++round) {
    std::vector<ChannelData> data;
    std::vector<ScaledFitResult> fits;
    for (size_t ci = 0; ci < options.channels.size(); ++ci) {
      const int c = options.channels[ci];
      data.push_back(channelObservations(shots, c, t, options, excluded[ci]));
      if (data.back().exact < 4)
        throw InvalidInput("channel " + channelName(c) + ": only " + std::to_string(data.back().exact) +
                           " usable patch samples (need ≥ 4)");
      fits.push_back(fitScaledInverseFixed(data.back().observations, std::min(3, options.fit.max_terms), fitted.fit));
      excluded[ci] = outlierPatches(shots, channelObservations(shots, c, t, options), fits.back(), options);
    }
    if (!all_exposures && shots.size() > 1) t = refitExposures(data, fits, t);
    if (progress) progress(0.5 * double(round + 1) / rounds, "exposures");
  }
  result.exposures = t;
  for (size_t ci = 0; ci < options.channels.size(); ++ci) {
    const int c = options.channels[ci];
    ChannelData data = channelObservations(shots, c, t, options, excluded[ci]);
    ChartChannelResult channel = fitChartChannel(c, data.observations, data.exact, data.origin, fitted, result.warnings);
    channel.rejected = data.rejected;
    if (options.band.replicates > 0)
      channel.band = scaledFitBand(data.observations, data.cluster, fitted.fit, channel.fit, options.band);
    result.channels.push_back(std::move(channel));
    if (progress) progress(0.5 + 0.5 * double(ci + 1) / double(options.channels.size()), channelName(c));
  }
  return result;
}

}  // namespace crfcal::detail
