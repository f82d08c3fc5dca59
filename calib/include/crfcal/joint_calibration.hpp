#pragma once
// Several pairs of one camera calibrated jointly (issue 19; `crfcal calibrate --pair S1 B1 --pair S2 B2 …`):
// each pair goes through the single-pair pipeline (pair_calibration.hpp: registration, kernel, kernel↔φ rounds,
// r from its images combined with EXIF, its own verdict), then one φ per channel is fitted to all pairs' data at
// once (joint_crf_fit.hpp), each pair with its own kernel and its own r, which starts at the pair's final
// single-pair r and moves, in rounds, to the least-squares r of the pair's rows at the joint φ (ratio_rounds; the
// pairs' r then agree with one another, while their common exponent φ^γ, r^γ stays where the starts put it). The
// pairs' covered ranges add up: the joint curve is data wherever any pair has data, and the scale φ(1) = 1 is
// extrapolated from the top of the union.
//   Options → Summary: calibrateJointly(pair results, options) → JointCalibrationResult.
// The band (curve_band.hpp) is the single pair's, with the half-samples drawn in every pair at once (each pair's
// blocks halved, complementary pairs of replicates), over the union's envelope; the verdict per channel is
// channel_verdict's on the joint curve and the union's range, at least "weak" when a pair's own verdict was not ok
// (its r, the joint fit's start, is then in doubt). Each pair's misfit (JointPairSummary::joint_misfit) is reported
// but not judged: it rises with a shot's offset at r ≈ 1–2, and as much with the pairs' own noise biases at r = 4–8
// (docs/RESULTS.md#joint-misfit).
// Pure computation: no file I/O, no printing.
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "crfcal/channel_verdict.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal {

struct JointCalibrationOptions {
  // The model of the joint φ and its priors: the single pair's defaults (PairCalibrationOptions::fit), so that the
  // joint and the single fits differ only in their data. Its ratio settings are ignored: each pair has its own r.
  CrfFitOptions model = PairCalibrationOptions{}.fit;
  // Where each pair's r starts: its final single-pair r (pair_fit: the images combined with EXIF,
  // ratio_evidence.hpp) or its nominal ratio (EXIF or --ratio).
  enum class RatioSource { pair_fit, nominal };
  RatioSource ratio_source = RatioSource::pair_fit;
  // Rounds that move each pair's r from that start to its least-squares r at the joint φ (JointCrfFitOptions::
  // ratio_rounds; 0: held). The rounds stop once no r moves by 0.1 %, or after 10 (a cap). They run on G
  // (else the first channel); the other channels are fitted at the r they settled at, one r per pair as in a single
  // pair. Measured on `bench joint` (docs/RESULTS.md#joint-ratio-rounds): the pairs' r agree, and the joint φ's
  // shape error falls.
  int ratio_rounds = 10;
  // An additive irradiance offset (a flare or black level in one shot) for the one pair whose offset lowers the joint
  // energy most, moved in the rounds with its r (JointCrfFitOptions::pair_offsets; needs ratio_rounds ≥ 1), per
  // channel. Off: found where that pair is at r ≈ 1, placed in the wrong pair in most cases at r ≫ 1
  // (docs/RESULTS.md#joint-offsets).
  bool pair_offsets = false;
  CurveBandOptions band;   // the joint band (replicates = 0: none)
  // The band's replicates also draw each pair's r (as the joint fit settled it) from its uncertainty: log r + z·σ,
  // z ~ N(0, 1) (antithetic in each complementary pair of replicates), σ the pair's ratio evidence σ
  // (RatioEvidence::log_sigma; EXIF's nominal σ when the evidence was not combined or r is the nominal one). The
  // half-samples alone see only the images' sampling error, not the error of the r the joint fit holds, which
  // biases φ along φ^γ, r^γ.
  // false: r as the joint fit settled it in every replicate.
  bool band_varies_ratio = true;
  VerdictOptions verdict;  // the joint verdict's thresholds
  void check() const;      // throws InvalidInput
};

// What the joint fit took from one pair, and what it says about it.
struct JointPairSummary {
  std::map<std::string, double> ratio_start;         // per channel: the pair's final single-pair r (or its nominal)
  std::map<std::string, double> ratio;               // per channel: r of the joint fit (G's for every channel)
  std::map<std::string, double> ratio_at_joint_phi;  // per channel: the pair's least-squares r at the joint φ
  // per channel, with JointCalibrationOptions::pair_offsets: the pair's offset c_p the joint φ was fitted at
  // (φ(B) = r_p (φ(I) ⊗ K_p) + c_p, a fraction of full-scale irradiance)
  std::map<std::string, double> offset;
  std::map<std::string, std::pair<double, double>> covered_range;  // per channel: the pair's own covered range
  std::map<std::string, long long> pixels_used;      // per channel, in the joint fit
  std::map<std::string, VerdictLevel> verdict;       // per channel: the pair's own verdict
  // Per channel, with a band: the fraction of the pair's own φ samples over its own covered range that lie inside
  // the joint band [lower, upper] (issue 19: the joint band should contain each single pair's "ok" curve there).
  std::map<std::string, double> own_curve_inside_band;
  // Per channel: the pair's rows' energy at the joint φ ÷ at a φ fitted to that pair alone at the same r
  // (JointCrfFitResult::misfit; ≈ 1 when the pairs agree at r ≈ 1–2). Absent when that fit's energy is 0 or not
  // finite. A diagnostic, not a verdict ground (docs/RESULTS.md#joint-misfit).
  std::map<std::string, double> joint_misfit;
};

struct JointCalibrationResult {
  std::vector<std::string> channels;                 // fitted in every pair ("R","G","B" or "G")
  std::map<std::string, CrfFitResult> fits;          // the joint φ per channel (ratio 1: the pairs' r are below)
  std::vector<JointPairSummary> pairs;
  std::map<std::string, std::pair<double, double>> covered_range;  // per channel: the envelope of the pairs' ranges
  std::map<std::string, CurveBand> bands;            // per channel (empty when options.band.replicates = 0)
  std::map<std::string, ChannelVerdict> verdicts;
  std::vector<std::string> warnings;
  std::map<std::string, double> timings;             // seconds: "joint_fit", "joint_band"
  std::string summary() const;
};

// `pairs`: results of calibratePair with options.keep_fit_inputs (at least two). Throws InvalidInput for fewer than
// two pairs, a pair without its fit inputs, no channel common to all pairs, or a joint fit the fitter refuses
// (the message names the pair: "pair N: …").
JointCalibrationResult calibrateJointly(const std::vector<PairCalibrationResult>& pairs,
                                        const JointCalibrationOptions& options = {});

}  // namespace crfcal
