#include "crf_model_selection.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <exception>
#include <limits>
#include <utility>
#include <variant>

#include "crf_curve.hpp"
#include "crf_optimisation.hpp"
#include "crf_priors.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/ggcm.hpp"
#include "parallel_jobs.hpp"

namespace crfcal::crf_fit {
namespace {

CrfCandidate makeCandidate(const Curve& curve, const ModelFit& fit, double criterion) {
  CrfCandidate c;
  c.kind = curve.name();
  c.model = curve.model(fit.x);
  c.valid = fit.valid;
  c.ratio = fit.ratio;
  c.energy = fit.energy;
  c.criterion = criterion;
  c.evaluations = fit.evaluations;
  return c;
}

// The moment fits of one pair and the state they share.
struct MomentFitter {
  const MomentProblem& problem;
  const CrfFitOptions& options;
  CrfFitResult& result;
  const Curve ggcm_curve, emor_curve;
  const int lm_iterations;
  double residual_variance = 0;  // of the prior-free EMoR fit, when the ratio prior is on (setRatioPrior)

  MomentFitter(const MomentProblem& p, const CrfFitOptions& o, CrfFitResult& r)
      : problem(p), options(o), result(r), ggcm_curve(Curve::kGgcm, p.moments.levels, o.ggcm_degree),
        emor_curve(Curve::kEmor, p.moments.levels, o.emor_terms),
        lm_iterations(std::max(20, o.max_evaluations / 10)) {}

  // The start's parameters when it is a fit of this curve's kind and size and `model` names that kind
  // (CrfFitOptions::start), else empty.
  std::vector<double> startParameters(const Curve& curve) const {
    const CrfModelChoice kind = curve.kind() == Curve::kGgcm ? CrfModelChoice::ggcm : CrfModelChoice::emor;
    if (!options.start || options.model != kind) return {};
    std::vector<double> x;
    if (const auto* g = std::get_if<GgcmModel>(&options.start->model); g && curve.kind() == Curve::kGgcm) x = g->alpha;
    if (const auto* e = std::get_if<EmorModel>(&options.start->model); e && curve.kind() == Curve::kEmor)
      x = e->coefficients;
    return static_cast<int>(x.size()) == curve.dims() ? x : std::vector<double>{};
  }

  ModelFit fitWithPriors(const Curve& curve, const MomentSystem& sys, std::vector<std::vector<double>> starts,
                         double r0) const {
    return fitModelMomentsWithPrior(curve, sys, std::move(starts), r0, options.fit_ratio, lm_iterations,
                                    options.prior_energy_factor);
  }

  // EMoR from its linear least-squares start (or CrfFitOptions::start). With the ratio prior: first what the images alone say, then the
  // same fit with the prior (every later fit, the cross-validation's too, carries it).
  ModelFit fitEmor(MomentSystem& full) {
    std::vector<std::vector<double>> starts;  // empty: the linear least-squares starts
    double r0 = options.nominal_ratio;
    if (std::vector<double> x = startParameters(emor_curve); !x.empty()) {
      starts.push_back(std::move(x));
      r0 = options.start->ratio;
    }
    ModelFit fit_e = fitWithPriors(emor_curve, full, starts, r0);
    result.evaluations += fit_e.evaluations;
    result.iterations += fit_e.iterations;
    const bool ratio_prior = options.fit_ratio && options.ratio_prior_sigma > 0;
    if (ratio_prior && fit_e.valid && std::isfinite(fit_e.energy)) {
      result.ratio_images_only = fit_e.ratio;
      const double bins = static_cast<double>(full.h.rows());
      residual_variance = fit_e.energy * bins / std::max(1.0, bins - emor_curve.dims() - 1);
      setRatioPrior(full, residual_variance, options);
      result.ratio_prior_scale = full.ratio_prior_scale;
      const ModelFit with_prior = fitWithPriors(emor_curve, full, starts, r0);
      result.evaluations += with_prior.evaluations;
      result.iterations += with_prior.iterations;
      if (with_prior.valid) fit_e = with_prior;
    }
    return fit_e;
  }

  // The GGCM fit of the EMoR curve: a start near the data's curve.
  void addEmorProjection(const ModelFit& fit_e, std::vector<std::vector<double>>& starts) const {
    if (!fit_e.valid) return;
    ggcm::FitOptions go;
    go.degree = options.ggcm_degree;
    const auto projected = ggcm::fitInverse(sampleInverse(EmorModel{fit_e.x}, kGrid), go);
    if (projected.valid) starts.push_back(projected.model.alpha);
  }

  // GGCM from the EMoR projection and γ = 2.2, 1.6, 3.0, 1.0 (the first multi_starts of them).
  // With CrfFitOptions::start of GGCM: from it alone.
  ModelFit fitGgcm(const MomentSystem& full, const ModelFit& fit_e) {
    std::vector<std::vector<double>> starts;
    double r_start = fit_e.valid ? fit_e.ratio : options.nominal_ratio;
    if (std::vector<double> x = startParameters(ggcm_curve); !x.empty()) {
      starts.push_back(std::move(x));
      r_start = options.start->ratio;
    } else {
      addEmorProjection(fit_e, starts);
      for (double gamma : {2.2, 1.6, 3.0, 1.0}) starts.push_back(ggcm::fromGamma(gamma, options.ggcm_degree).alpha);
      if (static_cast<int>(starts.size()) > options.multi_starts) starts.resize(options.multi_starts);
    }
    const ModelFit fit_g =
        options.experimental.optimizer == CrfOptimizer::nelder_mead
            ? fitGgcmNelderMead(ggcm_curve, full, starts, options.nominal_ratio, options.fit_ratio,
                                options.max_evaluations)
            : fitWithPriors(ggcm_curve, full, starts, r_start);
    result.evaluations += fit_g.evaluations;
    result.iterations += fit_g.iterations;
    return fit_g;
  }

  // Ablation (CrfFitOptions::Experimental::variance_correction): both fits refined on the CUE residuals.
  void refineCue(const MomentSystem& full, const NoiseOperators& noise, double ratio, bool want_emor, bool want_ggcm,
                 ModelFit& fit_e, ModelFit& fit_g) {
    CueModel cue;
    if (const NoiseDebias* t = noise.transition()) cue.t = &t->transition();
    if (noise.debias_active) cue.r = &noise.debias.matrix();
    if (want_emor) {
      const ModelFit e = fitModelCue(emor_curve, full, cue, {fit_e.x, std::vector<double>(emor_curve.dims(), 0.0)},
                                     fit_e.x.empty() ? ratio : fit_e.ratio, options.fit_ratio, lm_iterations);
      if (e.valid) fit_e = e;
      result.evaluations += e.evaluations;
    }
    if (want_ggcm) {
      std::vector<std::vector<double>> starts{fit_g.x};
      addEmorProjection(fit_e, starts);
      const ModelFit g = fitModelCue(ggcm_curve, full, cue, starts, fit_g.x.empty() ? ratio : fit_g.ratio,
                                     options.fit_ratio, lm_iterations);
      if (g.valid) fit_g = g;
      result.evaluations += g.evaluations;
    }
  }

  // One fold of the 2-fold cross-validation: fit on checkerboard half `fold` (from the whole-data fit), the
  // energy (times its weight) on the other half. `stop`: the criterion is `energy` whatever the other fold gives
  // (NaN: a half without rows; ∞: the fit failed).
  struct FoldEnergy {
    double energy = 0;
    bool stop = false;
  };
  FoldEnergy foldEnergy(const Curve& curve, const ModelFit& whole, int fold) const {
    MomentSystem train = problem.system(fold);
    setExtrapolationPrior(train, options, problem.covered_levels);
    setRatioPrior(train, residual_variance, options);
    const MomentSystem test = problem.system(1 - fold);
    if (train.h.rows() == 0 || test.h.rows() == 0) return {std::numeric_limits<double>::quiet_NaN(), true};
    const ModelFit f = fitWithPriors(curve, train, {whole.x}, whole.ratio);
    if (f.x.empty()) return {kInf, true};
    std::vector<double> fv;
    if (!curve.values(f.x.data(), fv, nullptr)) return {kInf, true};
    return {momentEnergy(test, fv, f.ratio) * test.weight, false};
  }

  // 2-fold cross-validated energies of the given fits (NaN where not asked: an empty curve pointer). The fold fits
  // are independent: all of them at once, one per core (serial inside a job that already runs in parallel); each
  // sum is formed in fold order, as the serial loop did, so the criterion is the same to the bit.
  std::vector<double> crossValidate(const std::vector<std::pair<const Curve*, const ModelFit*>>& fits) const {
    const int n = static_cast<int>(fits.size());
    std::vector<FoldEnergy> fold_energy(2 * n);
    const std::vector<std::exception_ptr> errors = detail::runInParallel(2 * n, [&](int job) {
      const auto& [curve, whole] = fits[static_cast<std::size_t>(job / 2)];
      if (curve) fold_energy[job] = foldEnergy(*curve, *whole, job % 2);
    });
    for (const std::exception_ptr& error : errors)
      if (error) std::rethrow_exception(error);
    std::vector<double> criterion(n, std::numeric_limits<double>::quiet_NaN());
    for (int i = 0; i < n; ++i) {
      if (!fits[i].first) continue;
      double total = 0;
      for (int fold = 0; fold < 2; ++fold) {
        const FoldEnergy& e = fold_energy[2 * i + fold];
        if (e.stop) {  // as the serial loop, which returned at the first failed fold
          total = e.energy;
          break;
        }
        total += e.energy;
      }
      criterion[i] = total;
    }
    return criterion;
  }
};

}  // namespace

std::vector<CrfCandidate> seedCandidates(const Prepared& prep, const NoiseOperators& noise,
                                         const CrfFitOptions& options, CrfFitResult& result, const ProgressFn& report) {
  const auto t_mix = std::chrono::steady_clock::now();
  const LevelMixture mixture = LevelMixture::build(prep.sharp, prep.kernel, prep.pixels);
  result.mixture_nonzeros = mixture.nonZeros();
  result.timings.mixture_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_mix).count();
  SeedObjective objective(prep, mixture, noise.debias_active ? &noise.debias : nullptr, options.nominal_ratio);
  const Curve ggcm_curve(Curve::kGgcm, prep.levels, options.ggcm_degree);
  const Curve emor_curve(Curve::kEmor, prep.levels, options.emor_terms);
  std::vector<CrfCandidate> candidates;
  for (const Curve* curve : {&ggcm_curve, &emor_curve}) {
    if (curve == &ggcm_curve && options.model == CrfModelChoice::emor) continue;
    if (curve == &emor_curve && options.model == CrfModelChoice::ggcm) continue;
    objective.curve = curve;
    objective.ratio = options.nominal_ratio;
    std::vector<double> x = curve == &ggcm_curve ? ggcm::fromGamma(2.2, options.ggcm_degree).alpha
                                                 : std::vector<double>(curve->dims(), 0.0);
    const SeedFit fit = alternateRatio(objective, std::move(x), options,
                                       [&](double fraction) { report(0.1 + 0.8 * fraction, "optimise"); });
    result.iterations += fit.rounds;
    CrfCandidate c;
    c.kind = curve->name();
    c.model = curve->model(fit.x);
    c.valid = isValid(c.model);
    c.ratio = objective.ratio;
    c.energy = objective.energy(fit.x);
    c.criterion = c.energy;
    c.evaluations = fit.evaluations;
    result.evaluations += fit.evaluations;
    candidates.push_back(c);
  }
  return candidates;
}

std::vector<CrfCandidate> momentCandidates(const MomentProblem& problem, const NoiseOperators& noise,
                                           const CrfFitOptions& options, CrfFitResult& result,
                                           const ProgressFn& report, MomentSystem& full) {
  const bool want_ggcm = options.model != CrfModelChoice::emor;
  const bool want_emor = options.model != CrfModelChoice::ggcm;
  MomentFitter fitter(problem, options, result);
  full = problem.system(-1);
  setExtrapolationPrior(full, options, problem.covered_levels);
  // EMoR is fitted even for GGCM alone (its projection is GGCM's first start; with the ratio prior, its residual
  // variance scales the prior), unless GGCM has a start of its own and no ratio prior is asked for
  const bool ratio_prior = options.fit_ratio && options.ratio_prior_sigma > 0;
  const bool ggcm_started = want_ggcm && !ratio_prior && !fitter.startParameters(fitter.ggcm_curve).empty();
  ModelFit fit_e = want_emor || !ggcm_started ? fitter.fitEmor(full) : ModelFit{};
  ModelFit fit_g;
  if (want_ggcm) fit_g = fitter.fitGgcm(full, fit_e);
  // r of the better valid fit: the start of the CUE refinement
  double ratio = options.nominal_ratio;
  const bool use_g = want_ggcm && fit_g.valid && (!fit_e.valid || fit_g.energy <= fit_e.energy || !want_emor);
  if (use_g) ratio = fit_g.ratio;
  else if (fit_e.valid) ratio = fit_e.ratio;
  report(0.5, "optimise");
  const bool corrected = options.experimental.variance_correction;
  if (corrected) fitter.refineCue(full, noise, ratio, want_emor, want_ggcm, fit_e, fit_g);
  // energies are per unit weight: (cost · weight) / weight — LM cost is already normalised
  const bool cross_validate = options.model == CrfModelChoice::automatic && !corrected;
  const bool has_e = want_emor && !fit_e.x.empty(), has_g = want_ggcm && !fit_g.x.empty();
  const bool cv_e = cross_validate && has_e && fit_e.valid, cv_g = cross_validate && has_g && fit_g.valid;
  const std::vector<double> cv = fitter.crossValidate({{cv_e ? &fitter.emor_curve : nullptr, &fit_e},
                                                       {cv_g ? &fitter.ggcm_curve : nullptr, &fit_g}});
  std::vector<CrfCandidate> candidates;
  if (has_e) candidates.push_back(makeCandidate(fitter.emor_curve, fit_e, cv_e ? cv[0] : fit_e.energy));
  if (has_g) candidates.push_back(makeCandidate(fitter.ggcm_curve, fit_g, cv_g ? cv[1] : fit_g.energy));
  return candidates;
}

bool chooseCandidate(std::vector<CrfCandidate>& candidates, const CrfFitOptions& options, CrfFitResult& result) {
  // valid first, then the lower criterion
  const CrfCandidate* best = nullptr;
  for (const auto& c : candidates) {
    if (!c.valid) continue;
    if (!best || (std::isfinite(c.criterion) && !(c.criterion >= best->criterion))) best = &c;
  }
  for (auto& c : candidates) c.inverse_crf = sampleValidTable(c.model);
  if (!best) {
    // never return an invalid curve: fall back to the γ = 2.2 start
    result.model = ggcm::fromGamma(2.2, options.ggcm_degree);
    result.ratio = options.nominal_ratio;
    result.energy = std::numeric_limits<double>::quiet_NaN();
    result.chosen = "fallback";
    result.choice_reason = "no candidate was a valid (monotone) curve; returned the gamma 2.2 start";
    return false;
  }
  result.model = best->model;
  result.ratio = best->ratio;
  result.energy = best->energy;
  result.chosen = best->kind;
  const bool seed_objective = options.experimental.objective == CrfObjective::seed_intensity;
  if (candidates.size() == 1) result.choice_reason = std::string("only ") + best->kind + " was fitted";
  else if (options.model == CrfModelChoice::automatic && !seed_objective)
    result.choice_reason = options.experimental.variance_correction
                               ? "lower CUE moment energy (chi-square per bin; equal parameter counts)"
                               : "lower 2-fold cross-validated moment energy";
  else result.choice_reason = "lower energy";
  return true;
}

// Along the exponential ambiguity (φ^γ, r^γ) the energy is flat to first order for a plain two-exposure pair;
// only the blur inconsistency raises it.
double ambiguityRise(const MomentSystem& full, const std::vector<double>& inverse_crf, double ratio) {
  const int L = full.levels();
  const std::vector<double> f = onLevelGrid(inverse_crf, L);
  const double e0 = momentEnergy(full, f, ratio);
  double rise = kInf;
  for (double gamma : {0.9, 1.1}) {
    std::vector<double> fg(L);
    for (int v = 0; v < L; ++v) fg[v] = std::pow(std::max(f[v], 0.0), gamma);
    rise = std::min(rise, momentEnergy(full, fg, std::pow(ratio, gamma)) / e0 - 1);
  }
  return rise;
}

}  // namespace crfcal::crf_fit
