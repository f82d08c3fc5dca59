// The tests of a held-out drop (effect_problem.hpp): does an extended model lower the held-back error by more than
// noise alone would? Per block (compare), per affected sample with the residuals' design effect (scoreTest), and the
// whole-pair form the effect search uses (globalHeldoutTest).
#include <algorithm>
#include <cmath>
#include <vector>

#include "effect_problem.hpp"

namespace crfcal::effect {

Comparison compare(const std::vector<double>& base, const std::vector<double>& ext, double base_total,
                   const std::vector<char>& used) {
  std::vector<double> d;
  double sum = 0;
  for (std::size_t b = 0; b < base.size(); ++b)
    if (used[b]) {
      d.push_back(base[b] - ext[b]);
      sum += d.back();
    }
  Comparison c;
  if (d.size() < 4 || !(base_total > 0)) return c;
  const double n = static_cast<double>(d.size()), mean = sum / n;
  double var = 0;
  for (double v : d) var += (v - mean) * (v - mean);
  var /= (n - 1);
  c.gain = sum / base_total;
  const double t = var > 0 ? mean / std::sqrt(var / n) : (mean > 0 ? 1e9 : 0);
  // Student's t with n − 1 degrees of freedom as the normal deviate of the same tail probability (Wallace's
  // approximation z = t (1 − 1/(4ν)) / sqrt(1 + t²/(2ν))): few blocks need a larger t.
  const double nu = n - 1;
  c.z = t * (1 - 1 / (4 * nu)) / std::sqrt(1 + t * t / (2 * nu));
  return c;
}

// The held-out drop Σ d_i over the affected samples against what noise alone would give for the same change of
// prediction δ_i = e_base,i − e_ext,i: under "no effect" Var(Σ d_i) ≈ 4 σ² A Σ δ_i², σ² the base model's held-out
// residual variance and A the residuals' design effect (variance inflation of block sums:
// A = Σ_b (Σ_{i∈b} e_i)² / Σ e_i², 1 for independent residuals). z = Σ d / (2 σ sqrt(A Σ δ²)).
Comparison scoreTest(const std::vector<Samples>& samples, const Evaluation& base, const Evaluation& ext,
                     const std::vector<char>& affected, int blocks) {
  Comparison c;
  double e2 = 0, sum_d = 0, sum_delta2 = 0;
  long n = 0;
  std::vector<double> block_sum(blocks, 0.0);
  for (std::size_t ch = 0; ch < samples.size(); ++ch) {
    const Samples& s = samples[ch];
    for (std::size_t i = 0; i < s.size(); ++i) {
      const double eb = base.residual[ch][i], ee = ext.residual[ch][i];
      e2 += eb * eb;
      ++n;
      block_sum[s.block[i]] += eb;
      if (!affected[s.fine[i]]) continue;
      sum_d += eb * eb - ee * ee;
      sum_delta2 += (eb - ee) * (eb - ee);
    }
  }
  if (n == 0 || !(e2 > 0) || !(sum_delta2 > 0)) return c;
  double A = 0;
  for (double v : block_sum) A += v * v;
  A = std::max(1.0, A / e2);
  const double sigma2 = e2 / n;
  c.gain = sum_d;
  c.z = sum_d / (2 * std::sqrt(sigma2 * A * sum_delta2));
  return c;
}

Comparison globalHeldoutTest(const EffectSearch& search, const Evaluation& without, const Evaluation& with) {
  Comparison cmp = scoreTest(search.problem.samples(), without, with, search.used_fine, search.blocks);
  cmp.gain = without.total > 0 ? cmp.gain / without.total : 0;
  return cmp;
}

}  // namespace crfcal::effect
