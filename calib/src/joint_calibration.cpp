// Several pairs of one camera calibrated jointly (joint_calibration.hpp): the joint φ per channel, its band from
// joint half-samples, and the verdict on the union of the pairs' covered ranges.
#include "crfcal/joint_calibration.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <sstream>

#include "crfcal/error.hpp"
#include "crfcal/joint_crf_fit.hpp"

namespace crfcal {
namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

std::string format(const char* pattern, double a, double b = 0) {
  char buffer[96];
  std::snprintf(buffer, sizeof buffer, pattern, a, b);
  return buffer;
}

// The channels every pair fitted, in R, G, B order.
std::vector<std::string> commonChannels(const std::vector<PairCalibrationResult>& pairs) {
  std::vector<std::string> channels;
  for (const char* c : {"R", "G", "B"}) {
    bool everywhere = true;
    for (const auto& pair : pairs)
      everywhere = everywhere && pair.fits.count(c) && pair.fit_inputs.sharp.count(c);
    if (everywhere) channels.push_back(c);
  }
  return channels;
}

// Channel `c` of every pair as the joint fitter takes it; r starting at the pair's final single-pair r or its
// nominal one (options.ratio_source).
std::vector<JointFitPair> jointInputs(const std::vector<PairCalibrationResult>& pairs, const std::string& c,
                                      const JointCalibrationOptions& options) {
  std::vector<JointFitPair> inputs;
  for (const auto& pair : pairs) {
    const PairFitInputs& in = pair.fit_inputs;
    const bool nominal = options.ratio_source == JointCalibrationOptions::RatioSource::nominal;
    const double ratio = nominal ? pair.fits.at(c).nominal_ratio : pair.fits.at(c).ratio;
    JointFitPair p{in.sharp.at(c), in.blurred.at(c), in.kernel, in.options, ratio};
    if (const auto it = in.sharp_error.find(c); it != in.sharp_error.end()) p.options.sharp_error_bound = it->second;
    inputs.push_back(std::move(p));
  }
  return inputs;
}

// σ of log r of each pair's r (JointCalibrationOptions::band_varies_ratio).
std::vector<double> ratioLogSigmas(const std::vector<PairCalibrationResult>& pairs, const JointCalibrationOptions& options) {
  std::vector<double> sigmas;
  for (const auto& pair : pairs) {
    const RatioEvidence& e = pair.ratio_evidence;
    const bool nominal = options.ratio_source == JointCalibrationOptions::RatioSource::nominal;
    sigmas.push_back(!options.band_varies_ratio ? 0.0
                     : !nominal && e.combined  ? e.log_sigma
                                               : RatioEvidenceOptions{}.nominal_log_sigma);
  }
  return sigmas;
}

// The band of the joint φ: every replicate halves the blocks of every pair at once (complementary pairs of
// replicates in each pair) and draws each pair's r from its uncertainty (antithetic in each complementary pair),
// refits jointly, and bandFromReplicates turns the spread into the shape band and adds the scale bound above the
// union (curve_band.hpp).
CurveBand jointBand(const std::vector<JointFitPair>& inputs, const std::vector<double>& ratio_log_sigmas,
                    const JointCrfFitResult& fit, const JointCrfFitOptions& fit_options,
                    std::pair<double, double> covered, const CurveBandOptions& options) {
  const auto start = Clock::now();
  std::vector<std::vector<cv::Mat>> masks;  // per pair, per replicate (empty: the pair is used whole)
  for (std::size_t p = 0; p < inputs.size(); ++p) {
    const cv::Mat& k = inputs[p].kernel;
    const int block = std::max(options.block_size, 2 * std::max(k.rows, k.cols));
    masks.push_back(halfSampleMasks(fit.pixels[p].used_mask, block, options.replicates, options.seed + p));
  }
  std::vector<std::vector<double>> curves;
  int failed = 0;
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal;
  std::vector<double> z(inputs.size(), 0.0);
  for (int j = 0; j < options.replicates; ++j) {
    std::vector<JointFitPair> half = inputs;
    for (std::size_t p = 0; p < half.size(); ++p) {
      if (static_cast<int>(masks[p].size()) > j) half[p].options.pixel_selection = masks[p][j];
      z[p] = j % 2 ? -z[p] : normal(rng);
      half[p].ratio *= std::exp(z[p] * ratio_log_sigmas[p]);
    }
    try {
      curves.push_back(fitInverseCrfJointly(half, fit_options).fit.inverse_crf);
    } catch (const InvalidInput&) {
      ++failed;  // a half without enough edge pixels in some pair: the band rests on the others
    }
  }
  std::vector<std::vector<double>> alternatives;
  for (const auto& candidate : fit.fit.candidates)
    if (candidate.valid && candidate.kind != fit.fit.chosen && !candidate.inverse_crf.empty())
      alternatives.push_back(candidate.inverse_crf);
  CurveBand band = bandFromReplicates(fit.fit.inverse_crf, curves, covered, options, alternatives);
  band.failed_replicates = failed;
  band.seconds = secondsSince(start);
  return band;
}

// channel_verdict's judgement of the joint curve over the union's range (no r of its own: the pairs have theirs,
// each judged in its own verdict), at least weak when a pair's verdict was not ok.
void judgeJoint(JointCalibrationResult& result, const JointCalibrationOptions& options) {
  std::vector<ChannelEvidence> evidence;
  for (const auto& c : result.channels) {
    ChannelEvidence e;
    e.channel = c;
    e.ratio = 1;
    e.ratio_fixed = true;
    e.covered = result.covered_range.at(c);
    if (const auto band = result.bands.find(c); band != result.bands.end() && !band->second.empty())
      e.shape_band_sigma = medianShapeSigma(band->second);
    e.inverse_crf = result.fits.at(c).inverse_crf;
    evidence.push_back(e);
  }
  result.verdicts = judgeChannels(evidence, RefitEvidence{}, options.verdict);
  for (const auto& c : result.channels) {
    ChannelVerdict& v = result.verdicts.at(c);
    const bool passed = v.level == VerdictLevel::ok;
    if (passed) v.reasons.clear();
    std::vector<std::string> doubtful;
    for (std::size_t p = 0; p < result.pairs.size(); ++p) {
      const VerdictLevel level = result.pairs[p].verdict.at(c);
      if (level != VerdictLevel::ok)
        doubtful.push_back("pair " + std::to_string(p + 1) + " " + toString(level));
    }
    if (!doubtful.empty()) {
      std::string text = "the pairs' own verdicts are not all ok (";
      for (std::size_t i = 0; i < doubtful.size(); ++i) text += (i ? ", " : "") + doubtful[i];
      v.reasons.insert(v.reasons.begin(), text + "): their r, where the joint fit starts, is in doubt");
      v.level = std::max(v.level, VerdictLevel::weak);
    }
    if (passed && doubtful.empty())
      v.reasons.push_back(std::to_string(result.pairs.size()) + " pairs, each ok; data of the union cover " +
                          format("%.2f-%.2f", result.covered_range.at(c).first, result.covered_range.at(c).second));
  }
}

// A gap between the pairs' covered ranges: the union's envelope is not all data.
void warnAboutGaps(JointCalibrationResult& result) {
  for (const auto& c : result.channels) {
    std::vector<std::pair<double, double>> ranges;
    for (const auto& pair : result.pairs) ranges.push_back(pair.covered_range.at(c));
    std::sort(ranges.begin(), ranges.end());
    double reach = ranges.front().second;
    for (const auto& r : ranges) {
      if (r.first > reach)
        result.warnings.push_back(c + ": no pair covers x " + format("%.2f-%.2f", reach, r.first) +
                                  " (between the pairs' ranges): phi is interpolated there");
      reach = std::max(reach, r.second);
    }
  }
}

// Fraction of `phi`'s samples over [lo, hi] inside the band's [lower, upper].
double fractionInside(const std::vector<double>& phi, const CurveBand& band, std::pair<double, double> range) {
  int n = 0, inside = 0;
  for (std::size_t i = 0; i < phi.size() && i < band.lower.size(); ++i) {
    const double x = double(i) / (phi.size() - 1);
    if (x < range.first || x > range.second) continue;
    ++n;
    inside += phi[i] >= band.lower[i] - 1e-12 && phi[i] <= band.upper[i] + 1e-12;
  }
  return n > 0 ? double(inside) / n : 0.0;
}

// Channel `c` fitted jointly into `result`: each pair's r from its own fit, moved by the rounds when `ratios` is
// empty, else held at `ratios` (the rounds' r of the channel fitted first). Returns the r the fit used.
std::vector<double> fitJointChannel(const std::vector<PairCalibrationResult>& pairs, const std::string& c,
                                    const std::vector<double>& ratios, const JointCalibrationOptions& options,
                                    JointCalibrationResult& result) {
  auto start = Clock::now();
  std::vector<JointFitPair> inputs = jointInputs(pairs, c, options);
  std::vector<double> own_start;
  for (const JointFitPair& input : inputs) own_start.push_back(input.ratio);
  JointCrfFitOptions fit_options;
  fit_options.model = options.model;
  fit_options.pair_offsets = options.pair_offsets;
  fit_options.hold_ratios = !ratios.empty();
  fit_options.ratio_rounds = ratios.empty() || options.pair_offsets ? options.ratio_rounds : 0;
  fit_options.pair_misfits = true;
  for (std::size_t p = 0; p < inputs.size() && !ratios.empty(); ++p) inputs[p].ratio = ratios[p];
  JointCrfFitResult joint = fitInverseCrfJointly(inputs, fit_options);
  std::pair<double, double> covered{1, 0};
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    JointPairSummary& summary = result.pairs[p];
    const auto range = pairs[p].covered_range.count(c)
                           ? pairs[p].covered_range.at(c)
                           : std::pair<double, double>{joint.covered_levels[p].first / (joint.fit.levels - 1.0),
                                                       joint.covered_levels[p].second / (joint.fit.levels - 1.0)};
    summary.covered_range[c] = range;
    summary.ratio_start[c] = own_start[p];
    summary.ratio[c] = joint.ratios[p];
    summary.ratio_at_joint_phi[c] = joint.ratios_at_joint_phi[p];
    if (options.pair_offsets) summary.offset[c] = joint.offsets[p];
    if (std::isfinite(joint.misfit(p))) summary.joint_misfit[c] = joint.misfit(p);
    summary.pixels_used[c] = joint.pixels[p].used;
    const auto verdict = pairs[p].verdicts.find(c);
    summary.verdict[c] = verdict == pairs[p].verdicts.end() ? VerdictLevel::ok : verdict->second.level;
    covered = {std::min(covered.first, range.first), std::max(covered.second, range.second)};
  }
  result.covered_range[c] = covered;
  result.timings["joint_fit"] += secondsSince(start);
  if (options.band.replicates > 0) {
    start = Clock::now();
    // The replicates start from the r the joint fit used and draw around it; they do not move it again (the rounds
    // would pull each draw back to the data's r).
    for (std::size_t p = 0; p < inputs.size(); ++p) {
      inputs[p].ratio = joint.ratios[p];
      inputs[p].offset = joint.offsets[p];
    }
    JointCrfFitOptions band_fit = fit_options;
    band_fit.ratio_rounds = 0;
    band_fit.pair_offsets = false;  // held at the joint fit's (above)
    band_fit.pair_misfits = false;  // the replicates' misfits are not read
    result.bands[c] = jointBand(inputs, ratioLogSigmas(pairs, options), joint, band_fit, covered, options.band);
    result.timings["joint_band"] += secondsSince(start);
    for (std::size_t p = 0; p < pairs.size(); ++p)
      result.pairs[p].own_curve_inside_band[c] =
          fractionInside(pairs[p].fits.at(c).inverse_crf, result.bands[c], result.pairs[p].covered_range.at(c));
  }
  result.fits[c] = std::move(joint.fit);
  return joint.ratios;
}

}  // namespace

void JointCalibrationOptions::check() const {
  if (ratio_rounds < 0 || ratio_rounds > 20)
    throw InvalidInput("joint calibration: ratio_rounds must be in 0..20", ErrorSubject::options);
  if (pair_offsets && ratio_rounds < 1)
    throw InvalidInput("joint calibration: the pairs' offsets move in the rounds: ratio_rounds must be at least 1",
                       ErrorSubject::options);
  model.check();
  band.check();
  verdict.check();
}

std::string JointCalibrationResult::summary() const {
  std::ostringstream s;
  s << "joint fit of " << pairs.size() << " pairs";
  for (const auto& [c, fit] : fits) {
    const auto [lo, hi] = covered_range.at(c);
    s << "\n" << c << ": " << describe(fit.model) << " (" << fit.chosen << "), union covered " << format("%.2f-%.2f", lo, hi);
    for (std::size_t p = 0; p < pairs.size(); ++p) {
      const auto [plo, phi] = pairs[p].covered_range.at(c);
      const double r = pairs[p].ratio.at(c), r0 = pairs[p].ratio_start.at(c);
      s << "\n  pair " << p + 1 << ": r "
        << (r == r0 ? format("%.4g held", r) : format("%.4g (from %.4g)", r, r0))
        << format(" (at the joint phi %.4g)", pairs[p].ratio_at_joint_phi.at(c))
        << ", covered " << format("%.2f-%.2f", plo, phi) << ", " << pairs[p].pixels_used.at(c) << " pixels";
      if (const auto it = pairs[p].own_curve_inside_band.find(c); it != pairs[p].own_curve_inside_band.end())
        s << format(", its own phi inside the joint band over its range: %.0f %%", 100 * it->second);
      if (const auto it = pairs[p].offset.find(c); it != pairs[p].offset.end())
        s << format(", offset %+.4f", it->second);
      if (const auto it = pairs[p].joint_misfit.find(c); it != pairs[p].joint_misfit.end())
        s << format(", misfit %.3gx", it->second);
    }
  }
  for (const auto& [c, band] : bands) s << "\nband " << c << ": " << band.summary();
  return s.str();
}

JointCalibrationResult calibrateJointly(const std::vector<PairCalibrationResult>& pairs,
                                        const JointCalibrationOptions& options) {
  options.check();
  if (pairs.size() < 2) throw InvalidInput("a joint calibration needs at least two pairs", ErrorSubject::options);
  for (std::size_t p = 0; p < pairs.size(); ++p)
    if (pairs[p].fit_inputs.empty())
      throw InvalidInput("pair " + std::to_string(p + 1) + ": its fit inputs were not kept (keep_fit_inputs)",
                         ErrorSubject::options);
  JointCalibrationResult result;
  result.channels = commonChannels(pairs);
  if (result.channels.empty()) throw InvalidInput("the pairs have no fitted channel in common", ErrorSubject::pair);
  result.pairs.resize(pairs.size());
  // r is the exposure's, one per pair for every channel (as a single pair's, pair_stage_ratio.cpp): the rounds run
  // on G (else the first channel), and the other channels are fitted at the r they settled at.
  std::vector<std::string> order = result.channels;
  std::stable_partition(order.begin(), order.end(), [](const std::string& c) { return c == "G"; });
  std::vector<double> settled;
  for (const auto& c : order) settled = fitJointChannel(pairs, c, settled, options, result);
  warnAboutGaps(result);
  judgeJoint(result, options);
  return result;
}

}  // namespace crfcal
