#pragma once
// The report of a joint calibration (`crfcal calibrate --pair S1 B1 --pair S2 B2 …`, joint_calibration.hpp):
// report.hpp's schema with the joint φ per channel ("inverse_crf", "models", "covered_range": the union's envelope,
// "inverse_crf_band", "verdict", "verdict_reasons" as calibrate writes them), and
//   "joint": {"pairs": [{"sharp", "blurred", "ratio_start": {"G": r}, "ratio_joint_fit": {"G": r},
//                        "ratio_at_joint_phi": {"G": r}, "covered_range": {"G": [lo, hi]}, "pixels_used": {"G": n},
//                        "verdict": {"G": "ok"}, "own_curve_inside_band": {"G": f}, "joint_misfit": {"G": m},
//                        "report": {… the pair's own calibrate report …}}, …]}
// "exposure_ratio" is absent at the top (each pair has its own r); compare and export read the report as any other.
#include <vector>

#include "crfcal/io/calibration_report.hpp"
#include "crfcal/joint_calibration.hpp"

namespace crfcal::io {

// `results` and `contexts`: the pairs' own calibrations and report contexts, in the joint result's order.
CalibrationReport jointCalibrationReport(const JointCalibrationResult& joint,
                                         const std::vector<PairCalibrationResult>& results,
                                         const std::vector<CalibrationReportContext>& contexts);

}  // namespace crfcal::io
