// Curve comparison (crfcal::compareCurves / compareChannels) and the `crfcal compare` command.
#include <cmath>
#include <fstream>
#include <numbers>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/response_model.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

namespace fs = std::filesystem;

std::vector<double> tabulate(int n, double (*f)(double)) {
  std::vector<double> v(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) v[static_cast<size_t>(i)] = f(double(i) / (n - 1));
  return v;
}

TEST(Compare, IdenticalCurvesHaveZeroError) {
  const auto a = sampleInverse(GammaModel{2.2});
  const ChannelComparison c = compareCurves(a, a);
  EXPECT_EQ(c.rmse, 0.0);
  EXPECT_EQ(c.max_error, 0.0);
  EXPECT_EQ(c.covered_source, "defined");
  EXPECT_EQ(c.covered.first, 0.0);
  EXPECT_EQ(c.covered.second, 1.0);
}

TEST(Compare, KnownDifference) {
  // b − a = 0.01·sin(πx): RMSE over [0,1] → 0.01/√2, max 0.01 at x = 0.5.
  const auto a = tabulate(1024, [](double x) { return x * x; });
  const auto b = tabulate(1024, [](double x) { return x * x + 0.01 * std::sin(std::numbers::pi * x); });
  CurveComparisonOptions options;
  options.samples = 4097;
  const ChannelComparison c = compareCurves(a, b, std::nullopt, std::nullopt, options);
  EXPECT_NEAR(c.rmse, 0.01 / std::sqrt(2.0), 2e-5);
  EXPECT_NEAR(c.max_error, 0.01, 1e-6);
  EXPECT_NEAR(c.argmax, 0.5, 1e-3);
  // Same as the benchmark error on the exchange grid.
  EXPECT_NEAR(compareCurves(a, b).rmse, curveRmse(a, b), 1e-12);
}

TEST(Compare, DifferentResolutionsAreResampled) {
  const auto fine = sampleInverse(GammaModel{2.0}, 1024);
  const auto coarse = sampleInverse(GammaModel{2.0}, 4097);
  const ChannelComparison c = compareCurves(fine, coarse);
  EXPECT_LT(c.max_error, 1e-6);  // interpolation error of the 1024-sample table only
}

TEST(Compare, CoveredRangeIntersection) {
  // The curves differ only below x = 0.2: over the covered range [0.3, 0.8] they agree.
  const auto a = tabulate(1024, [](double x) { return x; });
  const auto b = tabulate(1024, [](double x) { return x < 0.2 ? x + 0.05 * std::sin(5 * std::numbers::pi * x) : x; });
  const ChannelComparison c = compareCurves(a, b, IntensityRange{0.1, 0.8}, IntensityRange{0.3, 0.95});
  EXPECT_EQ(c.covered_source, "A∩B");
  EXPECT_DOUBLE_EQ(c.covered.first, 0.3);
  EXPECT_DOUBLE_EQ(c.covered.second, 0.8);
  EXPECT_LT(c.rmse_covered, 1e-12);
  EXPECT_GT(c.rmse, 0.005);
  EXPECT_EQ(c.samples_covered, 1024);
  // Only one side knows its range.
  const ChannelComparison one = compareCurves(a, b, std::nullopt, IntensityRange{0.0, 0.2});
  EXPECT_EQ(one.covered_source, "B");
  EXPECT_GT(one.rmse_covered, one.rmse);
  // Disjoint ranges: nothing to compare.
  EXPECT_THROW(compareCurves(a, b, IntensityRange{0.0, 0.2}, IntensityRange{0.5, 1.0}), InvalidInput);
}

TEST(Compare, UndefinedSamplesLimitTheCoveredRange) {
  auto a = tabulate(101, [](double x) { return x; });
  auto b = a;
  for (int i = 0; i < 10; ++i) b[static_cast<size_t>(i)] = std::numeric_limits<double>::quiet_NaN();
  b[100] = std::numeric_limits<double>::quiet_NaN();
  CurveComparisonOptions options;
  options.samples = 101;
  const ChannelComparison c = compareCurves(a, b, std::nullopt, std::nullopt, options);
  EXPECT_NEAR(c.covered.first, 0.10, 1e-12);
  EXPECT_NEAR(c.covered.second, 0.99, 1e-12);
  EXPECT_NEAR(c.rmse_covered, 0.0, 1e-12);
}

TEST(Compare, GreyAgainstRgbComparesEveryChannel) {
  std::map<std::string, std::vector<double>> grey{{"G", sampleInverse(GammaModel{2.2})}};
  std::map<std::string, std::vector<double>> rgb{{"R", sampleInverse(GammaModel{2.0})},
                                                 {"G", sampleInverse(GammaModel{2.2})},
                                                 {"B", sampleInverse(GammaModel{2.4})}};
  const CurveComparison c = compareChannels(grey, rgb);
  ASSERT_EQ(c.channels.size(), 3u);
  EXPECT_EQ(c.channels[0].channel, "R");
  EXPECT_EQ(c.channels[0].channel_a, "G");
  EXPECT_EQ(c.channels[1].rmse, 0.0);
  EXPECT_GT(c.channels[2].rmse, 0.01);
  EXPECT_DOUBLE_EQ(c.worst_rmse, std::max(c.channels[0].rmse, c.channels[2].rmse));
  EXPECT_TRUE(c.withinTolerance(0.1));
  EXPECT_FALSE(c.withinTolerance(0.001));
  EXPECT_NE(c.summary().find("G->R"), std::string::npos);
  // RGB vs RGB: pairwise.
  EXPECT_EQ(compareChannels(rgb, rgb).worst_rmse, 0.0);
  // Nothing in common.
  EXPECT_THROW(compareChannels({{"R", grey.at("G")}, {"B", grey.at("G")}}, {{"X", grey.at("G")}, {"Y", grey.at("G")}}),
               InvalidInput);
}

TEST(Compare, ScaleAlignedErrorIgnoresTheNormalisation) {
  // B = A/0.8 over the covered range (a different φ(1) = 1 normalisation of the same shape, e.g. two fits that
  // extrapolate differently above their data): large plain error, zero shape error with a = 0.8.
  const auto a = tabulate(1024, [](double x) { return 0.8 * std::pow(x, 2.2) + 0.2 * std::pow(x, 12.0); });
  const auto b = tabulate(1024, [](double x) { return std::pow(x, 2.2); });
  const ChannelComparison c = compareCurves(a, b, IntensityRange{0.05, 0.6}, std::nullopt);
  EXPECT_GT(c.rmse_covered, 0.02);
  EXPECT_NEAR(c.scale_covered, 0.8, 2e-3);
  EXPECT_LT(c.rmse_covered_aligned, 1e-3);
  // A shape difference survives the alignment.
  const auto d = tabulate(1024, [](double x) { return std::pow(x, 1.8); });
  EXPECT_GT(compareCurves(d, b, IntensityRange{0.05, 0.6}, std::nullopt).rmse_covered_aligned, 0.01);
  // Tolerances on the three RMSEs.
  const CurveComparison cc = compareChannels({{"G", a}}, {{"G", b}}, {{"G", {0.05, 0.6}}});
  EXPECT_FALSE(cc.withinTolerance(0.01, CurveComparison::Range::Covered));
  EXPECT_TRUE(cc.withinTolerance(0.01, CurveComparison::Range::CoveredAligned));
  EXPECT_DOUBLE_EQ(cc.worst_rmse_covered_aligned, cc.channels[0].rmse_covered_aligned);
}

// ---- the command ----

io::CalibrationReport reportOf(const ResponseModel& model, double ratio) {
  io::CalibrationReport report;
  report.command = "calibrate";
  report.inverse_crf["G"] = sampleInverse(model);
  report.models["G"] = model;
  report.fitted_ratio = ratio;
  report.nominal_ratio = 1.0;
  report.nominal_ratio_source = "exif";
  report.covered_range["G"] = {0.05, 0.9};
  return report;
}

TEST(Compare, CommandTableJsonPlotAndTolerance) {
  test::TempDir dir;
  io::writeReport(dir / "a.json", reportOf(GammaModel{2.2}, 1.02));
  // B as simulate's truth.json: a plain "inverse_crf" list and a numeric "exposure_ratio".
  nlohmann::json truth;
  truth["inverse_crf"] = sampleInverse(GammaModel{2.0});
  truth["exposure_ratio"] = 1.0;
  std::ofstream(dir / "truth.json") << truth.dump();
  const std::string binary = test::crfcalBinary().string();
  const std::string args = " compare " + (dir / "a.json").string() + " " + (dir / "truth.json").string();
  const double rmse = curveRmse(GammaModel{2.2}, GammaModel{2.0});

  auto result = test::run(binary + args + " -o " + (dir / "cmp").string());
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_NE(result.output.find("RMSE"), std::string::npos);
  EXPECT_NE(result.output.find("1.02"), std::string::npos) << result.output;  // the fitted ratio of A
  ASSERT_TRUE(fs::exists(dir / "cmp" / "compare.png"));
  std::ifstream in(dir / "cmp" / "compare.json");
  const nlohmann::json json = nlohmann::json::parse(in);
  ASSERT_EQ(json["channels"].size(), 1u);
  EXPECT_NEAR(json["channels"][0]["rmse"].get<double>(), rmse, 1e-9);
  EXPECT_EQ(json["channels"][0]["covered_source"], "A");
  EXPECT_NEAR(json["channels"][0]["covered_range"][0].get<double>(), 0.05, 1e-12);
  EXPECT_NEAR(json["exposure_ratio"]["a"]["fitted"].get<double>(), 1.02, 1e-12);
  EXPECT_NEAR(json["exposure_ratio"]["b"]["fitted"].get<double>(), 1.0, 1e-12);
  EXPECT_TRUE(json["exposure_ratio"]["b"]["nominal"].is_null());
  EXPECT_EQ(json["exposure_ratio"]["a"]["nominal"].get<double>(), 1.0);
  EXPECT_EQ(json["exposure_ratio"]["a"]["nominal_source"], "exif");

  result = test::run(binary + args + " --tolerance " + std::to_string(rmse * 0.5));
  EXPECT_EQ(result.exit_code, 3) << result.output;
  EXPECT_NE(result.output.find("FAIL"), std::string::npos);
  result = test::run(binary + args + " --tolerance " + std::to_string(rmse * 2) + " -q");
  EXPECT_EQ(result.exit_code, 0) << result.output;
  EXPECT_NE(result.output.find("PASS"), std::string::npos);
  result = test::run(binary + args + " --tolerance 1e-9 --tolerance-range covered -q");
  EXPECT_EQ(result.exit_code, 3) << result.output;
  result = test::run(binary + args + " --tolerance 1e-9 --tolerance-range aligned -q");
  EXPECT_EQ(result.exit_code, 3) << result.output;
  EXPECT_NE(result.output.find("scale-aligned"), std::string::npos) << result.output;
  EXPECT_TRUE(json["channels"][0].contains("rmse_covered_aligned"));
  EXPECT_GT(json["channels"][0]["scale_covered"].get<double>(), 0.0);
}

// report.json's exposure ratio: "nominal" with its source; reports written before it had only "exif".
TEST(Compare, ReportReadsTheNominalRatioFromNewAndOldKeys) {
  nlohmann::json old_report = {{"inverse_crf", {0.0, 1.0}}, {"exposure_ratio", {{"exif", 2.5}, {"fitted", 2.4}}}};
  io::CalibrationReport old_read = io::CalibrationReport::fromJson(old_report);
  ASSERT_TRUE(old_read.nominal_ratio.has_value());
  EXPECT_EQ(*old_read.nominal_ratio, 2.5);
  EXPECT_EQ(old_read.nominal_ratio_source, "exif");
  EXPECT_EQ(*old_read.fitted_ratio, 2.4);

  old_read.nominal_ratio_source = "--ratio";
  const nlohmann::json written = old_read.toJson();
  EXPECT_EQ(written["exposure_ratio"]["nominal"].get<double>(), 2.5);
  EXPECT_EQ(written["exposure_ratio"]["nominal_source"], "--ratio");
  EXPECT_FALSE(written["exposure_ratio"].contains("exif"));  // not EXIF's value
  const io::CalibrationReport new_read = io::CalibrationReport::fromJson(written);
  EXPECT_EQ(*new_read.nominal_ratio, 2.5);
  EXPECT_EQ(new_read.nominal_ratio_source, "--ratio");
}

TEST(Compare, CommandErrorsAreOneLine) {
  test::TempDir dir;
  io::writeReport(dir / "a.json", reportOf(GammaModel{2.2}, 1.0));
  std::ofstream(dir / "broken.json") << "{\"inverse_crf\": [0, 0.5";
  std::ofstream(dir / "empty.json") << "{\"command\": \"calibrate\"}";
  const std::string binary = test::crfcalBinary().string();
  for (const char* other : {"missing.json", "broken.json", "empty.json"}) {
    const auto result = test::run(binary + " compare " + (dir / "a.json").string() + " " + (dir / other).string());
    EXPECT_EQ(result.exit_code, 1) << other << ": " << result.output;
    EXPECT_NE(result.output.find(other), std::string::npos) << result.output;
    EXPECT_EQ(std::count(result.output.begin(), result.output.end(), '\n'), 1) << result.output;
  }
}

}  // namespace
}  // namespace crfcal
