// exposure_ratio_mismatch: the exposure ratio a free vs fixed to r_EXIF, each model with its own φ (the fitter with
// r fixed), within the selected model. Detected only when, in addition to the held-out test, |a / r_EXIF − 1|
// exceeds ratio_tolerance: nominal EXIF times, ISOs and f-numbers are rounded to 1/3 stop (up to ≈ 6 % each).
// Attribution (issue 18): EXIF r of a real camera is good to a few per cent, so a free r is the explanation of last
// resort. Each level effect is also added to the model with r at EXIF's value (its own φ); when one of them
// explains the held-back pixels about as well as the free r (the free r's held-out drop against it is not
// significant, z < min_z) and passes its own test against the fixed-r model, that effect is named instead (an offset
// in one shot bends φ and moves a free r; with the offset modelled, EXIF's r fits). Otherwise the mismatch is named
// with that best alternative as its runner-up. Within EXIF's tolerance nothing can be named, so the fixed-r fit
// (the costly part: one fit per channel) is skipped and the test is made around the current φ.
#include <cmath>

#include "crfcal/error.hpp"
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

// The seed's model with r = r_EXIF gets its own best φ (the fitter with r fixed) before the local re-fit: a φ
// fitted with a free r sits in a different valley (φ^γ trades with r^γ) that the local re-fit cannot leave, so
// "r fixed" would be judged around the wrong φ. Falls back to the current φ when that fit fails.
Problem fixedRatioProblem(const EffectSearch& search) {
  const EffectInputs& in = search.in;
  const int nc = search.nc;
  const Spec& current = search.current;
  try {
    std::vector<Curve> fixed_curves = search.curves;
    const bool corrected = current.vignetting || current.offset || current.mixing || current.clipping;
    const auto fixed_fits =
        corrected ? refitPair(search, current, search.curves, search.coef, search.current_eval.full, false, false,
                              in.nominal_ratio)
                        .fits
                  : std::map<std::string, CrfFitResult>{};
    for (int c = 0; c < nc; ++c) {
      if (corrected) {
        if (fixed_fits.empty()) throw InvalidInput("fixed-ratio refit failed");
        fixed_curves[c] = makeCurve(fixed_fits.at(in.channels[c]).inverse_crf);
        continue;
      }
      CrfFitOptions fo = in.fit;
      fo.progress = nullptr;
      fo.fit_ratio = false;
      fo.nominal_ratio = in.nominal_ratio;
      const cv::Mat& I = in.sharp.at(in.channels[c]);
      const cv::Mat& B = in.blurred.at(in.channels[c]);
      fixed_curves[c] = makeCurve(fitInverseCrf(I, B, search.K, fo).inverse_crf);
    }
    return search.problemAround(fixed_curves, std::vector<double>(nc, in.nominal_ratio));
  } catch (const InvalidInput&) {
    return search.problem;
  }
}

// The best level effect with r at EXIF's value (smallest held-out error) against the free r: whether it explains
// the misfit instead (then its name goes to search.ratio_explained_by), and the evidence either way.
void attribute(EffectSearch& search, const Problem& fixed_problem, const Spec& fixed, const Evaluation& fe,
               EffectEntry& e) {
  const std::vector<Candidate> alternatives = levelCandidates(search, fixed_problem, fixed, fe);
  const Candidate* best = nullptr;
  for (const Candidate& c : alternatives)
    if (c.plausible && (!best || c.eval.total < best->eval.total)) best = &c;
  if (!best) return;
  const Comparison h = headToHead(search, best->eval, search.current_eval);
  if (best->passes && h.z < search.options.min_z) {
    e.detected = false;
    e.explained_by = best->name;
    e.detail += "; not named: " + best->name +
                fmt(" with r at EXIF explains the held-back pixels as well (free r's drop against it %.4f, z %.2f)",
                    h.gain, h.z);
    search.ratio_explained_by = best->name;
    EffectEntry& named = search.entry(best->name);
    named.tested = true;
    named.gain = best->cmp.gain;  // its own test, with r at EXIF's value
    named.statistic = best->cmp.z;
    named.runner_up = "exposure_ratio_mismatch";
    named.runner_up_gain = e.gain;
    named.evidence_gain = -h.gain;
    named.evidence_z = -h.z;
    return;
  }
  e.runner_up = best->name;
  e.runner_up_gain = best->cmp.gain;
  e.evidence_gain = h.gain;
  e.evidence_z = h.z;
}

void run(EffectSearch& search) {
  const EffectInputs& in = search.in;
  const EffectOptions& options = search.options;
  auto& e = search.entry("exposure_ratio_mismatch");
  if (!(in.nominal_ratio > 0)) {
    e.detail = "no EXIF ratio";
    return;
  }
  const double a = search.coef[search.g_index].scale;
  const double rel = a / in.nominal_ratio - 1;
  // A free a outside the fitter's range is a runaway of the linearised search, not a ratio (vivo X6S pair 3: EXIF r
  // 6.25, the images' own r 1.96, a = 0.0027). Tried first and dropped: the shots' brightness ratio as a bound (the
  // verdict's interval of r excluded the planted r in 10 of 20 detector-form pairs; even the side of 1 it implies
  // was wrong in 6 of 20 — blur moves the quantiles; docs/RESULTS.md#effects-runaway-ratio).
  const bool possible_ratio = fittableExposureRatio(a);
  // The pipeline held r at EXIF because the blur cannot fix it (pair_stage_rounds.cpp): the free r here meets the
  // same ambiguity, and naming it a mismatch would contradict the reported r (vivo X6S pair 1, a 0.84 px blur: EXIF
  // 3.125, the shots' brightness 3.7, the free r 1.85 named a 41 % mismatch).
  const bool undecidable = in.ratio_held_for_small_blur;
  const bool beyond_tolerance = possible_ratio && !undecidable && std::abs(rel) > options.ratio_tolerance;
  Spec fixed = search.current;
  fixed.fixed_scale = true;
  fixed.scale = in.nominal_ratio;
  const Problem fixed_problem = beyond_tolerance ? fixedRatioProblem(search) : Problem{};
  const Problem& around = beyond_tolerance ? fixed_problem : search.problem;
  const Evaluation fe = around.evaluate(fixed);
  Comparison cmp = scoreTest(search.problem.samples(), fe, search.current_eval, search.used_fine, search.blocks);
  cmp.gain = fe.total > 0 ? cmp.gain / fe.total : 0;
  e.tested = true;
  e.gain = cmp.gain;
  e.statistic = cmp.z;
  e.detected = beyond_tolerance && cmp.gain >= options.min_gain && cmp.z >= options.min_z;
  e.parameters = {{"fitted_ratio", a}, {"nominal_ratio", in.nominal_ratio}, {"relative_difference", rel},
                  {"tolerance", options.ratio_tolerance}};
  e.detail = fmt("fitted r %.4f vs nominal %.4f (%+.1f%%; tolerance of nominal EXIF values ", a, in.nominal_ratio,
                 100 * rel) +
             fmt("%.0f%%); ", 100 * options.ratio_tolerance) +
             (beyond_tolerance ? "phi from the free-r fit"
              : undecidable     ? "not named: the blur is too small to tell r from phi's exponent (r held at EXIF); "
                                  "r = EXIF tested around the current phi"
              : possible_ratio  ? "within tolerance: r = EXIF tested around the current phi"
                                : fmt("not a ratio: outside the %g-%g the fitter considers (a runaway of the "
                                      "linearised search), not named; r = EXIF tested around the current phi",
                                      kMinExposureRatio, kMaxExposureRatio));
  // Attribution: a blur that varies across the frame (checked before this, effect_search.cpp) leaves a single kernel's
  // misfit that a free r partly absorbs, so the free r is then no evidence against EXIF, whose r is good to a few per
  // cent (measured: held-out planted varying blurs at r ≈ 6 named beside a false mismatch in 3 of 6 pairs).
  const EffectEntry& blur = search.entry("spatially_varying_blur");
  if (e.detected && blur.detected) {
    e.detected = false;
    e.explained_by = blur.name;
    e.detail += "; not named: the spatially varying blur found explains a single kernel's misfit, which a free r "
                "absorbs";
    return;
  }
  if (!e.detected) return;
  attribute(search, around, fixed, fe, e);
  // A free a whose model flattens φ's re-fit over the data where φ̂ is not (flattenedChannel: the floored residuals
  // shrink with such a φ) is no evidence about r (vivo X6S pairs 2 and 3: a 68–71 % "mismatch" at z 6–13, the shots'
  // brightness siding with EXIF). A level effect with r at EXIF's value that explains the misfit as well as that free
  // a (attribute, above) is still named: against the flattened model's lowered error, the comparison is conservative.
  const std::string flattened = flattenedChannel(search, search.problem, search.current, search.current_eval);
  if (e.detected && !flattened.empty()) {
    e.detected = false;
    e.detail += "; not named: the free-r model's phi re-fit is nearly constant over the data in " + flattened +
                ", where phi is not (the verdict's flat rule)";
  }
}

}  // namespace

const ModelCheck& exposureRatioMismatchCheck() {
  static const ModelCheck check{"exposure_ratio_mismatch", run};
  return check;
}

}  // namespace crfcal::effect
