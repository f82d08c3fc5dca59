// channel_mixing: Ŷ_c = Σ_d m_cd X_d, a 3×3 mix before the per-channel curves (rgb only); the row sum Σ_d m_cd is
// the exposure ratio; the channels' φ re-fits are coupled through X_d (Problem::fitAll).
#include <algorithm>
#include <cmath>

#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

Spec extend(Spec spec) {
  spec.mixing = true;
  return spec;
}

bool in(const Spec& spec) { return spec.mixing; }

const char* applicable(const EffectSearch& search) {
  return search.nc == 3 ? nullptr : "needs three channels (--channels rgb)";
}

void describe(const EffectSearch& search, const Spec& spec, const Evaluation& ev, EffectEntry& e) {
  const int nc = search.nc;
  double largest = 0;
  for (int c = 0; c < nc; ++c) {
    if (!ev.full[c].ok) continue;
    const Coefficients cc = coefficients(spec, ev.full[c], c, nc, search.terms);
    for (int d = 0; d < nc; ++d) {
      const double m = cc.mix[d] / cc.scale;
      e.parameters["m_" + search.in.channels[c] + search.in.channels[d]] = m;
      if (d != c) largest = std::max(largest, std::abs(m));
    }
  }
  e.detail = std::isfinite(largest)
                 ? fmt("largest off-diagonal mix %.3f (relative to the own channel)", largest)
                 : std::string("no mix measurable: a channel's own term fitted to 0 (not physical)");
}

// Channel c's row of the mix applied to I's irradiances, so that B_c = ψ_c(a_c K ⊗ φ_c(I'_c)) holds:
// I'_c = ψ_c(φ_c(I_c) + Σ_{d≠c} (m_cd / a_c) (φ_d(I_d) − φ_c(I_c))) — only the channel's own row is needed.
void correct(PairCorrection& pair) {
  const int nc = pair.search.nc;
  const Prepared& p = pair.search.p;
  const EffectInputs& in = pair.search.in;
  std::vector<cv::Mat> phiI(nc);
  for (int d = 0; d < nc; ++d) phiI[d] = pair.ext[d].curve.inverse(p.I[d]);
  for (int c = 0; c < nc; ++c) {
    const Coefficients& cf = pair.coefficients[c];
    cv::Mat e = phiI[c].clone();
    for (int d = 0; d < nc; ++d)
      if (d != c && cf.scale > 0) e += (cf.mix[d] / cf.scale) * (phiI[d] - phiI[c]);
    cv::Mat i = pair.ext[c].curve.forward(cv::max(cv::min(e, 1.0), 0.0));
    i.setTo(0, p.I[c] <= 0);  // no data stays no data
    pair.sharp[c] = store(i, in.sharp.at(in.channels[c]).depth());
  }
}

}  // namespace

const LevelEffect& channelMixingEffect() {
  static const LevelEffect effect{"channel_mixing", extend, in, applicable, globalHeldoutTest, false, describe,
                                  correct};
  return effect;
}

}  // namespace crfcal::effect
