#pragma once
// The per-r summary tables of `crfcal bench pairs` (issues 17 and 19): r error, φ_G and shape RMSE per ratio, and the
// band's coverage of the truth pooled over the cases of a ratio.
#include <map>
#include <string>
#include <vector>

#include "crfcal/curve_band.hpp"

namespace crfcal::app {

// Per-ratio summary of a run (the targets of issue 17 are stated per r).
struct RatioSummary {
  std::string regime;
  double iso_sharp = 0, iso_blurred = 0;
  int cases = 0, done = 0, within_5_percent = 0, shape_within_001 = 0, size_limit_stops = 0, other_failures = 0;
  double sum_r_error = 0, worst_r_error = 0, sum_rmse = 0, worst_rmse = 0, sum_shape = 0, worst_shape = 0, seconds = 0;
};

// Per-ratio band scores (curve_band.hpp): x samples of the true φ_G inside the 90 % band, pooled over the cases.
struct BandSummary {
  int cases = 0;
  BandScore pooled;                     // sums of samples and hits
  std::vector<double> widths, shape_widths, scale_errors;  // per case: median widths; |a − 1| of the truth's scale
  double band_seconds = 0, seconds = 0;  // the band's stage, the whole calibrations
};

// The per-r table: r error, r within 5 %, φ_G and shape RMSE, kernel-size stops, time (markdown).
std::string ratioSummaryTable(const std::map<double, RatioSummary>& by_ratio);

// The band table: coverage inside / above / below the covered range, shape coverage, median widths (markdown).
std::string bandSummaryTable(const std::map<double, BandSummary>& by_ratio);

}  // namespace crfcal::app
