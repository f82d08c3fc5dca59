// Every reader of crfcal's own formats survives 1,000 mutated inputs: truncations, flipped bytes, inserted NaN/inf,
// huge numbers, deleted and duplicated spans (deterministic seed). Each input gives a valid result or a clean
// crfcal::Error — never a crash, never another exception type — and a report that is accepted holds only curves
// that every other command accepts too (the one validation, response_curve.hpp).
#include <cmath>
#include <fstream>
#include <functional>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/response_curve.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;

namespace {

constexpr int kMutations = 1000;

std::string mutate(const std::string& original, std::mt19937& rng) {
  std::string text = original;
  static const char* kInserts[] = {"nan", "NaN", "inf", "-inf", "1e308", "-1e400", "1e999999", "-0", "0x1p-1074",
                                   "\"", "{", "]", ",", "\xFF\xFE", "\n", "#", "99999999999999999999"};
  const int edits = 1 + static_cast<int>(rng() % 4);
  for (int e = 0; e < edits && !text.empty(); ++e) {
    const std::size_t at = rng() % text.size();
    switch (rng() % 6) {
      case 0: text.resize(at); break;                                                    // truncate
      case 1: text[at] = static_cast<char>(text[at] ^ (1 << (rng() % 8))); break;        // flip a bit
      case 2: text[at] = static_cast<char>(rng() % 256); break;                          // replace a byte
      case 3: text.insert(at, kInserts[rng() % (sizeof kInserts / sizeof *kInserts)]); break;
      case 4: text.erase(at, rng() % 16); break;                                         // delete a span
      case 5: text.insert(at, text.substr(at, rng() % 32)); break;                       // duplicate a span
    }
  }
  return text;
}

// Feeds `kMutations` mutations of `original` to `read` through a file; counts accepted and refused inputs.
void fuzz(const std::string& original, const std::string& file_name, unsigned seed,
          const std::function<void(const fs::path&)>& read) {
  crfcal::test::TempDir dir;
  const fs::path path = dir / file_name;
  std::mt19937 rng(seed);
  int accepted = 0, refused = 0;
  for (int i = 0; i < kMutations; ++i) {
    const std::string input = i == 0 ? original : mutate(original, rng);
    std::ofstream(path, std::ios::binary | std::ios::trunc) << input;
    try {
      read(path);
      ++accepted;
    } catch (const crfcal::Error&) {
      ++refused;
    } catch (const std::exception& e) {
      ADD_FAILURE() << "mutation " << i << ": " << typeid(e).name() << ": " << e.what();
    }
  }
  EXPECT_EQ(accepted + refused, kMutations);
  EXPECT_GT(accepted, 0) << "the unmutated input must be accepted";
  EXPECT_GT(refused, kMutations / 10) << "mutations that cannot fail would not test the reader";
}

std::vector<double> gammaCurve(int n) {
  std::vector<double> phi(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) phi[static_cast<size_t>(i)] = std::pow(i / double(n - 1), 2.2);
  return phi;
}

}  // namespace

TEST(ReaderFuzz, ReportJsonSurvivesMutations) {
  nlohmann::json json;
  json["command"] = "calibrate";
  json["inverse_crf"] = {{"R", gammaCurve(64)}, {"G", gammaCurve(64)}};
  json["covered_range"] = {{"G", {0.05, 0.9}}};
  json["exposure_ratio"] = {{"exif", 4.0}, {"fitted", 3.9}};
  json["models"] = {{"G", {{"kind", "gamma"}, {"parameters", {2.2}}}}};
  json["warnings"] = {"w"};
  fuzz(json.dump(1), "report.json", 1, [](const fs::path& path) {
    const crfcal::io::CalibrationReport report = crfcal::io::readReport(path);
    for (const auto& [channel, phi] : report.inverse_crf)
      EXPECT_TRUE(crfcal::checkInverseSamples(phi)) << channel << ": accepted a curve ResponseCurve rejects";
  });
}

TEST(ReaderFuzz, KernelTextSurvivesMutations) {
  std::string text = "# 5x5 kernel\n";
  for (int y = 0; y < 5; ++y) {
    for (int x = 0; x < 5; ++x) text += std::to_string(0.01 * (1 + x + y)) + (x < 4 ? " " : "\n");
  }
  fuzz(text, "kernel.txt", 2, [](const fs::path& path) {
    const cv::Mat k = crfcal::io::readKernel(path);
    EXPECT_TRUE(cv::checkRange(k));
    EXPECT_NEAR(cv::sum(k)[0], 1.0, 1e-9);
  });
}

TEST(ReaderFuzz, OneColumnCurveTableSurvivesMutations) {
  std::string text = "phi\n";
  for (double v : gammaCurve(33)) text += std::to_string(v) + "\n";
  fuzz(text, "curve.txt", 3, [](const fs::path& path) {
    const crfcal::ResponseModel model = crfcal::io::parseResponseSpec("table:" + path.string());
    EXPECT_TRUE(crfcal::checkValidity(model, 1024, 1e-6));
  });
}

TEST(ReaderFuzz, TwoColumnCsvCurveSurvivesMutations) {
  std::string text = "x,phi\n";
  const auto phi = gammaCurve(33);
  for (int i = 0; i < 33; ++i) text += std::to_string(i / 32.0) + "," + std::to_string(phi[static_cast<size_t>(i)]) + "\n";
  fuzz(text, "curve.csv", 4, [](const fs::path& path) {
    EXPECT_TRUE(crfcal::checkInverseSamples(crfcal::io::readCurveTable(path, "G", 256)));
  });
}

TEST(ReaderFuzz, JsonCurveTableSurvivesMutations) {
  nlohmann::json json;
  json["inverse_crf"] = {{"G", gammaCurve(40)}};
  fuzz(json.dump(), "truth.json", 5, [](const fs::path& path) {
    EXPECT_TRUE(crfcal::checkInverseSamples(crfcal::io::readCurveTable(path, "G", 256)));
  });
}
