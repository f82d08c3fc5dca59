#pragma once
// One inverse response φ from several pairs of one camera (issue 19: "several pairs, fitted jointly"). Each pair
// has its own kernel K_p and exposure ratio r_p; φ is common. With the moments objective (crf_fitter.hpp) each pair
// contributes its own instrument bins k with the rows (r_p Ĥ_k − N_k) · φ of Eq. 4 in the irradiance domain; the
// joint objective is the sum over the pairs' bins, J(φ) = Σ_p Σ_{k∈p} ω_k ((r_p Ĥ_k − N_k) · φ / s_k)², so the
// intensities the pairs cover add up: a level one pair does not reach is data for another, and φ(1) = 1 is
// extrapolated from the top of the union instead of each pair's own top.
// For the φ fit each r_p is held (at the value the caller gives, e.g. the pair's single-pair r after its evidence
// with EXIF, ratio_evidence.hpp): with r_p held the pairs' rows stack into one moment problem at r = 1, and the
// fitter's model selection (GGCM vs EMoR by 2-fold cross-validation), priors and validity checks apply unchanged.
// At the joint φ the closed-form r of each pair (the least-squares r of its rows, as Eq. 25 does for the seed
// objective) is reported; with JointCrfFitOptions::ratio_rounds each r_p then moves there and φ is refitted, until
// no r moves (alternating, as Eq. 25 alternates with φ in a single pair). Then the pairs' relative exposures come
// from all their data, and the pairs' r agree with one another (docs/RESULTS.md#joint-ratio-rounds).
// The common exponent is not fixed by the rounds: φ^γ with every r_p^γ fits all the pairs alike, so it stays
// where the starting r put it. Each pair's misfit can be measured too (pair_misfits): its rows' energy at the
// joint φ against their energy at a φ fitted to that pair alone at the same r (the energy is scale-free, so only
// φ's shape over the pair's data counts, and at one r the exponent valley is out of it: a pair whose own r was off
// is not a disagreement). Pairs of one camera agree, and their misfit stays small; a pair whose shots break what
// the others share (an offset in one shot, which a single pair absorbs into its own φ + c / (r − 1); a tone curve
// of its own) cannot be fitted by the common φ, and its misfit grows (docs/RESULTS.md#joint-misfit).
// Pure computation: no file I/O, no printing.
#include <string>
#include <utility>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/crf_fitter.hpp"

namespace crfcal {

// One pair's data, as fitInverseCrf takes it.
struct JointFitPair {
  cv::Mat sharp, blurred;  // registered single-channel images (CV_8U, CV_16U or floating point in [0, 1])
  cv::Mat kernel;          // the pair's blur kernel (normalised internally)
  // The pair's own fit options: noise handling and σ, saturation levels, edge threshold, pixel selection, chroma
  // error bound. Their model, prior and ratio settings are not used (JointCrfFitOptions::model decides those).
  CrfFitOptions options;
  double ratio = 1;        // r_p (> 0): held, or the start of JointCrfFitOptions::ratio_rounds
  double offset = 0;       // c_p (JointCrfFitOptions::pair_offsets): held, or the start of the rounds
};

struct JointCrfFitOptions {
  // The model of φ and its priors (model, ggcm_degree, emor_terms, exponent_smoothness, shoulder_prior,
  // prior_energy_factor, min_local_exponent, multi_starts, max_evaluations, threads). Its ratio settings are
  // ignored (each pair has its own r); only the moments objective (the default) can be fitted jointly.
  CrfFitOptions model;
  // Rounds that move each pair's r to the least-squares r of its own rows at the joint φ, then refit φ (0: every r
  // held at JointFitPair::ratio). The pairs then agree on their relative exposures from all their data; the common
  // exponent (φ^γ with every r_p^γ fits alike) stays where the starting r put it.
  int ratio_rounds = 0;
  double ratio_tolerance = 1e-3;  // the rounds stop when no pair's r moves by more than this (in log r) ...
  double offset_tolerance = 1e-4; // ... and no pair's offset by more than this (fraction of full scale)
  // An additive irradiance offset c_p for one pair, moved with r_p in the rounds (requires ratio_rounds > 0):
  // φ(B) = r_p (φ(I) ⊗ K_p) + c_p, a flare or black level in the blurred shot (an offset c_I in the sharp shot is
  // c_p = r_p c_I). One pair alone cannot see it (φ + c / (r − 1) fits as well). It enters the rows through
  // φ(1) = 1: N_k φ − c m_k = (N_k − c m_k e_top) φ. As φ + δ with every c_p + δ (1 − r_p) fits all pairs alike
  // (held only by φ(0) = 0), the offsets are freed one pair at a time, the others held at JointFitPair::offset, and
  // the fit with the lowest stacked energy is kept (no offset included): P + 1 joint fits. Identified where that
  // pair is at r = 1; at r ≫ 1 it trades with the pair's r and is often placed in the wrong pair
  // (docs/RESULTS.md#joint-offsets).
  bool pair_offsets = false;
  // The rounds move only the offsets; every r_p stays at JointFitPair::ratio (the other channels of a pair, fitted at
  // the r its first channel settled at).
  bool hold_ratios = false;
  // Each pair also fitted alone, at the r the joint fit gives it, with the same model and priors: the reference of
  // its misfit (JointCrfFitResult::misfit). One more fit per pair; off: no misfit measured.
  bool pair_misfits = false;
  void check() const;  // throws InvalidInput
};

struct JointCrfFitResult {
  CrfFitResult fit;  // the joint φ; fit.ratio = 1 and fit.covered_levels the union's envelope
  std::vector<double> start_ratios;                  // r_p as given (JointFitPair::ratio)
  std::vector<double> ratios;                        // r_p the joint φ was fitted at (the starts without rounds)
  int ratio_rounds = 0;                              // rounds that moved r (JointCrfFitOptions::ratio_rounds)
  std::vector<double> ratios_at_joint_phi;           // per pair the least-squares r of its rows at the joint φ
  // per pair the offset c_p the joint φ was fitted at (JointCrfFitOptions::pair_offsets; all 0 without), as a
  // fraction of full-scale irradiance (φ(1) = 1), and the least-squares offset of its rows at the joint φ
  std::vector<double> offsets, offsets_at_joint_phi;
  // pair_offsets: the stacked rows' energy (per unit weight, priors aside) with no offset fitted, and with pair p's
  // alone; -1: not fitted
  double no_offset_energy = -1;
  std::vector<double> offset_energies;
  std::vector<std::pair<int, int>> covered_levels;   // per pair (0.1 % tails dropped, as CrfFitResult's)
  std::vector<CrfPixelAccounting> pixels;            // per pair
  std::vector<double> energies;                      // per pair: its rows' energy at the joint φ (per unit weight)
  // per pair: its rows' energy at its own φ, fitted to them alone at the same r (JointCrfFitOptions::pair_misfits;
  // < 0: not measured)
  std::vector<double> own_energies;
  // energies[p] / own_energies[p]: how much worse the joint φ fits pair p's data than a φ fitted to that pair alone
  // at the same r (≥ about 1; ≈ 1 when the pairs agree); NaN when not measured, or when the own fit's energy is 0 or
  // not finite.
  double misfit(std::size_t p) const;
  std::string summary() const;
};

// Throws InvalidInput for no pairs, a pair the single fitter would refuse (size mismatch, no usable edges; the
// message starts with "pair N: "), pairs on different level grids (8-bit with 16-bit) or the seed objective.
JointCrfFitResult fitInverseCrfJointly(const std::vector<JointFitPair>& pairs, const JointCrfFitOptions& options = {});

}  // namespace crfcal
