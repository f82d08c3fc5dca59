// One NoiseDebias per noise law, shared by the fits that need it.
//
// A calibration fits φ many times on the same sharp image (kernel↔φ rounds, the ratio stage, the band's and the
// ratio evidence's half-sample refits, the effect search's refits): every fit estimates the same σ of I and built
// the same L×L operator again (a Tikhonov solve; 6–7 % of a 0.1 MP pair's CPU, measured with perf on the vivo X6S
// pair 1). The operator is a pure function of its options, so it is built once per distinct options and reused.
#pragma once

#include "crfcal/noise_debias.hpp"

namespace crfcal::detail {

// The operator for these options: built on first use, then a copy of the stored one (bit-identical to
// NoiseDebias(options)). Thread-safe; keeps the few most recent noise laws.
NoiseDebias cachedNoiseDebias(const NoiseDebiasOptions& options);

}  // namespace crfcal::detail
