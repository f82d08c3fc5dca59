#pragma once
// A pointwise band of φ for the static references (issue 19's band, asked for by issue 21: "report covered range
// and band here too"): the curves of `crfcal bracket` (and any fit of chart_calibration.hpp's y = s·φ(x) form).
//
// Resampling unit. The observations of one scene point (bracket) share its unknown irradiance s_p and its local
// texture, so they are not independent: the band resamples CLUSTERS (scene points), never single observations.
// Each refit sees a random half of the clusters, in complementary pairs (every cluster in exactly one half of a
// pair), with K and the exposures of the full fit held fixed. For a half-sample Var(φ_half − φ_full) ≈ Var(φ_full),
// so the refits' deviations from the full fit, each after its best common scale over the covered range, estimate the
// full fit's pointwise sampling variance (curve_band.hpp's bandFromReplicates, the same estimator as the pair's
// block bootstrap). Resampling cannot see systematic errors, so model terms are added: the choice of K, and what the
// caller knows of its own (the bracket: the texture inside its points' windows, bracket_calibration.cpp). Still not
// in the shape band: errors of the exposures themselves (EXIF times off by a few per cent), and a colour rendering no
// per-channel curve describes.
//
// Above and below the covered range the band is curve_band.hpp's bound on the local exponent (a bracket's φ(1) = 1
// is reached by extrapolation from its top sample just as a pair's is).
// Pure computation: no file I/O, no printing.
#include <cstdint>
#include <span>
#include <vector>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/curve_band.hpp"

namespace crfcal {

// Random halves of `clusters` cluster ids, `count` of them (even) in complementary pairs: half[k][c] is true when
// cluster c is in the k-th half. Deterministic for a seed. None for fewer than 4 clusters or count < 2.
std::vector<std::vector<bool>> clusterHalves(int clusters, int count, std::uint64_t seed);

// The band of `fit` (a fitScaledInverse result on `observations`): refits with fitScaledInverseFixed(K = fit.terms,
// `fit_options`) on options.replicates cluster halves — cluster[i] is observation i's resampling unit (0 …) —, their
// groups renumbered within each half; then bandFromReplicates over fit.covered_range with model terms (when
// options.include_model_spread): the fits with K − 1 and K + 1 terms on all observations (the cross-validated K is
// itself an estimate) and the caller's `alternatives` (other fits of the same data, kCurveSamples samples, e.g. the
// bracket's fit on its flatter points). Halves that cannot be fitted (too few observations) count in
// failed_replicates. Throws InvalidInput for a cluster list of another length than the observations or a fit without
// a curve. The refits run in parallel.
CurveBand scaledFitBand(std::span<const ScaledObservation> observations, const std::vector<int>& cluster,
                        const ScaledFitOptions& fit_options, const ScaledFitResult& fit,
                        const CurveBandOptions& options = {}, std::vector<std::vector<double>> alternatives = {});

}  // namespace crfcal
