// report.json's `effects_refit` block (io/src/calibration_report.cpp): whose φ is reported after the effect
// diagnostics asked for a refit, and why. A refit the fitter refused is written as failed, with the fitter's reason
// and no held-out errors (none were measured); a judged refit keeps its held-out errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "crfcal/io/calibration_report.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal {
namespace {

// A calibration result with one linear green curve and the effect diagnostics' refit as `refit` describes it.
PairCalibrationResult resultWithRefit(const EffectReport& refit) {
  PairCalibrationResult result;
  CrfFitResult green;
  green.inverse_crf.resize(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) green.inverse_crf[i] = static_cast<double>(i) / (kCurveSamples - 1);
  green.model = TableModel{green.inverse_crf};
  green.ratio = 2;
  result.channels = {"G"};
  result.fits["G"] = green;
  result.effects = refit;
  return result;
}

// report.json of that result (no input files: the report's input block is empty).
io::CalibrationReport reportWithRefit(const EffectReport& refit) {
  const io::LoadedPair pair;
  const io::CalibrationReportContext context{pair, 0, "", false, 0, nullptr};
  return io::calibrationReport(resultWithRefit(refit), context);
}

bool hasWarningContaining(const io::CalibrationReport& report, const std::string& text) {
  return std::any_of(report.warnings.begin(), report.warnings.end(),
                     [&](const std::string& w) { return w.find(text) != std::string::npos; });
}

TEST(ReportEffectsRefit, FailedRefitIsWrittenAsFailedWithItsReasonAndNoHeldOutErrors) {
  EffectReport failed;
  failed.refit_tried = true;
  failed.refit_failed = true;
  failed.refit_rejected_reason = "the corrected pair could not be refitted: channel G: fit: no usable edges";
  const io::CalibrationReport report = reportWithRefit(failed);
  ASSERT_TRUE(report.extra.contains("effects_refit"));
  const auto& block = report.extra["effects_refit"];
  EXPECT_TRUE(block["failed"].get<bool>());
  EXPECT_FALSE(block["adopted"].get<bool>());
  EXPECT_EQ(block["rejected_reason"].get<std::string>(), failed.refit_rejected_reason);
  EXPECT_FALSE(block.contains("heldout_error_refit")) << block.dump();
  EXPECT_TRUE(hasWarningContaining(report, "refit failed (the corrected pair could not be refitted"));
}

TEST(ReportEffectsRefit, RejectedRefitKeepsTheHeldOutErrorsThatDecidedIt) {
  EffectReport rejected;
  rejected.refit_tried = true;
  rejected.refit_rejected_reason = "its phi explains the held-back pixels worse than the base fit";
  rejected.heldout_error_base_fit = 0.002;
  rejected.heldout_error_refit = 0.003;
  const io::CalibrationReport report = reportWithRefit(rejected);
  const auto& block = report.extra["effects_refit"];
  EXPECT_FALSE(block["failed"].get<bool>());
  EXPECT_DOUBLE_EQ(block["heldout_error_refit"].get<double>(), 0.003);
  EXPECT_DOUBLE_EQ(block["heldout_error_base_fit"].get<double>(), 0.002);
  EXPECT_TRUE(hasWarningContaining(report, "refit was rejected"));
}

}  // namespace
}  // namespace crfcal
