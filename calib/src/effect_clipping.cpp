// clipping: Ŷ = min(a X, φ(b_c)), a plateau b_c of B below full scale (a sensor or processing clip); b_c on a grid of
// B's top quantiles, "none" included (Problem::fit). The plateau acts locally, so its test runs over the blocks
// that reach it.
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

Spec extend(Spec spec) {
  spec.clipping = true;
  return spec;
}

bool in(const Spec& spec) { return spec.clipping; }

const char* applicable(const EffectSearch&) { return nullptr; }

// A plateau acts only where B reaches it: the paired test (and the relative gain) runs over the half-size blocks
// that contain plateau samples — chosen from B alone, so the selection does not favour the extended model (a
// localised effect touches too few full blocks for a test over blocks).
Comparison plateauTest(const EffectSearch& search, const Evaluation& without, const Evaluation& with) {
  std::vector<char> plateau(search.fine_blocks, 0);
  for (const auto& smp : search.problem.samples()) {
    const int c = static_cast<int>(&smp - search.problem.samples().data());
    const double clip = with.full[c].ok ? with.full[c].clip : 2.0;
    for (std::size_t i = 0; i < smp.size(); ++i)
      if (smp.level[i] >= clip) plateau[smp.fine[i]] = 1;
  }
  double base_total = 0;
  for (int b = 0; b < search.fine_blocks; ++b)
    if (plateau[b]) base_total += without.fine_error[b];
  Comparison cmp = scoreTest(search.problem.samples(), without, with, plateau, search.blocks);
  cmp.gain = base_total > 0 ? cmp.gain / base_total : 0;
  return cmp;
}

void describe(const EffectSearch& search, const Spec&, const Evaluation& ev, EffectEntry& e) {
  const int gi = search.g_index;
  const double level = ev.full[gi].ok && ev.full[gi].clip > 0 && ev.full[gi].clip <= 1 ? ev.full[gi].clip : 1.0;
  const double irradiance = search.curves[gi].curve.inverse(level);
  e.parameters["clip_irradiance"] = irradiance;
  e.parameters["clip_intensity"] = level;
  e.parameters["full_scale_margin"] = search.full_scale_margin;  // B within it of full scale: saturated
  e.detail = fmt("plateau of B at intensity %.3f (irradiance %.3f): pixels there are censored", level, irradiance);
}

// The plateau is treated like saturation in the refit.
void correct(PairCorrection& pair) {
  const EffectInputs& in = pair.search.in;
  for (int c = 0; c < pair.search.nc; ++c) {
    const ChannelFit& ff = pair.fits[c];
    if (!(ff.ok && ff.clip > 0 && ff.clip <= 1)) continue;
    CrfFitOptions& fo = pair.fit_options[c];
    const double level = ff.clip - 0.5 / fullScale(in.blurred.at(in.channels[c]));
    fo.saturation_high = std::max(fo.saturation_low + 0.1, std::min(fo.saturation_high, level));
  }
}

}  // namespace

const LevelEffect& clippingEffect() {
  static const LevelEffect effect{"clipping", extend, in, applicable, plateauTest, true, describe, correct};
  return effect;
}

}  // namespace crfcal::effect
