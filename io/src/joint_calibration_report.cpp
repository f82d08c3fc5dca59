#include "crfcal/io/joint_calibration_report.hpp"

#include "crfcal/error.hpp"
#include "crfcal/io/band_report.hpp"

namespace crfcal::io {

using nlohmann::json;

CalibrationReport jointCalibrationReport(const JointCalibrationResult& joint,
                                         const std::vector<PairCalibrationResult>& results,
                                         const std::vector<CalibrationReportContext>& contexts) {
  if (results.size() != joint.pairs.size() || contexts.size() != joint.pairs.size())
    throw Error("joint report: one result and one context per pair expected");
  CalibrationReport report = curveFitsReport(joint.fits);
  report.timings = joint.timings;
  report.covered_range = joint.covered_range;
  report.warnings = joint.warnings;
  json pairs = json::array();
  for (std::size_t p = 0; p < results.size(); ++p) {
    const JointPairSummary& s = joint.pairs[p];
    const CalibrationReport own = calibrationReport(results[p], contexts[p]);
    for (const auto& w : own.warnings) report.warnings.push_back("pair " + std::to_string(p + 1) + ": " + w);
    json verdict = json::object();
    for (const auto& [c, level] : s.verdict) verdict[c] = toString(level);
    json covered = json::object();
    for (const auto& [c, range] : s.covered_range) covered[c] = {range.first, range.second};
    pairs.push_back({{"sharp", contexts[p].pair.sharp.path.string()},
                     {"blurred", contexts[p].pair.blurred.path.string()},
                     {"ratio_start", s.ratio_start},
                     {"ratio_joint_fit", s.ratio},
                     {"ratio_at_joint_phi", s.ratio_at_joint_phi},
                     {"covered_range", covered},
                     {"pixels_used", s.pixels_used},
                     {"verdict", verdict},
                     {"own_curve_inside_band", s.own_curve_inside_band},
                     {"joint_misfit", s.joint_misfit},
                     {"report", own.toJson()}});
    if (!s.offset.empty()) pairs.back()["offset"] = s.offset;
  }
  json& extra = report.extra;
  extra["joint"] = {{"pairs", pairs},
                    {"method", "one phi per channel fitted to every pair's moment rows, each pair with its own "
                               "kernel and its own r, which starts at its single-pair value and moves to the "
                               "least-squares r of its rows at the joint phi (joint_crf_fit.hpp)"}};
  json fit = json::object();
  for (const auto& [name, f] : joint.fits)
    fit[name] = {{"chosen", f.chosen}, {"choice_reason", f.choice_reason}, {"energy", f.energy},
                 {"spec", describe(f.model)}};
  extra["fit"] = fit;
  if (!joint.bands.empty()) extra["inverse_crf_band"] = curveBandsJson(joint.bands);
  extra["verdict"] = json::object();
  extra["verdict_reasons"] = json::object();
  for (const auto& [name, verdict] : joint.verdicts) {
    extra["verdict"][name] = toString(verdict.level);
    extra["verdict_reasons"][name] = verdict.reasons;
  }
  return report;
}

}  // namespace crfcal::io
