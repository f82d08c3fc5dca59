#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the candidate models and the choice among them. GGCM (seed
// Eq. 19) and EMoR are both fitted unless CrfFitOptions::model names one; with the moments, `automatic` picks the
// candidate with the lower 2-fold cross-validated energy (pixels split in 16×16 tiles, checkerboard; fit on one
// half, energy on the other, summed both ways). An invalid curve is never returned.
#include <functional>
#include <string>
#include <vector>

#include "crf_objective.hpp"
#include "crf_preparation.hpp"
#include "crfcal/crf_fitter.hpp"

namespace crfcal::crf_fit {

using ProgressFn = std::function<void(double fraction, const std::string& stage)>;

// The seed's objective (Eq. 22): GGCM from γ = 2.2 and EMoR from its mean curve, each by the Eq. 25 alternation;
// criterion = energy. Adds to result.iterations/evaluations and sets the mixture statistics.
std::vector<CrfCandidate> seedCandidates(const Prepared& prep, const NoiseOperators& noise,
                                         const CrfFitOptions& options, CrfFitResult& result, const ProgressFn& report);

// The moments: EMoR (with the ratio prior, if any), GGCM from the EMoR projection and γ starts, the optional CUE
// refinement; criterion = the cross-validated energy when the model is chosen automatically. full: the system of
// all the data (for the ambiguity check). Adds to result.iterations/evaluations and sets the ratio-prior results.
std::vector<CrfCandidate> momentCandidates(const MomentProblem& problem, const NoiseOperators& noise,
                                           const CrfFitOptions& options, CrfFitResult& result,
                                           const ProgressFn& report, MomentSystem& full);

// The valid candidate with the lowest criterion (the first on ties) into result (model, ratio, energy, chosen,
// choice_reason), or the γ = 2.2 fallback; samples every candidate's curve. Returns false for the fallback.
bool chooseCandidate(std::vector<CrfCandidate>& candidates, const CrfFitOptions& options, CrfFitResult& result);

// CrfFitResult::ambiguity_rise: the relative rise of the data energy of φ^γ, r^γ at γ = 1 ± 0.1.
double ambiguityRise(const MomentSystem& full, const std::vector<double>& inverse_crf, double ratio);

}  // namespace crfcal::crf_fit
