// vignetting: Ŷ = a X (1 + v₁ρ² + v₂ρ⁴), ρ the distance to the optical centre over the normalising radius (the two
// shots can differ in aperture, so their falloffs differ by a smooth radial gain).
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

Spec extend(Spec spec) {
  spec.vignetting = true;
  return spec;
}

bool in(const Spec& spec) { return spec.vignetting; }

const char* applicable(const EffectSearch&) { return nullptr; }

void describe(const EffectSearch& search, const Spec& spec, const Evaluation& ev, EffectEntry& e) {
  const int gi = search.g_index;
  const Coefficients v = ev.full[gi].ok ? coefficients(spec, ev.full[gi], gi, search.nc, search.terms) : Coefficients{};
  e.parameters["v1"] = v.v1;
  e.parameters["v2"] = v.v2;
  e.parameters["corner_gain"] = 1 + v.v1 + v.v2;
  const double corner = 1 + v.v1 + v.v2;
  e.detail = fmt("gain of B relative to I at the corner %.3f (1 + v1 rho^2 + v2 rho^4, v1 %.3f, v2 %.3f)", corner,
                 v.v1, v.v2);
  if (!physicalCornerGain(corner)) e.detail += "; outside 0.1-10: not physical (a runaway of the linearised fit)";
}

// B' = ψ(φ(B) / g(ρ)), the gain floored at 0.05.
void correct(PairCorrection& pair) {
  const cv::Mat& rho2 = pair.search.p.rho2;
  for (int c = 0; c < pair.search.nc; ++c) {
    const Coefficients& cf = pair.coefficients[c];
    cv::Mat g = 1.0 + cf.v1 * rho2 + cf.v2 * rho2.mul(rho2);
    g = cv::max(g, 0.05);
    cv::divide(pair.Y[c], g, pair.Y[c]);
  }
}

}  // namespace

const LevelEffect& vignettingEffect() {
  static const LevelEffect effect{"vignetting", extend, in, applicable, globalHeldoutTest, false, describe, correct};
  return effect;
}

}  // namespace crfcal::effect
