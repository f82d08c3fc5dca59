#include "crfcal/curve_comparison.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "crfcal/error.hpp"

namespace crfcal {
namespace {

struct ErrorStats {
  double rmse = 0, max_error = 0, argmax = 0;
  int count = 0;
};

// Errors on `n` uniform points of [lo, hi], skipping points where either curve is not finite.
ErrorStats errorsOn(const std::vector<double>& a, const std::vector<double>& b, double lo, double hi, int n) {
  ErrorStats stats;
  double sum = 0;
  for (int i = 0; i < n; ++i) {
    const double x = n == 1 ? lo : lo + (hi - lo) * double(i) / double(n - 1);
    const double d = interpolateSamples(a, x) - interpolateSamples(b, x);
    if (!std::isfinite(d)) continue;
    sum += d * d;
    ++stats.count;
    if (std::abs(d) > stats.max_error) {
      stats.max_error = std::abs(d);
      stats.argmax = x;
    }
  }
  stats.rmse = stats.count > 0 ? std::sqrt(sum / stats.count) : std::numeric_limits<double>::quiet_NaN();
  if (stats.count == 0) stats.max_error = std::numeric_limits<double>::quiet_NaN();
  return stats;
}

void checkRange(const IntensityRange& range, const char* which) {
  if (!std::isfinite(range.first) || !std::isfinite(range.second) || range.first > range.second)
    throw InvalidInput(std::string("covered range of ") + which + " is not an interval");
}

}  // namespace

void CurveComparisonOptions::check() const {
  if (samples < 2) throw InvalidInput("curve comparison needs at least 2 grid samples");
}

double interpolateSamples(const std::vector<double>& samples, double x) {
  const size_t n = samples.size();
  if (n == 0) return std::numeric_limits<double>::quiet_NaN();
  if (n == 1) return samples[0];
  const double position = std::clamp(x, 0.0, 1.0) * double(n - 1);
  const size_t i = std::min(static_cast<size_t>(position), n - 2);
  const double t = position - double(i);
  if (t == 0) return samples[i];
  return samples[i] + t * (samples[i + 1] - samples[i]);
}

ChannelComparison compareCurves(const std::vector<double>& a, const std::vector<double>& b,
                                const std::optional<IntensityRange>& covered_a,
                                const std::optional<IntensityRange>& covered_b, const CurveComparisonOptions& options) {
  options.check();
  if (a.size() < 2 || b.size() < 2) throw InvalidInput("a curve needs at least 2 samples");
  ChannelComparison result;
  const ErrorStats full = errorsOn(a, b, 0.0, 1.0, options.samples);
  result.rmse = full.rmse;
  result.max_error = full.max_error;
  result.argmax = full.argmax;

  // Covered range: the reports' covered ranges (intersected), else where both curves are finite.
  if (covered_a) checkRange(*covered_a, "A");
  if (covered_b) checkRange(*covered_b, "B");
  if (covered_a && covered_b) {
    result.covered = {std::max(covered_a->first, covered_b->first), std::min(covered_a->second, covered_b->second)};
    result.covered_source = "A∩B";
    if (result.covered.first > result.covered.second)
      throw InvalidInput("the covered ranges of A and B do not overlap");
  } else if (covered_a || covered_b) {
    result.covered = covered_a ? *covered_a : *covered_b;
    result.covered_source = covered_a ? "A" : "B";
  } else {
    result.covered_source = "defined";
    int first = -1, last = -1;
    for (int i = 0; i < options.samples; ++i) {
      const double x = double(i) / double(options.samples - 1);
      if (std::isfinite(interpolateSamples(a, x)) && std::isfinite(interpolateSamples(b, x))) {
        if (first < 0) first = i;
        last = i;
      }
    }
    if (first < 0) throw InvalidInput("the two curves have no point where both are defined");
    result.covered = {double(first) / double(options.samples - 1), double(last) / double(options.samples - 1)};
  }
  result.covered.first = std::clamp(result.covered.first, 0.0, 1.0);
  result.covered.second = std::clamp(result.covered.second, 0.0, 1.0);
  const int n = result.covered.first == result.covered.second ? 1 : options.samples;
  const ErrorStats covered = errorsOn(a, b, result.covered.first, result.covered.second, n);
  result.rmse_covered = covered.rmse;
  result.max_error_covered = covered.max_error;
  result.samples_covered = covered.count;
  // Least-squares factor a of φ_A ≈ a·φ_B on the same grid (bounded: kMinAlignmentScale), then the RMSE of the
  // difference.
  double ab = 0, bb = 0;
  for (int i = 0; i < n; ++i) {
    const double x = n == 1 ? result.covered.first
                            : result.covered.first + (result.covered.second - result.covered.first) * double(i) / double(n - 1);
    const double va = interpolateSamples(a, x), vb = interpolateSamples(b, x);
    if (!std::isfinite(va) || !std::isfinite(vb)) continue;
    ab += va * vb;
    bb += vb * vb;
  }
  // The error is a convex quadratic in a: the best factor within the bounds is the unconstrained one, clamped.
  result.scale_covered = std::clamp(bb > 0 && std::isfinite(ab / bb) ? ab / bb : 1.0, kMinAlignmentScale,
                                    kMaxAlignmentScale);
  std::vector<double> scaled(b);
  for (double& v : scaled) v *= result.scale_covered;
  result.rmse_covered_aligned = errorsOn(a, scaled, result.covered.first, result.covered.second, n).rmse;
  return result;
}

CurveComparison compareChannels(const std::map<std::string, std::vector<double>>& a,
                                const std::map<std::string, std::vector<double>>& b,
                                const std::map<std::string, IntensityRange>& covered_a,
                                const std::map<std::string, IntensityRange>& covered_b,
                                const CurveComparisonOptions& options) {
  options.check();
  if (a.empty() || b.empty()) throw InvalidInput("a report has no curves to compare");
  auto ordered = [](const std::map<std::string, std::vector<double>>& curves) {
    std::vector<std::string> names;
    for (const char* c : {"R", "G", "B"})
      if (curves.count(c)) names.emplace_back(c);
    for (const auto& [name, _] : curves)
      if (name != "R" && name != "G" && name != "B") names.push_back(name);
    return names;
  };
  auto find = [](const std::map<std::string, IntensityRange>& ranges, const std::string& channel) {
    const auto it = ranges.find(channel);
    return it == ranges.end() ? std::optional<IntensityRange>() : std::optional<IntensityRange>(it->second);
  };

  std::vector<std::pair<std::string, std::string>> pairs;  // (channel of A, channel of B)
  for (const auto& name : ordered(a))
    if (b.count(name)) pairs.emplace_back(name, name);
  if (pairs.empty() || (pairs.size() < std::max(a.size(), b.size()) && (a.size() == 1 || b.size() == 1))) {
    pairs.clear();
    if (a.size() == 1) {
      for (const auto& name : ordered(b)) pairs.emplace_back(a.begin()->first, name);
    } else if (b.size() == 1) {
      for (const auto& name : ordered(a)) pairs.emplace_back(name, b.begin()->first);
    }
  }
  if (pairs.empty()) throw InvalidInput("the two reports have no channel in common");

  CurveComparison result;
  for (const auto& [ca, cb] : pairs) {
    ChannelComparison channel =
        compareCurves(a.at(ca), b.at(cb), find(covered_a, ca), find(covered_b, cb), options);
    channel.channel_a = ca;
    channel.channel_b = cb;
    channel.channel = ca == cb ? ca : (a.size() == 1 ? cb : ca);
    result.worst_rmse = std::max(result.worst_rmse, channel.rmse);
    result.worst_rmse_covered = std::max(result.worst_rmse_covered, channel.rmse_covered);
    result.worst_rmse_covered_aligned = std::max(result.worst_rmse_covered_aligned, channel.rmse_covered_aligned);
    result.channels.push_back(std::move(channel));
  }
  return result;
}

bool CurveComparison::withinTolerance(double tolerance, Range range) const {
  for (const auto& c : channels) {
    const double e = range == Range::Full ? c.rmse : range == Range::Covered ? c.rmse_covered : c.rmse_covered_aligned;
    if (!(e <= tolerance)) return false;  // NaN fails
  }
  return true;
}

std::string CurveComparison::summary() const {
  std::string text =
      "channel  A->B   RMSE[0,1]   max[0,1]  (at x)   covered range      RMSE(cov)   max(cov)   RMSE(cov, A vs a*B)\n";
  char line[256];
  for (const auto& c : channels) {
    std::snprintf(line, sizeof line,
                  "%-7s  %s->%s  %10.3e  %10.3e  (%.3f)  [%.3f, %.3f] %-7s %10.3e  %10.3e  %10.3e (a = %.4f)\n",
                  c.channel.c_str(), c.channel_a.c_str(), c.channel_b.c_str(), c.rmse, c.max_error, c.argmax,
                  c.covered.first, c.covered.second, c.covered_source == "A∩B" ? "A&B" : c.covered_source.c_str(),
                  c.rmse_covered, c.max_error_covered, c.rmse_covered_aligned, c.scale_covered);
    text += line;
  }
  return text;
}

}  // namespace crfcal
