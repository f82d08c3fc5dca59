// The camera's response from a RAW (linear) image and the JPEG of the same shot (calib/raw_truth.hpp).
#include <cmath>
#include <filesystem>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/raw_image.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/raw_truth.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {
namespace fs = std::filesystem;

constexpr const char* kCamera = "CanonEOS1DsMarkII";
// Covered range of the bundled table (its header: patch medians of 8 shots cover x in [0.0353, 0.9451]).
const IntensityRange kTableCovered{0.0352941, 0.945098};

fs::path shotFile(const std::string& shot, const std::string& kind) {
  return test::samples() / "middlebury" / kCamera / (shot + "-" + kind + ".png");
}

cv::Mat readShot(const std::string& shot, const std::string& kind) {
  return cv::imread(shotFile(shot, kind).string(), cv::IMREAD_UNCHANGED);
}

RawTruthOptions greenOnly() {
  RawTruthOptions options;
  options.channels = {"G"};
  return options;
}

// The per-pixel RAW→JPEG truth of ONE shot against the camera's bundled curve, which was fitted from the grey-patch
// medians of all 8 shots (samples/camera_curves/PROVENANCE.md): same camera, independent method. Over the range
// both cover, the shapes agree within 0.01 RMSE (scale-aligned; measured 0.0013–0.0058 on the four shots). The
// normalisation φ(1) = 1 of a single shot rests on the EMoR extrapolation above its brightest flat level, so the
// plain RMSE over the covered range is looser (measured 0.011–0.039; docs/RESULTS.md#raw-truth).
TEST(RawTruth, MiddleburyShotsMatchTheBundledCameraCurve) {
  const std::vector<double> table = io::readCurveTable(test::samples() / "camera_curves" / (std::string(kCamera) + ".csv"));
  for (const char* shot : {"wb1i1e1", "wb1i1e2", "wb1i1e3", "wb1i1e4"}) {
    const cv::Mat jpeg = readShot(shot, "jpg"), linear = readShot(shot, "raw");
    ASSERT_FALSE(jpeg.empty() || linear.empty()) << shot;
    const RawTruthResult truth = computeRawTruth(jpeg, linear, greenOnly());
    ASSERT_EQ(truth.channels.size(), 1u);
    const RawTruthChannel& g = truth.channels[0];
    EXPECT_EQ(g.channel, "G");
    EXPECT_GT(truth.registration.ecc_correlation, 0.9) << shot;  // the chart registers onto itself
    EXPECT_GT(g.explained, 0.99) << shot;
    EXPECT_GT(g.pixels, 20000) << shot;
    const auto [lo, hi] = g.fit.covered_range;
    EXPECT_GT(hi - lo, 0.35) << shot;
    const ChannelComparison cmp = compareCurves(g.fit.inverse, table, g.fit.covered_range, kTableCovered);
    EXPECT_LT(cmp.rmse_covered_aligned, 0.01) << shot << " over [" << cmp.covered.first << ", " << cmp.covered.second << "]";
    EXPECT_LT(cmp.rmse_covered, 0.05) << shot << " (a = " << cmp.scale_covered << ")";
  }
}

// The camera's colour matrix acts before the tone curve: with the fitted mixing row the per-pixel relation of the
// 24 coloured patches is several times tighter than channel against channel (step 5 of raw_truth.hpp).
TEST(RawTruth, ColourMatrixExplainsTheCrosstalk) {
  const cv::Mat jpeg = readShot("wb1i1e2", "jpg"), linear = readShot("wb1i1e2", "raw");
  RawTruthOptions plain = greenOnly();
  plain.colour_matrix = false;
  const RawTruthResult mixed = computeRawTruth(jpeg, linear, greenOnly());
  const RawTruthResult pointwise = computeRawTruth(jpeg, linear, plain);
  const RawTruthChannel &m = mixed.channels[0], &p = pointwise.channels[0];
  EXPECT_LT(m.pixel_rmse, 0.5 * p.pixel_rmse) << m.pixel_rmse << " vs " << p.pixel_rmse;
  EXPECT_GT(m.explained, p.explained);
  ASSERT_EQ(m.mix.size(), 3u);
  ASSERT_EQ(p.mix.size(), 3u);
  EXPECT_EQ(p.mix[0], 0.0);  // pointwise: G from G only
  EXPECT_EQ(p.mix[2], 0.0);
  EXPECT_GT(std::abs(m.mix[0]) + std::abs(m.mix[2]), 0.05 * std::abs(m.mix[1]));  // real crosstalk found
}

// LibRaw output and a camera JPEG differ in size, crop and possibly orientation: a 16-bit copy of the RAW, 1.3x larger,
// turned by 2 degrees and offset — and the same turned by 90 degrees — give the same truth.
TEST(RawTruth, SizeCropAndOrientationDoNotChangeTheTruth) {
  const cv::Mat jpeg = readShot("wb1i1e3", "jpg"), linear = readShot("wb1i1e3", "raw");
  const RawTruthResult base = computeRawTruth(jpeg, linear, greenOnly());
  cv::Mat linear16;
  linear.convertTo(linear16, CV_16U, 257);
  cv::Mat A = cv::getRotationMatrix2D(cv::Point2f(linear.cols / 2.f, linear.rows / 2.f), 2.0, 1.3);
  A.at<double>(0, 2) += 0.15 * linear.cols;
  A.at<double>(1, 2) += 0.15 * linear.rows;
  cv::Mat framed, turned;
  cv::warpAffine(linear16, framed, A, cv::Size(int(linear.cols * 1.6), int(linear.rows * 1.6)), cv::INTER_LINEAR);
  cv::rotate(framed, turned, cv::ROTATE_90_COUNTERCLOCKWISE);
  for (const auto& [name, image, degrees] : {std::tuple<const char*, cv::Mat, int>{"framed", framed, 0},
                                             std::tuple<const char*, cv::Mat, int>{"turned", turned, 90}}) {
    const RawTruthResult truth = computeRawTruth(jpeg, image, greenOnly());
    EXPECT_EQ(truth.rotation_degrees, degrees) << name;
    // Linear part of (linear working copy → JPEG): scale 1.3 · (working scale) with a 2-degree turn.
    const cv::Mat& H = truth.registration.homography;
    const double scale = std::hypot(H.at<double>(0, 0), H.at<double>(1, 0)) * truth.linear_scale;
    EXPECT_NEAR(scale, 1 / 1.3, 0.01) << name;
    const ChannelComparison cmp = compareCurves(truth.channels[0].fit.inverse, base.channels[0].fit.inverse,
                                                truth.channels[0].fit.covered_range, base.channels[0].fit.covered_range);
    EXPECT_LT(cmp.rmse_covered_aligned, 0.003) << name;
    EXPECT_GT(truth.channels[0].explained, 0.99) << name;
  }
}

TEST(RawTruth, RejectsRenderedAndForeignImages) {
  const cv::Mat jpeg = readShot("wb1i1e3", "jpg");
  // The JPEG's own pixels taken for linear: the relation is the identity, exponent ≈ 1.
  try {
    computeRawTruth(jpeg, jpeg, greenOnly());
    ADD_FAILURE() << "a rendered image was accepted as linear";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("looks non-linear"), std::string::npos) << e.what();
  }
  // Another scene.
  cv::Mat other;
  cv::pow(test::levinImage(1), 2.2, other);
  try {
    computeRawTruth(jpeg, other, greenOnly());
    ADD_FAILURE() << "another scene was accepted";
  } catch (const InvalidInput& e) {
    EXPECT_NE(std::string(e.what()).find("does not register"), std::string::npos) << e.what();
  }
  // Without registration the sizes must agree.
  RawTruthOptions aligned = greenOnly();
  aligned.register_images = false;
  cv::Mat small;
  cv::resize(readShot("wb1i1e3", "raw"), small, cv::Size(100, 80));
  EXPECT_THROW(computeRawTruth(jpeg, small, aligned), InvalidInput);
  EXPECT_THROW(computeRawTruth(cv::Mat(), small), InvalidInput);
}

TEST(RawTruth, OptionsAreChecked) {
  EXPECT_NO_THROW(RawTruthOptions{}.check());
  auto bad = [](auto change) {
    RawTruthOptions o;
    change(o);
    EXPECT_THROW(o.check(), InvalidInput);
  };
  bad([](RawTruthOptions& o) { o.channels = {"X"}; });
  bad([](RawTruthOptions& o) { o.channels.clear(); });
  bad([](RawTruthOptions& o) { o.fold_grid = 1; });
  bad([](RawTruthOptions& o) { o.flat_quantile = 0; });
  bad([](RawTruthOptions& o) { o.bins = 4; });
  bad([](RawTruthOptions& o) { o.smoothing_sigma = -1; });
  bad([](RawTruthOptions& o) { o.fit.max_terms = 99; });
}

// Real camera data from ../shared: the Kodak DC50 RAW against the preview the camera embedded in the same file
// (96x64, its own rendering of this very shot). Skips without ../shared.
TEST(RawTruth, KodakRawAgainstItsEmbeddedPreview) {
  const fs::path shared = test::sharedData();
  const fs::path file = shared / "raw_samples" / "RAW_KODAK_DC50.KDC";
  if (shared.empty() || !fs::exists(file)) GTEST_SKIP() << "../shared/data absent";
  const cv::Mat preview = io::readRawThumbnail(file);
  EXPECT_EQ(preview.type(), CV_8UC3);
  EXPECT_EQ(preview.cols, 96);
  io::RawDecodeOptions raw;
  raw.half_size = true;
  const RawTruthResult truth = computeRawTruth(preview, io::readRaw(file, raw).image);
  ASSERT_EQ(truth.channels.size(), 3u);
  for (const auto& c : truth.channels) {
    EXPECT_GT(c.explained, 0.97) << c.channel;
    EXPECT_GT(c.effective_gamma, 1.25) << c.channel;
  }
}

// `crfcal bench raw-truth --channels rgb` on the bundled Middlebury subset (samples/middlebury, 4 shots of the Canon
// 1Ds II): every channel's truth is written, R's and B's with their shape RMSE against G, and G's truth is the one the
// default (green-only) run writes. The camera applies one tone curve to all channels in the mid-tones: on its three
// darker shots R and B lie within 0.015 of G in shape (measured 0.0009–0.0108); on the brightest (e4, data up to
// x = 0.99) they part (0.005–0.021), docs/RESULTS.md#chroma-shared-tone-curve.
TEST(RawTruthBenchCli, EveryChannelsTruthIsWrittenWithItsShapeAgainstGreen) {
  test::TempDir dir;
  const std::string bench =
      test::crfcalBinary().string() + " bench raw-truth -q --data " + test::quote(test::samples());
  const auto rgb = test::run(bench + " --channels rgb --json " + test::quote(dir / "rgb.json"));
  ASSERT_EQ(rgb.exit_code, 0) << rgb.output;
  EXPECT_NE(rgb.output.find("R and B against G in shape"), std::string::npos) << rgb.output;
  const auto green = test::run(bench + " --json " + test::quote(dir / "g.json"));
  ASSERT_EQ(green.exit_code, 0) << green.output;
  EXPECT_EQ(green.output.find("R and B against G in shape"), std::string::npos);
  const nlohmann::json all = test::readJson(dir / "rgb.json").at("middlebury");
  const nlohmann::json green_only = test::readJson(dir / "g.json").at("middlebury");
  ASSERT_EQ(all.size(), 4u);
  ASSERT_EQ(green_only.size(), 4u);
  for (std::size_t i = 0; i < all.size(); ++i) {
    const nlohmann::json& shot = all[i];
    const std::string name = shot.at("shot");
    ASSERT_TRUE(shot.contains("channels")) << name;
    EXPECT_FALSE(green_only[i].contains("channels")) << name;
    for (const char* c : {"R", "G", "B"}) EXPECT_EQ(shot["channels"][c]["inverse_crf"].size(), 1024u) << name << c;
    EXPECT_EQ(shot.at("inverse_crf"), green_only[i].at("inverse_crf")) << name;  // G alone or beside R and B
    EXPECT_EQ(shot["channels"]["G"]["inverse_crf"], shot.at("inverse_crf")) << name;
    for (const char* c : {"R", "B"}) {
      const double shape = shot["channels"][c].at("shape_rmse_vs_G");
      EXPECT_TRUE(std::isfinite(shape)) << name << c;
      if (name != "wb1i1e4") {
        EXPECT_LT(shape, 0.015) << name << " " << c;
      }
    }
  }
}

}  // namespace
}  // namespace crfcal
