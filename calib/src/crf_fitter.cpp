#include "crfcal/crf_fitter.hpp"

// The fitter's steps live in internal headers next to this file: crf_preparation (the pair on levels, σ, the usable
// pixels, the noise operators), crf_objective (Eq. 22 and the moments), crf_priors, crf_optimisation (the solvers and
// the r alternation of Eq. 25), crf_model_selection (the candidates and the choice), crf_curve (the models).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <functional>
#include <optional>
#include <sstream>

#include "crf_model_selection.hpp"
#include "crf_objective.hpp"
#include "crf_preparation.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"

namespace crfcal {

const char* toString(CrfModelChoice value) {
  switch (value) {
    case CrfModelChoice::ggcm: return "ggcm";
    case CrfModelChoice::emor: return "emor";
    case CrfModelChoice::automatic: return "auto";
  }
  return "?";
}
const char* toString(CrfObjective value) {
  switch (value) {
    case CrfObjective::seed_intensity: return "seed_intensity";
    case CrfObjective::moments: return "moments";
  }
  return "?";
}
const char* toString(CrfOptimizer value) {
  switch (value) {
    case CrfOptimizer::nelder_mead: return "nelder_mead";
    case CrfOptimizer::levenberg_marquardt: return "levenberg_marquardt";
  }
  return "?";
}
const char* toString(NoiseHandling value) {
  switch (value) {
    case NoiseHandling::none: return "none";
    case NoiseHandling::debias: return "debias";
    case NoiseHandling::denoise: return "denoise";
    case NoiseHandling::jensen: return "jensen";
  }
  return "?";
}

NoiseHandling noiseHandlingFromString(const std::string& name) {
  for (NoiseHandling value : {NoiseHandling::none, NoiseHandling::debias, NoiseHandling::denoise, NoiseHandling::jensen})
    if (name == toString(value)) return value;
  throw InvalidInput("unknown noise handling '" + name + "' (none, jensen, debias, denoise)");
}

CrfFitOptions CrfFitOptions::seed() {
  CrfFitOptions o;
  o.model = CrfModelChoice::ggcm;
  o.experimental.objective = CrfObjective::seed_intensity;
  o.experimental.optimizer = CrfOptimizer::nelder_mead;
  o.experimental.noise = NoiseHandling::none;
  o.multi_starts = 1;
  o.max_pixels = 6000;  // deterministic subsample keeps one fit near a second (Nelder–Mead needs ~10³ evaluations)
  o.max_evaluations = 600;
  o.experimental.ratio_rounds = 3;
  return o;
}

void CrfFitOptions::check() const {
  if (ggcm_degree < 0 || ggcm_degree > 10) throw InvalidInput("fit options: ggcm_degree must be in [0, 10]");
  if (emor_terms < 1 || emor_terms > emor::kMaxTerms) throw InvalidInput("fit options: emor_terms must be in [1, 25]");
  if (!(experimental.tau1 >= 0) || !(experimental.tau2 >= 0))
    throw InvalidInput("fit options: experimental.tau1 and tau2 must be non-negative");
  if (!(nominal_ratio > 0) || !std::isfinite(nominal_ratio))
    throw InvalidInput("fit options: nominal_ratio must be positive");
  if (multi_starts < 1) throw InvalidInput("fit options: multi_starts must be at least 1");
  if (!(noise_sigma < 1)) throw InvalidInput("fit options: noise_sigma must be < 1");
  for (double s : noise_sigma_per_level)
    if (!(s >= 0 && s < 1)) throw InvalidInput("fit options: noise_sigma_per_level entries must be in [0, 1)");
  if (!(experimental.debias_regularization > 0))
    throw InvalidInput("fit options: experimental.debias_regularization must be positive");
  if (!(edge_threshold >= 0)) throw InvalidInput("fit options: edge_threshold must be non-negative");
  if (level_bins < 4 || level_bins > 1024) throw InvalidInput("fit options: level_bins must be in [4, 1024]");
  if (position_bins < 1 || position_bins > 16) throw InvalidInput("fit options: position_bins must be in [1, 16]");
  if (!(exponent_smoothness >= 0)) throw InvalidInput("fit options: exponent_smoothness must be >= 0");
  if (!(shoulder_prior >= 0)) throw InvalidInput("fit options: shoulder_prior must be >= 0");
  if (!(learned_prior_weight >= 0) || !std::isfinite(learned_prior_weight))
    throw InvalidInput("fit options: learned_prior_weight must be >= 0");
  if (learned_prior && learned_prior->empty()) throw InvalidInput("fit options: learned_prior has no training curves");
  if (!(prior_energy_factor >= 1)) throw InvalidInput("fit options: prior_energy_factor must be >= 1");
  if (!(ratio_prior_sigma >= 0) || !std::isfinite(ratio_prior_sigma))
    throw InvalidInput("fit options: ratio_prior_sigma must be >= 0");
  if (!(min_local_exponent >= 0 && min_local_exponent < 1))
    throw InvalidInput("fit options: min_local_exponent must be in [0, 1)");
  if (!(saturation_high > saturation_low)) throw InvalidInput("fit options: saturation_high must exceed saturation_low");
  if (!(censored_weight >= 0) || !std::isfinite(censored_weight))
    throw InvalidInput("fit options: censored_weight must be >= 0");
  if (!(censored_sigma_floor > 0) || !std::isfinite(censored_sigma_floor))
    throw InvalidInput("fit options: censored_sigma_floor must be positive");
  if (!(censored_margin >= 0) || !std::isfinite(censored_margin))
    throw InvalidInput("fit options: censored_margin must be >= 0");
  if (max_censored_pixels < 0) throw InvalidInput("fit options: max_censored_pixels must be >= 0");
  if (experimental.ratio_rounds < 1) throw InvalidInput("fit options: experimental.ratio_rounds must be >= 1");
  if (max_evaluations < 10) throw InvalidInput("fit options: max_evaluations must be at least 10");
  if (min_pixels < 1) throw InvalidInput("fit options: min_pixels must be positive");
  if (max_pixels < 0) throw InvalidInput("fit options: max_pixels must be >= 0");
  if (threads < 0) throw InvalidInput("fit options: threads must be >= 0");
  if (start && (!(start->ratio > 0) || !std::isfinite(start->ratio)))
    throw InvalidInput("fit options: start.ratio must be positive");
}

std::string CrfFitResult::summary() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(6);
  s << "phi: " << describe(model) << " (" << chosen << ", " << choice_reason << ")\n";
  s << "ratio r = " << ratio << " (nominal " << nominal_ratio << "), energy " << energy << ", iterations "
    << iterations << ", evaluations " << evaluations << ", ambiguity rise " << ambiguity_rise << "\n";
  for (const auto& c : candidates)
    s << "  candidate " << c.kind << ": energy " << c.energy << ", criterion " << c.criterion
      << (c.valid ? "" : " (invalid)") << ", r " << c.ratio << "\n";
  s << "pixels: " << pixels.used << " used of " << pixels.total << " (border " << pixels.border << ", saturated "
    << pixels.saturated << ", unmodelled " << pixels.unmodelled << ", low weight " << pixels.low_weight << ", subsampled " << pixels.subsampled << ")";
  if (pixels.censored_clipped > 0)
    s << "; censored: " << pixels.censored_clipped << " clipped in B";
  s << "\n";
  s.precision(4);
  s << "noise sigma of I: " << noise_sigma << (noise_sigma_estimated ? " (estimated)" : " (given)") << "; "
    << toString(objective) << ", " << toString(optimizer) << ", " << levels << " levels, " << moment_bins
    << " moment bins, " << mixture_nonzeros << " mixture non-zeros\n";
  s << "time: prepare " << timings.prepare_s << " s, mixtures " << timings.mixture_s << " s, optimise "
    << timings.optimise_s << " s, total " << timings.total_s << " s";
  return s.str();
}

namespace {

using Clock = std::chrono::steady_clock;
double secondsSince(Clock::time_point t0) { return std::chrono::duration<double>(Clock::now() - t0).count(); }

// Never a curve that fails validation (e.g. NaN): the γ = 2.2 start instead.
void ensureValid(const CrfFitOptions& options, CrfFitResult& result) {
  if (checkValidity(TableModel{result.inverse_crf}, kCurveSamples, 1e-6)) return;
  result.model = ggcm::fromGamma(2.2, options.ggcm_degree);
  result.inverse_crf = sampleValidTable(result.model);
  result.chosen = "fallback";
  result.choice_reason = "the chosen curve failed validation; returned the gamma 2.2 start";
}

}  // namespace

namespace {

// What a fit prepares before it optimises: the pixels, the noise operators and (moment objectives) the moments. With
// the moment objectives none of it depends on r, the ratio's prior or the start (CrfFitOptions::fit_ratio,
// nominal_ratio, ratio_prior_*, start); the seed's intensity objective selects pixels by r (Eq. 23/24).
// Built in place and never moved: the moments keep a pointer to the noise operators' level operator.
struct PreparedFit {
  PreparedFit(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel, const CrfFitOptions& options,
              Clock::time_point t_start)
      : base(baseResult(options)),
        prep(crf_fit::preparePair(sharp, blurred, kernel, options, base)),
        noise(crf_fit::makeNoiseOperators(prep, options)) {
    base.timings.prepare_s = secondsSince(t_start);
    if (options.progress) options.progress(0.1, "prepare");
    if (options.experimental.objective == CrfObjective::seed_intensity) return;
    const auto t_moments = Clock::now();
    const int threads = options.threads > 0 ? options.threads : std::max(1, cv::getNumThreads());
    problem.emplace(crf_fit::buildMomentProblem(prep, noise, options, threads, base));
    base.timings.optimise_s = secondsSince(t_moments);  // counted with the optimisation, as before the split
  }
  PreparedFit(const PreparedFit&) = delete;
  PreparedFit& operator=(const PreparedFit&) = delete;

  static CrfFitResult baseResult(const CrfFitOptions& options) {
    CrfFitResult r;
    r.nominal_ratio = options.nominal_ratio;
    r.objective = options.experimental.objective;
    r.optimizer = options.experimental.optimizer;
    return r;
  }

  CrfFitResult base;  // the result's fields the preparation fills (pixels, noise, levels, bins, covered levels, times)
  crf_fit::Prepared prep;
  crf_fit::NoiseOperators noise;
  std::optional<crf_fit::MomentProblem> problem;
};

// The candidates, the choice and the curve on a prepared fit (the rest of fitInverseCrf).
CrfFitResult solvePreparedFit(const PreparedFit& prepared, const CrfFitOptions& options, Clock::time_point t_start) {
  using namespace crf_fit;
  const ProgressFn report = [&](double fraction, const std::string& stage) {
    if (options.progress) options.progress(fraction, stage);
  };
  CrfFitResult result = prepared.base;
  result.nominal_ratio = options.nominal_ratio;
  const auto t_opt = Clock::now();
  MomentSystem full;  // moments: all the data (the ambiguity check evaluates on it)
  std::vector<CrfCandidate> candidates =
      prepared.problem ? momentCandidates(*prepared.problem, prepared.noise, options, result, report, full)
                       : seedCandidates(prepared.prep, prepared.noise, options, result, report);
  result.timings.optimise_s += secondsSince(t_opt);

  const bool chosen = chooseCandidate(candidates, options, result);
  result.candidates = std::move(candidates);
  result.inverse_crf = sampleValidTable(result.model);
  if (prepared.problem && chosen && full.h.rows() > 0 && result.energy > 0)
    result.ambiguity_rise = ambiguityRise(full, result.inverse_crf, result.ratio);
  ensureValid(options, result);
  result.timings.total_s = secondsSince(t_start);
  report(1.0, "done");
  return result;
}

}  // namespace

CrfFitResult fitInverseCrf(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                           const CrfFitOptions& options) {
  options.check();
  const auto t_start = Clock::now();
  const PreparedFit prepared(sharp, blurred, kernel, options, t_start);
  return solvePreparedFit(prepared, options, t_start);
}

CrfFitAtHeldRatio fitInverseCrfThenHoldRatio(const cv::Mat& sharp, const cv::Mat& blurred, const cv::Mat& kernel,
                                             const CrfFitOptions& options,
                                             const std::function<double(double fitted_ratio)>& held_ratio) {
  options.check();
  if (!options.fit_ratio) throw InvalidInput("fit options: holding r after the fit needs fit_ratio");
  const auto held_options = [&](const CrfFitResult& free_fit) {
    CrfFitOptions held = options;
    held.fit_ratio = false;
    held.nominal_ratio = held_ratio(free_fit.ratio);
    if (held.start) held.start = CrfFitOptions::Start{free_fit.model, held.nominal_ratio};
    return held;
  };
  if (options.experimental.objective == CrfObjective::seed_intensity) {  // its pixel selection depends on r (Eq. 23/24)
    CrfFitAtHeldRatio fits;
    fits.free_ratio = fitInverseCrf(sharp, blurred, kernel, options);
    fits.held_ratio = fitInverseCrf(sharp, blurred, kernel, held_options(fits.free_ratio));
    return fits;
  }
  const auto t_start = Clock::now();
  const PreparedFit prepared(sharp, blurred, kernel, options, t_start);
  CrfFitAtHeldRatio fits;
  fits.free_ratio = solvePreparedFit(prepared, options, t_start);
  const CrfFitOptions held = held_options(fits.free_ratio);
  held.check();
  fits.held_ratio = solvePreparedFit(prepared, held, Clock::now());
  return fits;
}

std::vector<CrfFitResult> fitInverseCrfAtHeldRatios(const cv::Mat& sharp, const cv::Mat& blurred,
                                                    const cv::Mat& kernel, const CrfFitOptions& options,
                                                    const std::vector<double>& ratios) {
  for (double r : ratios)
    if (!(r > 0 && std::isfinite(r))) throw InvalidInput("fit options: a held ratio must be positive");
  const auto held_options = [&](double ratio) {
    CrfFitOptions held = options;
    held.fit_ratio = false;
    held.nominal_ratio = ratio;
    if (held.start) held.start->ratio = ratio;
    held.check();
    return held;
  };
  std::vector<CrfFitResult> fits;
  if (ratios.empty()) return fits;
  if (options.experimental.objective == CrfObjective::seed_intensity) {  // its pixel selection depends on r
    for (double r : ratios) fits.push_back(fitInverseCrf(sharp, blurred, kernel, held_options(r)));
    return fits;
  }
  const auto t_start = Clock::now();
  const CrfFitOptions first = held_options(ratios.front());
  const PreparedFit prepared(sharp, blurred, kernel, first, t_start);
  for (double r : ratios) fits.push_back(solvePreparedFit(prepared, held_options(r), Clock::now()));
  return fits;
}

}  // namespace crfcal

