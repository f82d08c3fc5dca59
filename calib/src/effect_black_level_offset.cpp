// black_level_offset: Ŷ = a X + c, a flare or black-level offset in one shot (an offset d in I is c = −a d),
// fitted jointly with φ (the base fit absorbs an offset into φ by bending it ≈ c / (r − 1)).
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

Spec extend(Spec spec) {
  spec.offset = true;
  return spec;
}

bool in(const Spec& spec) { return spec.offset; }

const char* applicable(const EffectSearch&) { return nullptr; }

void describe(const EffectSearch& search, const Spec& spec, const Evaluation& ev, EffectEntry& e) {
  const int gi = search.g_index;
  const Coefficients c = ev.full[gi].ok ? coefficients(spec, ev.full[gi], gi, search.nc, search.terms) : Coefficients{};
  e.parameters["offset"] = c.offset;
  e.parameters["scale"] = c.scale;
  e.detail = fmt("additive irradiance offset %.4f of full scale ", c.offset) +
             (c.offset >= 0 ? "(B brighter: flare/offset in B, or a negative offset in I)"
                            : "(I brighter: offset in I, or a negative offset in B)");
}

// B' = ψ(φ(B) − c).
void correct(PairCorrection& pair) {
  for (int c = 0; c < pair.search.nc; ++c) pair.Y[c] = pair.Y[c] - pair.coefficients[c].offset;
}

}  // namespace

const LevelEffect& blackLevelOffsetEffect() {
  static const LevelEffect effect{"black_level_offset", extend, in, applicable, globalHeldoutTest, false, describe,
                                  correct};
  return effect;
}

}  // namespace crfcal::effect
