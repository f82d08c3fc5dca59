#include "bench_pairs_summary.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>

namespace crfcal::app {

namespace {

double medianOf(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

std::string percent(int hits, int samples) {
  if (samples == 0) return "-";
  char buffer[32];
  std::snprintf(buffer, sizeof buffer, "%.1f %%", 100.0 * hits / samples);
  return buffer;
}

}  // namespace

std::string bandSummaryTable(const std::map<double, BandSummary>& by_ratio) {
  std::ostringstream out;
  out << "\nband of phi_G (90 %; curve_band.hpp): coverage = fraction of x samples (1024 per case, pooled) where the "
         "true phi lies inside the band. absolute: the truth as it is against [lower, upper] (phi(1) = 1; the band "
         "carries the scale's uncertainty); shape: inside the covered range, the truth times its best common scale "
         "a (least squares onto the fit over the covered range) against fit +- shape half-width (half-sample spread and the other candidate model, no scale part). "
         "Above covered, farther half: the samples of each case's [covered top, 1] nearer x = 1 (the nearer half "
         "has the rest). "
         "Widths: median over cases of each case's median over the covered range.\n"
      << "| r | cases | absolute inside covered | absolute above covered | above: nearer half | above: farther half | "
         "absolute below covered | shape inside covered | median width inside (absolute) | median width inside "
         "(shape) | median abs(a - 1) | band s / calibration s |\n"
      << "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& [ratio, b] : by_ratio) {
    if (b.cases == 0) continue;
    char line[600];
    std::snprintf(line, sizeof line, "| %.2f | %d | %s | %s | %s | %s | %s | %s | %.4f | %.4f | %.4f | %.0f / %.0f |\n",
                  ratio, b.cases, percent(b.pooled.inside_hits, b.pooled.inside).c_str(),
                  percent(b.pooled.above_hits, b.pooled.above).c_str(),
                  percent(b.pooled.above_hits - b.pooled.above_far_hits, b.pooled.above - b.pooled.above_far).c_str(),
                  percent(b.pooled.above_far_hits, b.pooled.above_far).c_str(),
                  percent(b.pooled.below_hits, b.pooled.below).c_str(),
                  percent(b.pooled.shape_hits, b.pooled.inside).c_str(), medianOf(b.widths), medianOf(b.shape_widths),
                  medianOf(b.scale_errors), b.band_seconds, b.seconds);
    out << line;
  }
  return out.str();
}

std::string ratioSummaryTable(const std::map<double, RatioSummary>& by_ratio) {
  std::ostringstream out;
  out << "\nper r (fitted r error = |r_fitted/r_true - 1|; shape RMSE = min_b RMS(b phi_fit - phi_true) over the "
         "covered range of G)\n"
      << "| r | regime | ISO sharp / blurred | cases | r error mean | r error worst | r within 5 % | phi_G RMSE "
         "mean (worst) | shape RMSE mean (worst) | shape <= 0.01 | kernel-size stops | other failures | time s |\n"
      << "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const auto& [ratio, s] : by_ratio) {
    const double n = std::max(s.done, 1);
    char line[512];
    std::snprintf(line, sizeof line,
                  "| %.2f | %s | %s | %d | %.4f | %.4f | %d/%d | %.4f (%.4f) | %.4f (%.4f) | %d/%d | %d | %d | %.0f |\n",
                  ratio, s.regime.c_str(),
                  s.iso_sharp > 0 ? (std::to_string(static_cast<int>(std::lround(s.iso_sharp))) + " / " +
                                     std::to_string(static_cast<int>(std::lround(s.iso_blurred)))).c_str()
                                  : "generic noise",
                  s.cases, s.sum_r_error / n, s.worst_r_error, s.within_5_percent, s.cases, s.sum_rmse / n,
                  s.worst_rmse, s.sum_shape / n, s.worst_shape, s.shape_within_001, s.cases, s.size_limit_stops,
                  s.other_failures, s.seconds);
    out << line;
  }
  return out.str();
}

}  // namespace crfcal::app
