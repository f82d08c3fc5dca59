// crfcal calibrate's verdict per channel (channel_verdict.hpp) in report.json and on the terminal, and --strict's
// exit code 4 on the bundled demo pair (samples/pairs, r ≈ 1): ok as measured; unreliable when r is fixed at 4,
// which the shots' brightness ratio (≈ 1) contradicts.
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "test_support.hpp"

namespace crfcal {
namespace {
namespace fs = std::filesystem;

// The demo pair, fast settings (G only, the known kernel, no rounds, no effect diagnostics).
std::string demoCommand(const fs::path& out, const std::string& extra) {
  const fs::path pairs = test::samples() / "pairs";
  return test::crfcalBinary().string() + " calibrate -q " + (pairs / "sharp.jpg").string() + " " +
         (pairs / "blurred.jpg").string() + " --channels g --rounds 0 --no-effects --kernel " +
         (test::samples() / "levin09" / "kernel03.txt").string() + " -o " + out.string() + " " + extra;
}

nlohmann::json readReport(const fs::path& dir) {
  std::ifstream in(dir / "report.json");
  return nlohmann::json::parse(in);
}

TEST(VerdictCli, DemoPairIsOkAndStrictExitsZero) {
  test::TempDir dir;
  const auto r = test::run(demoCommand(dir / "out", "--strict"));
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto report = readReport(dir / "out");
  EXPECT_EQ(report["verdict"]["G"], "ok") << report["verdict_reasons"].dump();
  ASSERT_TRUE(report["verdict_reasons"]["G"].is_array());
  EXPECT_FALSE(report["verdict_reasons"]["G"].empty());
  EXPECT_NEAR(report["brightness_ratio"]["G"].get<double>(), 1.0, 0.15);
  EXPECT_NE(r.output.find("verdict G: ok"), std::string::npos) << r.output;
}

TEST(VerdictCli, StrictExitsFourWhenAChannelIsUnreliableAndStillWrites) {
  test::TempDir dir;
  const std::string fixed_wrong = "--ratio 4 --fix-ratio";
  const auto lenient = test::run(demoCommand(dir / "lenient", fixed_wrong));
  EXPECT_EQ(lenient.exit_code, 0) << lenient.output;
  const auto strict = test::run(demoCommand(dir / "strict", fixed_wrong + " --strict"));
  EXPECT_EQ(strict.exit_code, 4) << strict.output;
  EXPECT_NE(strict.output.find("--strict: channel G unreliable"), std::string::npos) << strict.output;
  for (const char* f : {"report.json", "inverse_crf.csv", "curve.png"}) EXPECT_TRUE(fs::exists(dir / "strict" / f)) << f;
  const auto report = readReport(dir / "strict");
  EXPECT_EQ(report["verdict"]["G"], "unreliable");
  EXPECT_NE(report["verdict_reasons"]["G"][0].get<std::string>().find("brightness ratio"), std::string::npos)
      << report["verdict_reasons"].dump();
}

// The demo pair's JPEGs are 4:2:0. With the pointwise model R and B name it in their reasons, and the chroma check
// decides their level: B, whose φ is 27× worse than G's (its shape 0.026 after the best scale,
// docs/RESULTS.md#chroma-now), differs in shape from its fit where the chroma is flat, so it is "weak"; G stays "ok".
TEST(VerdictCli, DemoPairBlueFromSubsampledChromaIsWeakByTheChromaCheck) {
  test::TempDir dir;
  std::string command = demoCommand(dir / "out", "");
  command.replace(command.find("--channels g"), 12, "--channels rgb");
  const auto r = test::run(command);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto report = readReport(dir / "out");
  EXPECT_EQ(report["verdict"]["G"], "ok") << report["verdict_reasons"].dump();
  for (const char* name : {"R", "B"})
    EXPECT_NE(report["verdict_reasons"][name].dump().find("4:2:0"), std::string::npos)
        << report["verdict_reasons"].dump();
  EXPECT_EQ(report["verdict"]["B"], "weak") << report["verdict_reasons"].dump();
  EXPECT_NE(report["verdict_reasons"]["B"].dump().find("differs in shape by"), std::string::npos)
      << report["verdict_reasons"].dump();
}

}  // namespace
}  // namespace crfcal
