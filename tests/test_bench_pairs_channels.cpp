// `crfcal bench pairs --channels rgb`: every channel judged as the brief asks (shape over the range its own pixels
// cover, after the best common scale; φ → bφ leaves Eq. 4 unchanged) and with the verdict `calibrate` gives it.
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "test_support.hpp"

namespace crfcal {
namespace {

namespace fs = std::filesystem;

using test::quote;
using test::readJson;

// One small 4:2:0 pair fitted per channel with the pointwise model (the default).
nlohmann::json benchRgbCase(const fs::path& out) {
  const auto result = test::run(quote(test::crfcalBinary()) +
                                " bench pairs --channels rgb --band-replicates 0 --image " +
                                quote(test::samples() / "effects" / "window.jpg") +
                                " --max-side 200 --kernel levin:1 --crf gamma:2.2 -o " + quote(out));
  EXPECT_EQ(result.exit_code, 0) << result.output;
  const nlohmann::json rows = readJson(out / "results.json");
  EXPECT_EQ(rows.size(), 1u);
  return rows.empty() ? nlohmann::json::object() : rows.at(0);
}

TEST(BenchPairsChannels, RgbRowsScoreEachChannelsShapeOverItsOwnCoveredRangeAndItsVerdict) {
  test::TempDir dir;
  const nlohmann::json row = benchRgbCase(dir / "out");
  for (const std::string channel : {"R", "G", "B"}) {
    SCOPED_TRACE(channel);
    ASSERT_TRUE(row.contains("phi_shape_rmse_" + channel + "_covered")) << row.dump();
    const double shape = row.at("phi_shape_rmse_" + channel + "_covered").get<double>();
    const double scale = row.at("phi_scale_" + channel + "_covered").get<double>();
    const auto covered = row.at("covered_" + channel);
    EXPECT_TRUE(std::isfinite(shape) && shape >= 0 && shape < 0.2) << shape;
    EXPECT_TRUE(scale > 0.3 && scale < 3) << scale;
    EXPECT_LT(covered.at(0).get<double>(), covered.at(1).get<double>());
    EXPECT_GE(covered.at(0).get<double>(), 0.0);
    EXPECT_LE(covered.at(1).get<double>(), 1.0);
  }
  // R and B of the pointwise model from a 4:2:0 sharp shot: the bench reads the stored sampling as calibrate does,
  // so their verdict names it, with the chroma check's result: weak when the fit where the chroma is flat differs
  // in shape and lies above (the sign of the lost chroma's bias), a note when it agrees or lies below.
  for (const std::string channel : {"R", "B"}) {
    ASSERT_TRUE(row.contains("verdict_reasons_" + channel)) << row.dump();
    const std::string reasons = row.at("verdict_reasons_" + channel).dump();
    EXPECT_NE(reasons.find("4:2:0"), std::string::npos) << reasons;
    const bool above = reasons.find("differs in shape by") != std::string::npos &&
                       reasons.find("lies above it") != std::string::npos;
    const bool below = reasons.find("lies below it") != std::string::npos;
    EXPECT_EQ(above + below + (reasons.find("has the same shape") != std::string::npos), 1) << reasons;
    EXPECT_EQ(row.at("verdict_" + channel).get<std::string>() != "ok", above) << reasons;
  }
  std::ifstream in(dir / "out" / "results.md");
  const std::string table((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_NE(table.find("mean shape RMSE over each channel's covered range"), std::string::npos) << table;
}

}  // namespace
}  // namespace crfcal
