#pragma once
// Comparison of two inverse response curves φ_A, φ_B (e.g. a calibration against simulate's truth, or two
// calibrations of the same camera): RMSE and maximum absolute error per channel over the whole domain [0,1]
// and over the intensity range actually covered by data. The RMSE over [0,1] is the benchmark error of the
// seed's Sec. 5 (crfcal::curveRmse), evaluated here on a uniform grid after resampling both curves.
// Pure computation: no file I/O, no printing.
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace crfcal {

// Bounds of the factor a of the aligned comparison (φ_A ≈ a·φ_B on the covered range). The factor exists to forgive
// a different normalisation: φ(1) = 1 is pinned by extrapolation when the data stop below x = 1, and then the two
// scales may legitimately differ by several stops (one RAW shot whose flat areas stop at x = 0.5: a bound of one
// stop, [1/2, 2], changed `bench raw-truth`'s aligned medians, e.g. Nikon D70 0.0028 → 0.0086). Unbounded, a factor
// of 0 made a curve that is 0 on the covered range "equal" to any other (RMSE 0 against 0·φ_B); four stops either
// way keep that case failing and every measured normalisation difference inside.
inline constexpr double kMinAlignmentScale = 1.0 / 16, kMaxAlignmentScale = 16.0;

using IntensityRange = std::pair<double, double>;  // [lo, hi] ⊂ [0,1]

struct CurveComparisonOptions {
  int samples = 1024;  // uniform grid x = i/(samples−1) on which both curves are compared (≥ 2; 1024 = the
                       // resolution at which curves are exchanged, kCurveSamples)
  void check() const;  // throws InvalidInput
};

struct ChannelComparison {
  std::string channel;    // output label: "R", "G", "B" (a grey side is compared against each channel of the other)
  std::string channel_a;  // channel of A used
  std::string channel_b;  // channel of B used
  double rmse = 0;        // over [0,1]
  double max_error = 0;   // max |φ_A − φ_B| over [0,1]
  double argmax = 0;      // x of max_error
  IntensityRange covered{0.0, 1.0};
  std::string covered_source;  // "A∩B", "A", "B" (from the reports' covered_range) or "defined" (finite on both)
  double rmse_covered = 0;
  double max_error_covered = 0;
  int samples_covered = 0;  // grid points inside the covered range
  // Shape difference over the covered range, free of the normalisation φ(1) = 1 (which rests on each curve's
  // extrapolation above its data when the top of the range is not observed): RMSE of φ_A − a·φ_B with the
  // least-squares factor a over the covered range.
  double scale_covered = 1;          // a, least squares within [kMinAlignmentScale, kMaxAlignmentScale]
  double rmse_covered_aligned = 0;
};

struct CurveComparison {
  std::vector<ChannelComparison> channels;
  double worst_rmse = 0;          // max over channels of rmse (over [0,1])
  double worst_rmse_covered = 0;  // max over channels of rmse_covered
  double worst_rmse_covered_aligned = 0;
  // Which RMSE a tolerance applies to.
  enum class Range { Full, Covered, CoveredAligned };
  // True when every channel's RMSE (over [0,1], over the covered range, or its scale-aligned form) is ≤ tolerance.
  bool withinTolerance(double tolerance, Range range = Range::Full) const;
  std::string summary() const;  // a readable table, one line per channel
};

// Linear interpolation of samples at x = i/(n−1) (n ≥ 2); x is clamped to [0,1]. NaN samples propagate.
double interpolateSamples(const std::vector<double>& samples, double x);

// Compares two curves given by samples at x = i/(n−1) (the two may have different n). `covered_a/b` are the
// ranges supported by data for each curve, if known; the covered range is their intersection (or the one that
// is known), else the range where both curves are finite. Throws InvalidInput (fewer than 2 samples, empty
// covered intersection).
ChannelComparison compareCurves(const std::vector<double>& a, const std::vector<double>& b,
                                const std::optional<IntensityRange>& covered_a = {},
                                const std::optional<IntensityRange>& covered_b = {},
                                const CurveComparisonOptions& options = {});

// Per channel. Channels present in both are compared pairwise; a single-channel (grey) side is compared against
// every channel of the other side. Throws InvalidInput if no pair can be formed.
CurveComparison compareChannels(const std::map<std::string, std::vector<double>>& a,
                                const std::map<std::string, std::vector<double>>& b,
                                const std::map<std::string, IntensityRange>& covered_a = {},
                                const std::map<std::string, IntensityRange>& covered_b = {},
                                const CurveComparisonOptions& options = {});

}  // namespace crfcal
