// exposure_ratio_mismatch: the exposure ratio a free vs fixed to r_EXIF, each model with its own φ (the fitter with
// r fixed), within the selected model. Detected only when, in addition to the held-out test, |a / r_EXIF − 1|
// exceeds ratio_tolerance: nominal EXIF times, ISOs and f-numbers are rounded to 1/3 stop (up to ≈ 6 % each).
#include <cmath>

#include "crfcal/error.hpp"
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

// The seed's model with r = r_EXIF gets its own best φ (the fitter with r fixed) before the local re-fit: a φ
// fitted with a free r sits in a different valley (φ^γ trades with r^γ) that the local re-fit cannot leave, so
// "r fixed" would be judged around the wrong φ. Falls back to the current φ when that fit fails.
Evaluation fixedRatioEvaluation(const EffectSearch& search, const Spec& fixed) {
  const EffectInputs& in = search.in;
  const int nc = search.nc;
  const Spec& current = search.current;
  try {
    std::vector<Curve> fixed_curves = search.curves;
    const bool corrected = current.vignetting || current.offset || current.mixing || current.clipping;
    const auto fixed_fits =
        corrected ? refitPair(search, current, search.curves, search.coef, search.current_eval.full, false, false,
                              in.nominal_ratio)
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
    const Problem fixed_problem = search.problemAround(fixed_curves, std::vector<double>(nc, in.nominal_ratio));
    return fixed_problem.evaluate(fixed);
  } catch (const InvalidInput&) {
    return search.problem.evaluate(fixed);
  }
}

void run(EffectSearch& search) {
  const EffectInputs& in = search.in;
  const EffectOptions& options = search.options;
  auto& e = search.entry("exposure_ratio_mismatch");
  if (!(in.nominal_ratio > 0)) {
    e.detail = "no EXIF ratio";
    return;
  }
  Spec fixed = search.current;
  fixed.fixed_scale = true;
  fixed.scale = in.nominal_ratio;
  const Evaluation fe = fixedRatioEvaluation(search, fixed);
  Comparison cmp = scoreTest(search.problem.samples(), fe, search.current_eval, search.used_fine, search.blocks);
  cmp.gain = fe.total > 0 ? cmp.gain / fe.total : 0;
  const double a = search.coef[search.g_index].scale;
  const double rel = a / in.nominal_ratio - 1;
  e.tested = true;
  e.gain = cmp.gain;
  e.statistic = cmp.z;
  // a non-positive or non-finite scale is a runaway fit, not a ratio (see physical())
  e.detected = a > 0 && std::isfinite(a) && cmp.gain >= options.min_gain && cmp.z >= options.min_z &&
               std::abs(rel) > options.ratio_tolerance;
  e.parameters = {{"fitted_ratio", a}, {"nominal_ratio", in.nominal_ratio}, {"relative_difference", rel},
                  {"tolerance", options.ratio_tolerance}};
  e.detail = fmt("fitted r %.4f vs nominal %.4f (%+.1f%%; tolerance of nominal EXIF values ", a, in.nominal_ratio,
                 100 * rel) +
             fmt("%.0f%%); phi from the free-r fit", 100 * options.ratio_tolerance);
}

}  // namespace

const ModelCheck& exposureRatioMismatchCheck() {
  static const ModelCheck check{"exposure_ratio_mismatch", run};
  return check;
}

}  // namespace crfcal::effect
