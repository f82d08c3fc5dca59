#pragma once
// One inverse response φ from several pairs of one camera (issue 19: "several pairs, fitted jointly"). Each pair
// has its own kernel K_p and exposure ratio r_p; φ is common. With the moments objective (crf_fitter.hpp) each pair
// contributes its own instrument bins k with the rows (r_p Ĥ_k − N_k) · φ of Eq. 4 in the irradiance domain; the
// joint objective is the sum over the pairs' bins, J(φ) = Σ_p Σ_{k∈p} ω_k ((r_p Ĥ_k − N_k) · φ / s_k)², so the
// intensities the pairs cover add up: a level one pair does not reach is data for another, and φ(1) = 1 is
// extrapolated from the top of the union instead of each pair's own top.
// r_p is HELD (at the value the caller gives, e.g. the pair's single-pair r after its evidence with EXIF,
// ratio_evidence.hpp): with r_p held the pairs' rows stack into one moment problem at r = 1, and the fitter's
// model selection (GGCM vs EMoR by 2-fold cross-validation), priors and validity checks apply unchanged. At the
// joint φ the closed-form r of each pair (the least-squares r of its rows, as Eq. 25 does for the seed objective)
// is reported as a check of that hold.
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
  double ratio = 1;        // r_p, held (> 0)
};

struct JointCrfFitOptions {
  // The model of φ and its priors (model, ggcm_degree, emor_terms, exponent_smoothness, shoulder_prior,
  // prior_energy_factor, min_local_exponent, multi_starts, max_evaluations, threads). Its ratio settings are
  // ignored (each pair's r is held); only the moments objective (the default) can be fitted jointly.
  CrfFitOptions model;
  void check() const;  // throws InvalidInput
};

struct JointCrfFitResult {
  CrfFitResult fit;  // the joint φ; fit.ratio = 1 and fit.covered_levels the union's envelope
  std::vector<double> ratios;                        // r_p as held
  std::vector<double> ratios_at_joint_phi;           // per pair the least-squares r of its rows at the joint φ
  std::vector<std::pair<int, int>> covered_levels;   // per pair (0.1 % tails dropped, as CrfFitResult's)
  std::vector<CrfPixelAccounting> pixels;            // per pair
  std::vector<double> energies;                      // per pair: its rows' energy at the joint φ (per unit weight)
  std::string summary() const;
};

// Throws InvalidInput for no pairs, a pair the single fitter would refuse (size mismatch, no usable edges; the
// message starts with "pair N: "), pairs on different level grids (8-bit with 16-bit) or the seed objective.
JointCrfFitResult fitInverseCrfJointly(const std::vector<JointFitPair>& pairs, const JointCrfFitOptions& options = {});

}  // namespace crfcal
