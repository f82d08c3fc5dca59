// ColorChecker calibration (crfcal chart) and the bundled real camera curves (crfcal curves middlebury).
#include <algorithm>
#include <cmath>
#include <fstream>
#include <random>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/chart_calibration.hpp"
#include "crfcal/colorchecker.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/io/chart_io.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

namespace fs = std::filesystem;

const char* kBundledCamera = "CanonEOS1DsMarkII";

// RMSE of a − (best factor)·b over the samples with x in [lo, hi] (shape error, free of the φ(1) = 1 normalisation).
double scaledRmse(const std::vector<double>& a, const std::vector<double>& b, double lo, double hi) {
  double num = 0, den = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double x = double(i) / double(a.size() - 1);
    if (x >= lo && x <= hi) num += a[i] * b[i], den += b[i] * b[i];
  }
  const double f = num / den;
  double sum = 0;
  int n = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    const double x = double(i) / double(a.size() - 1);
    if (x >= lo && x <= hi) sum += std::pow(a[i] - f * b[i], 2), ++n;
  }
  return std::sqrt(sum / n);
}

// A rectified 390×260 chart (BGR 8 bit) whose patch p has the given R,G,B values in [0,1].
cv::Mat syntheticChart(const std::vector<std::array<double, 3>>& rgb) {
  cv::Mat chart(260, 390, CV_8UC3);
  for (int p = 0; p < chart::kPatches; ++p) {
    const auto& v = rgb[static_cast<size_t>(p)];
    const cv::Rect cell((p % 6) * 65, (p / 6) * 65, 65, 65);
    chart(cell).setTo(cv::Scalar(std::round(255 * v[2]), std::round(255 * v[1]), std::round(255 * v[0])));
  }
  return chart;
}

std::vector<ChartShot> bundledShots(bool with_raw) {
  std::vector<ChartShot> shots;
  for (const auto& shot : io::listMiddleburyShots(test::samples() / "middlebury" / kBundledCamera)) {
    ChartShot s;
    s.name = shot.name;
    s.measured = chart::sampleRectified(io::loadChart(shot.jpg, io::ChartLayout::Rectified).rectified);
    if (with_raw) s.raw = chart::sampleRectified(io::loadChart(shot.raw, io::ChartLayout::Rectified).rectified);
    shots.push_back(std::move(s));
  }
  return shots;
}

TEST(CameraCurve, BundledTablesAreValidMonotoneCurves) {
  const fs::path dir = test::samples() / "camera_curves";
  int count = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    if (entry.path().extension() != ".csv") continue;
    ++count;
    const std::vector<double> phi = io::readCurveTable(entry.path());
    ASSERT_EQ(phi.size(), size_t(kCurveSamples)) << entry.path();
    const ModelValidity validity = checkValidity(TableModel{phi}, 4096, 1e-7);
    EXPECT_TRUE(validity.valid) << entry.path() << ": " << validity.reason;
    // A real camera's inverse response is convex-ish: well below the identity in the mid-tones.
    EXPECT_LT(phi[511], 0.35) << entry.path();
    EXPECT_GT(phi[511], 0.03) << entry.path();
  }
  EXPECT_EQ(count, 10);
  EXPECT_TRUE(fs::exists(dir / "PROVENANCE.md"));
}

TEST(CameraCurve, BundledShotsReproduceTheBundledCurve) {
  // The bundled subset (4 of 8 shots) of one camera, RAW reference, grey patches: the same curve as the table
  // made from all 8 shots, within the covered range.
  ChartCalibrationOptions options;
  options.use_raw = true;
  options.raw_neutral_only = true;
  options.channels = {1};
  options.fit.exponent_smoothness = 0;  // as `crfcal curves middlebury`, which made the bundled tables
  const ChartCalibrationResult result = calibrateChart(bundledShots(true), options);
  ASSERT_EQ(result.channels.size(), 1u);
  const ChartChannelResult& g = result.channels.front();
  EXPECT_LT(g.fit.rmse, 0.012);
  const std::vector<double> table =
      io::readCurveTable(test::samples() / "camera_curves" / (std::string(kBundledCamera) + ".csv"));
  const auto [lo, hi] = g.fit.covered_range;
  EXPECT_LT(lo, 0.1);
  EXPECT_GT(hi, 0.85);
  EXPECT_LT(scaledRmse(table, g.fit.inverse, lo, hi), 0.01);
  EXPECT_LT(curveRmse(table, g.fit.inverse), 0.05);
}

TEST(Chart, ReflectanceCalibrationMatchesRawTruthOnRealCamera) {
  // JPEG shots against the published grey reflectances (free exposure per shot) vs the RAW→JPEG truth.
  const std::vector<ChartShot> shots = bundledShots(true);
  ChartCalibrationOptions truth_options;
  truth_options.use_raw = true;
  truth_options.raw_neutral_only = true;
  const ChartCalibrationResult truth = calibrateChart(shots, truth_options);
  ChartCalibrationOptions options;  // neutral reference, per-shot scales
  const ChartCalibrationResult fit = calibrateChart(shots, options);
  ASSERT_EQ(fit.channels.size(), 3u);
  for (size_t c = 0; c < 3; ++c) {
    const auto& f = fit.channels[c];
    EXPECT_EQ(f.fit.scales.size(), shots.size());
    EXPECT_TRUE(checkValidity(TableModel{f.fit.inverse}, 4096, 1e-7).valid);
    EXPECT_LT(scaledRmse(truth.channels[c].fit.inverse, f.fit.inverse, f.fit.covered_range.first,
                         f.fit.covered_range.second),
              0.02)
        << channelName(int(c));
    EXPECT_LT(f.ggcm_rmse, 0.03) << "GGCM conversion of channel " << channelName(int(c));
  }
}

TEST(Chart, SamplerRejectsClippedAndNonUniformPatches) {
  std::vector<std::array<double, 3>> rgb(chart::kPatches);
  for (int p = 0; p < chart::kPatches; ++p) rgb[static_cast<size_t>(p)] = {0.2 + 0.02 * p, 0.3, 0.25};
  cv::Mat image = syntheticChart(rgb);
  // Patch 3: clipped in the red channel. Patch 7: strong horizontal gradient. Patch 12: heavy noise.
  image(cv::Rect(3 * 65, 0, 65, 65)).setTo(cv::Scalar(60, 80, 255));
  for (int x = 0; x < 65; ++x) image(cv::Rect(1 * 65 + x, 65, 1, 65)).setTo(cv::Scalar(40, 60 + x * 2, 90));
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0, 25);
  for (int y = 130; y < 195; ++y)
    for (int x = 0; x < 65; ++x)
      image.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(100 + noise(rng)),
                                            cv::saturate_cast<uchar>(100 + noise(rng)),
                                            cv::saturate_cast<uchar>(100 + noise(rng)));
  const std::vector<chart::PatchStats> stats = chart::sampleRectified(image);
  ASSERT_EQ(stats.size(), size_t(chart::kPatches));
  for (const auto& s : stats) {
    if (s.patch == 3) {
      EXPECT_TRUE(s.clipped && s.clipped_high);
      EXPECT_EQ(s.rejection(), "clipped");
    } else if (s.patch == 7 || s.patch == 12) {
      EXPECT_TRUE(s.non_uniform) << s.patch;
    } else {
      EXPECT_TRUE(s.usable()) << s.patch << " " << s.rejection();
      EXPECT_NEAR(s.median[0], std::round(255 * (0.2 + 0.02 * s.patch)) / 255, 1e-9);
      EXPECT_NEAR(s.median[1], std::round(255 * 0.3) / 255, 1e-9);
    }
  }
}

TEST(Chart, RecoversPerShotExposureScalesOnSyntheticCharts) {
  // Charts rendered with a known response from the published luminances at three unknown exposures.
  const ResponseCurve truth(GgcmModel{{0.42, 0.08, -0.05, 0.02, 0.0}});  // a camera-like convex φ
  const std::vector<double> exposures{0.35, 0.7, 1.05};
  std::vector<ChartShot> shots;
  for (double e : exposures) {
    std::vector<std::array<double, 3>> rgb(chart::kPatches);
    for (int p = 0; p < chart::kPatches; ++p) {
      const double v = truth.forward(std::min(1.0, e * chart::reference()[static_cast<size_t>(p)].Y));
      rgb[static_cast<size_t>(p)] = {v, v, v};
    }
    ChartShot shot;
    shot.name = "e" + std::to_string(e);
    shot.measured = chart::sampleRectified(syntheticChart(rgb));
    shots.push_back(std::move(shot));
  }
  ChartCalibrationOptions options;
  options.reference = chart::ReferenceSet::Luminance;
  options.channels = {1};
  const ChartCalibrationResult result = calibrateChart(shots, options);
  const auto& g = result.channels.front();
  ASSERT_EQ(g.fit.scales.size(), 3u);
  // y = s·φ(x) with y = Y and φ(x) = e·Y ⇒ s_g = 1/e_g: ratios recovered.
  for (size_t i = 1; i < 3; ++i)
    EXPECT_NEAR(g.fit.scales[0] / g.fit.scales[i], exposures[i] / exposures[0], 0.03 * exposures[i] / exposures[0]);
  EXPECT_LT(curveRmse(truth.sample(kCurveSamples), g.fit.inverse), 0.01);
  EXPECT_LT(g.fit.rmse, 0.005);
}

// A chart shot through a camera with a colour matrix: channel c of patch p sees t·(M·linear sRGB_p)_c (the greys:
// t·Y_p·w_c, w the white balance), then the curve, 8 bits, noise σ = 0.5 code. What --reference all assumes.
std::vector<ChartShot> colourMatrixShots(const ResponseCurve& curve, const std::vector<double>& exposures,
                                         const std::vector<int>& scenes) {
  const double M[3][3] = {{1.55, -0.40, -0.15}, {-0.25, 1.45, -0.20}, {-0.05, -0.45, 1.50}};
  const double white_balance[2][3] = {{0.95, 1.0, 0.9}, {0.8, 1.0, 1.15}};  // per scene
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0, 0.5 / 255);
  std::vector<ChartShot> shots;
  for (size_t j = 0; j < exposures.size(); ++j) {
    std::vector<std::array<double, 3>> rgb(chart::kPatches);
    for (int p = 0; p < chart::kPatches; ++p) {
      const auto& ref = chart::reference()[static_cast<size_t>(p)];
      for (int c = 0; c < 3; ++c) {
        double e = ref.Y * white_balance[scenes[j]][c];
        if (!ref.neutral) {
          e = 0;
          for (int k = 0; k < 3; ++k) e += M[c][k] * ref.linear[static_cast<size_t>(k)];
          e *= white_balance[scenes[j]][c];
        }
        const double v = curve.forward(std::clamp(exposures[j] * e, 0.0, 1.0)) + noise(rng);
        rgb[static_cast<size_t>(p)][static_cast<size_t>(c)] = std::clamp(v, 0.0, 1.0);
      }
    }
    ChartShot shot;
    shot.name = "e" + std::to_string(j);
    shot.scene = scenes[j];
    shot.measured = chart::sampleRectified(syntheticChart(rgb));
    shots.push_back(std::move(shot));
  }
  return shots;
}

TEST(Chart, AllPatchesRecoverAKnownCurveThroughAColourMatrix) {
  // Two scenes (white balances) × 4 exposures one stop apart, given: every patch of every channel enters, the
  // coloured ones as unknown irradiances per scene. The curve must come back in every channel, with the colours as
  // data. (With the exposures unknown the fitted ratios are compressed on this chart, 8 → 4.9: docs/RESULTS.md#chart.)
  const ResponseCurve truth(GgcmModel{{0.42, 0.08, -0.05, 0.02, 0.0}});
  const std::vector<double> exposures{0.15, 0.3, 0.6, 1.2, 0.15, 0.3, 0.6, 1.2};
  std::vector<ChartShot> shots = colourMatrixShots(truth, exposures, {0, 0, 0, 0, 1, 1, 1, 1});
  for (size_t j = 0; j < shots.size(); ++j) shots[j].exposure = exposures[j];
  ChartCalibrationOptions options;
  options.reference = chart::ReferenceSet::AllPatches;
  const ChartCalibrationResult result = calibrateChart(shots, options);
  ASSERT_EQ(result.channels.size(), 3u);
  ASSERT_EQ(result.exposures.size(), shots.size());
  EXPECT_NEAR(result.exposures[3] / result.exposures[0], 8.0, 1e-9);
  const std::vector<double> exact = truth.sample(kCurveSamples);
  for (const auto& c : result.channels) {
    EXPECT_GT(c.fit.observations, 60) << channelName(c.channel);  // more than the greys' ≤ 48
    const auto [lo, hi] = c.fit.covered_range;
    EXPECT_LT(scaledRmse(exact, c.fit.inverse, lo, hi), 0.006) << channelName(c.channel) << " " << c.fit.summary();
    // The band (scaled_fit_band.hpp): refits on halves of the patches, around the curve.
    ASSERT_FALSE(c.band.empty()) << channelName(c.channel);
    EXPECT_GE(c.band.replicates, 6) << channelName(c.channel);
    for (int i = 0; i < kCurveSamples; i += 32) {
      EXPECT_LE(c.band.lower[static_cast<size_t>(i)], c.fit.inverse[static_cast<size_t>(i)] + 1e-12);
      EXPECT_GE(c.band.upper[static_cast<size_t>(i)], c.fit.inverse[static_cast<size_t>(i)] - 1e-12);
    }
  }
}

TEST(Chart, RawScalePerSceneAbsorbsTheLightsGain) {
  // RAW reference in common units, but the JPEG of the second light renders the RAW through 1.25× the gain of the
  // first (white balance): the grey patches of the two scenes lie on two scalings of one curve. One common RAW scale
  // must bend the curve to split the difference; one scale per scene recovers it.
  const ResponseCurve truth(GgcmModel{{0.42, 0.08, -0.05, 0.02, 0.0}});
  const double gain[2] = {1.0, 1.25};
  std::vector<ChartShot> shots;
  for (int scene = 0; scene < 2; ++scene)
    for (double t : {0.15, 0.3, 0.6, 1.2}) {
      std::vector<std::array<double, 3>> jpeg(chart::kPatches);
      cv::Mat raw(260, 390, CV_32FC3);
      for (int p = 0; p < chart::kPatches; ++p) {
        const double e = t * chart::reference()[static_cast<size_t>(p)].Y * 0.7;
        const double v = truth.forward(std::min(1.0, gain[scene] * e));
        jpeg[static_cast<size_t>(p)] = {v, v, v};
        raw(cv::Rect((p % 6) * 65, (p / 6) * 65, 65, 65)).setTo(cv::Scalar::all(std::min(1.0, e)));
      }
      ChartShot shot;
      shot.name = "s" + std::to_string(scene) + "t" + std::to_string(t);
      shot.scene = scene;
      shot.measured = chart::sampleRectified(syntheticChart(jpeg));
      shot.raw = chart::sampleRectified(raw);
      shots.push_back(std::move(shot));
    }
  ChartCalibrationOptions options;
  options.use_raw = true;
  options.raw_neutral_only = true;
  options.channels = {1};
  const std::vector<double> exact = truth.sample(kCurveSamples);
  const ChartCalibrationResult common = calibrateChart(shots, options);
  options.raw_scale_per_scene = true;
  const ChartCalibrationResult per_scene = calibrateChart(shots, options);
  const ScaledFitResult& a = common.channels.front().fit;
  const ScaledFitResult& b = per_scene.channels.front().fit;
  ASSERT_EQ(b.scales.size(), 2u);
  EXPECT_NEAR(b.scales[0] / b.scales[1], gain[1] / gain[0], 0.02);
  EXPECT_LT(b.rmse, 0.004) << b.summary();
  EXPECT_GT(a.rmse, 2 * b.rmse) << a.summary();
  const double shape_per_scene = scaledRmse(exact, b.inverse, b.covered_range.first, b.covered_range.second);
  const double shape_common = scaledRmse(exact, a.inverse, a.covered_range.first, a.covered_range.second);
  EXPECT_LT(shape_per_scene, 0.004);
  EXPECT_LT(shape_per_scene, shape_common);
}

TEST(Chart, CensoredSamplesBoundTheScale) {
  // Data only up to x = 0.6 on φ = x²; an upper bound s·φ(0.99) ≤ 1.0 at the clipped end keeps the scale honest.
  std::vector<ScaledObservation> obs;
  for (int i = 1; i <= 30; ++i) {
    const double x = 0.02 * i;
    obs.push_back({ScaledObservation::Kind::Exact, x, 2.0 * x * x, 0, i % 5, 1});
  }
  obs.push_back({ScaledObservation::Kind::AtMost, 0.99, 2.0, 0, 0, 1});
  obs.push_back({ScaledObservation::Kind::AtLeast, 0.99, 1.9, 0, 1, 1});
  const ScaledFitResult fit = fitScaledInverse(obs);
  EXPECT_EQ(fit.censored, 2);
  EXPECT_NEAR(fit.scales[0], 2.0, 0.15);
  EXPECT_LT(fit.rmse, 0.01);
}

TEST(Chart, RectifyWithCornersUndoesARotatedPerspective) {
  std::vector<std::array<double, 3>> rgb(chart::kPatches);
  for (int p = 0; p < chart::kPatches; ++p) rgb[static_cast<size_t>(p)] = {0.1 + 0.03 * p, 0.8 - 0.025 * p, 0.5};
  const cv::Mat flat = syntheticChart(rgb);
  // Place it upside down (rotated 180°) with some perspective into a larger photo.
  const chart::ChartCorners where{cv::Point2f(900, 640), cv::Point2f(120, 600), cv::Point2f(160, 90),
                                  cv::Point2f(880, 70)};
  const std::array<cv::Point2f, 4> from{cv::Point2f(0, 0), cv::Point2f(390, 0), cv::Point2f(390, 260),
                                        cv::Point2f(0, 260)};
  cv::Mat photo;
  cv::warpPerspective(flat, photo, cv::getPerspectiveTransform(from.data(), where.data()), cv::Size(1000, 700),
                      cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(20, 20, 20));
  const std::vector<chart::PatchStats> stats = chart::sampleRectified(chart::rectify(photo, where));
  for (const auto& s : stats) {
    EXPECT_TRUE(s.usable()) << s.patch;
    EXPECT_NEAR(s.median[0], rgb[static_cast<size_t>(s.patch)][0], 2.0 / 255) << s.patch;
    EXPECT_NEAR(s.median[1], rgb[static_cast<size_t>(s.patch)][1], 2.0 / 255) << s.patch;
  }
}

TEST(Chart, ParsesCornersAndRejectsBadInput) {
  const chart::ChartCorners c = io::parseCorners("1,2,3,4,5,6,7,8");
  EXPECT_FLOAT_EQ(c[2].x, 5);
  EXPECT_FLOAT_EQ(c[3].y, 8);
  EXPECT_THROW(io::parseCorners("1,2,3"), InvalidInput);
  EXPECT_THROW(io::parseCorners("1,2,3,4,5,6,7,x"), InvalidInput);
  EXPECT_THROW(chart::parseReferenceSet("xyz"), InvalidInput);
  std::vector<ScaledObservation> bad{{ScaledObservation::Kind::Exact, 0.5, -1, 0, 0, 1},
                                     {ScaledObservation::Kind::Exact, 0.6, 1, 0, 1, 1},
                                     {ScaledObservation::Kind::Exact, 0.7, 1, 0, 2, 1}};
  EXPECT_THROW(fitScaledInverse(bad), InvalidInput);
}

TEST(Chart, CommandWritesReportWithThreeChannelsAndGgcmModels) {
  test::TempDir dir;
  const fs::path cam = test::samples() / "middlebury" / kBundledCamera;
  std::string images, raws;
  for (const auto& shot : io::listMiddleburyShots(cam)) {
    images += " '" + shot.jpg.string() + "'";
    raws += " '" + shot.raw.string() + "'";
  }
  const auto truth = test::run(test::crfcalBinary().string() + " chart" + images + " --raw" + raws + " -q -o '" +
                               (dir / "truth").string() + "'");
  ASSERT_EQ(truth.exit_code, 0) << truth.output;
  const auto run = test::run(test::crfcalBinary().string() + " chart" + images + " -q --truth '" +
                             (dir / "truth" / "report.json").string() + "' -o '" + (dir / "out").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const io::CalibrationReport report = io::readReport(dir / "out" / "report.json");
  EXPECT_EQ(report.command, "chart");
  for (const char* ch : {"R", "G", "B"}) {
    ASSERT_TRUE(report.inverse_crf.count(ch)) << ch;
    EXPECT_EQ(report.inverse_crf.at(ch).size(), size_t(kCurveSamples));
    ASSERT_TRUE(report.models.count(ch));
    EXPECT_EQ(modelKind(report.models.at(ch)), "ggcm");
  }
  EXPECT_TRUE(fs::exists(dir / "out" / "chart_fit.png"));
  std::ifstream in(dir / "out" / "report.json");
  const nlohmann::json json = nlohmann::json::parse(in);
  EXPECT_FALSE(json.at("patch_residuals").empty());
  // --reference all (the default) writes a band per channel, as calibrate does.
  for (const char* ch : {"R", "G", "B"})
    EXPECT_EQ(json.at("inverse_crf_band").at(ch).at("upper").size(), size_t(kCurveSamples)) << ch;
  EXPECT_LT(json.at("truth").at("phi_error").at("G").at("rmse_covered_aligned").get<double>(), 0.02);
  // Errors are one line with the reason.
  const auto bad = test::run(test::crfcalBinary().string() + " chart" + images + " --raw '" +
                             (cam / "wb1i1e1-raw.png").string() + "' -o '" + (dir / "bad").string() + "'");
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  EXPECT_FALSE(fs::exists(dir / "bad"));
}

TEST(Chart, ExifExposuresGiveOneCommonScale) {
  // The four bundled JPEG shots with EXIF written into copies (ISO 100, f/4, t ∝ the exposure the RAW grey
  // patches show): the command reads the ratios, fits one scale instead of one per shot, and still agrees with
  // the RAW→JPEG truth.
  test::TempDir dir;
  const std::vector<ChartShot> shots = bundledShots(true);
  const auto listed = io::listMiddleburyShots(test::samples() / "middlebury" / kBundledCamera);
  ASSERT_EQ(listed.size(), shots.size());
  std::vector<double> exposure;
  for (const auto& shot : shots) {
    // Median ratio of the unclipped RAW grey patches (G) to the first shot's.
    std::vector<double> ratios;
    for (int p = 18; p < 24; ++p) {
      const auto& a = shots.front().raw[static_cast<size_t>(p)];
      const auto& b = shot.raw[static_cast<size_t>(p)];
      if (a.usable() && b.usable() && a.median[1] > 0.03 && b.median[1] > 0.03) ratios.push_back(b.median[1] / a.median[1]);
    }
    ASSERT_FALSE(ratios.empty());
    std::nth_element(ratios.begin(), ratios.begin() + ratios.size() / 2, ratios.end());
    exposure.push_back(ratios[ratios.size() / 2]);
  }
  std::string images;
  for (size_t i = 0; i < listed.size(); ++i) {
    const fs::path copy = dir / listed[i].jpg.filename();
    fs::copy_file(listed[i].jpg, copy);
    ExifExposure exif;
    exif.iso = 100;
    exif.exposure_time = exposure[i] / 100;
    exif.f_number = 4.0;
    io::writeExif(copy, exif);
    images += " '" + copy.string() + "'";
  }
  const auto run = test::run(test::crfcalBinary().string() + " chart" + images + " --reference neutral --channels G -q -o '" +
                             (dir / "out").string() + "'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_EQ(run.output.find("free exposure scale"), std::string::npos) << run.output;
  std::ifstream in(dir / "out" / "report.json");
  const nlohmann::json json = nlohmann::json::parse(in);
  const auto& inputs = json.at("chart").at("inputs");
  ASSERT_EQ(inputs.size(), listed.size());
  for (size_t i = 0; i < listed.size(); ++i)  // ISO·t/N² relative to the first shot (EXIF rationals round t)
    EXPECT_NEAR(inputs[i].at("exposure").get<double>() / inputs[0].at("exposure").get<double>(), exposure[i],
                0.01 * exposure[i]);
  EXPECT_EQ(json.at("chart").at("channels").at("G").at("scales").size(), 1u);

  ChartCalibrationOptions truth_options;
  truth_options.use_raw = true;
  truth_options.raw_neutral_only = true;
  truth_options.channels = {1};
  const ChartCalibrationResult truth = calibrateChart(shots, truth_options);
  const io::CalibrationReport report = io::readReport(dir / "out" / "report.json");
  const ChannelComparison e = compareCurves(truth.channels.front().fit.inverse, report.inverse_crf.at("G"),
                                            truth.channels.front().fit.covered_range, report.covered_range.at("G"));
  EXPECT_LT(e.rmse_covered_aligned, 0.015);
  EXPECT_LT(e.rmse, 0.04);
}

TEST(Chart, ExponentPenaltyKeepsTheUnobservedTopFromJumping) {
  // φ = x^1.6 observed only up to x ≈ 0.8 with one common scale (a RAW-like reference): without the
  // local-exponent penalty the EMoR fit may bend steeply above the data and rescale everything; with it the
  // continuation follows the exponent the data show. The data term alone cannot tell the two apart.
  const ResponseCurve truth(GammaModel{1.6});
  std::vector<ScaledObservation> obs;
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0, 0.002);
  for (int i = 1; i <= 40; ++i) {
    const double x = 0.02 * i;  // up to 0.8
    obs.push_back({ScaledObservation::Kind::Exact, x, 0.7 * (truth.inverse(x) + noise(rng)), 0, i % 8, 1});
  }
  ScaledFitOptions with;
  ScaledFitOptions without;
  without.exponent_smoothness = 0;
  const ScaledFitResult a = fitScaledInverse(obs, with);
  const ScaledFitResult b = fitScaledInverse(obs, without);
  const std::vector<double> exact = truth.sample(kCurveSamples);
  EXPECT_LT(curveRmse(exact, a.inverse), 0.01) << a.summary();  // without the penalty: 0.0196
  EXPECT_NEAR(a.scales[0], 0.7, 0.02);
  // Both fit the data equally well: the difference is only above x = 0.8.
  EXPECT_LT(a.rmse, 0.004);
  EXPECT_LT(b.rmse, 0.004);
  EXPECT_LE(curveRmse(exact, a.inverse), curveRmse(exact, b.inverse) + 1e-3) << b.summary();
}

TEST(Chart, CompiledReferenceMatchesTheBundledTable) {
  // chart::reference() is transcribed from samples/colorchecker/colorchecker_classic_reference.csv (see its
  // PROVENANCE.md): names, Y and the linear sRGB columns must agree with the file.
  std::ifstream in(test::samples() / "colorchecker" / "colorchecker_classic_reference.csv");
  ASSERT_TRUE(in) << "samples/colorchecker/colorchecker_classic_reference.csv missing";
  std::string line, header;
  while (std::getline(in, line) && !line.empty() && line[0] == '#') {
  }
  header = line;
  auto split = [](const std::string& text) {
    std::vector<std::string> fields;
    std::string field;
    bool quoted = false;
    for (char ch : text) {
      if (ch == '"') quoted = !quoted;
      else if (ch == ',' && !quoted) fields.push_back(field), field.clear();
      else field += ch;
    }
    fields.push_back(field);
    return fields;
  };
  const std::vector<std::string> columns = split(header);
  auto column = [&](const std::string& name) {
    const auto it = std::find(columns.begin(), columns.end(), name);
    EXPECT_NE(it, columns.end()) << name;
    return static_cast<size_t>(it - columns.begin());
  };
  const size_t name = column("name"), Y = column("Y_babel"), r = column("R_lin"), g = column("G_lin"), b = column("B_lin");
  int rows = 0;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    const std::vector<std::string> f = split(line);
    ASSERT_LT(rows, chart::kPatches);
    const chart::PatchReference& ref = chart::reference()[static_cast<size_t>(rows)];
    EXPECT_EQ(std::string(ref.name), f.at(name)) << rows;
    EXPECT_DOUBLE_EQ(ref.Y, std::stod(f.at(Y))) << ref.name;
    EXPECT_DOUBLE_EQ(ref.linear[0], std::stod(f.at(r))) << ref.name;
    EXPECT_DOUBLE_EQ(ref.linear[1], std::stod(f.at(g))) << ref.name;
    EXPECT_DOUBLE_EQ(ref.linear[2], std::stod(f.at(b))) << ref.name;
    EXPECT_EQ(ref.neutral, rows >= 18) << ref.name;
    ++rows;
  }
  EXPECT_EQ(rows, chart::kPatches);
}

TEST(Chart, DetectsTheChartInARealPhotoWithMcc) {
  const fs::path shared = test::sharedData();
  const fs::path photo = shared / "colorchecker" / "photos_mindvision" / "d65_colorchecker.jpg";
  if (shared.empty() || !fs::exists(photo)) GTEST_SKIP() << "../shared/data/colorchecker not available";
  const io::LoadedChart loaded = io::loadChart(photo, io::ChartLayout::Detect);
  EXPECT_EQ(loaded.how, "mcc");
  const std::vector<chart::PatchStats> stats = chart::sampleRectified(loaded.rectified);
  // Upside-down chart: mcc must still give chart order — the grey row decreases from white to black.
  for (int p = 19; p < 24; ++p)
    EXPECT_LT(stats[static_cast<size_t>(p)].median[1], stats[static_cast<size_t>(p) - 1].median[1]) << p;
  int usable = 0;
  for (const auto& s : stats) usable += s.usable();
  EXPECT_GE(usable, 20);
}

}  // namespace
}  // namespace crfcal

namespace crfcal {
namespace {

TEST(BenchReferences, RunsOnTheBundledCameraAndSkipsWithoutData) {
  // samples/ holds middlebury/CanonEOS1DsMarkII (one scene, 4 exposures): the whole table on one camera scene.
  test::TempDir dir;
  const std::string crfcal = test::crfcalBinary().string();
  const auto run = test::run(crfcal + " bench references -q --data " + test::samples().string() + " --json " +
                             (dir / "references.json").string());
  ASSERT_EQ(run.exit_code, 0) << run.output;
  std::ifstream in(dir / "references.json");
  const nlohmann::json json = nlohmann::json::parse(in);
  ASSERT_EQ(json["cases"].size(), 1u);
  for (const char* method : {"OpenCV Debevec", "OpenCV Robertson", "crfcal chart", "crfcal chart, exposures given",
                             "crfcal bracket"}) {
    ASSERT_TRUE(json["summary"].contains(method)) << method;
    // Robertson's response has NaN entries on these shots (counted as failed, as in bench bracket).
    if (std::string(method) != "OpenCV Robertson") {
      EXPECT_EQ(json["summary"][method]["failed"], 0) << method;
    }
  }
  for (const char* method : {"crfcal chart", "crfcal chart, exposures given"})
    EXPECT_LT(json["summary"][method]["rgb_mean"].get<double>(), 0.03) << method << "\n" << run.output;
  // One camera: it is the first in name order, so its scene is on the choosing side of the split.
  EXPECT_NEAR(json["summary"]["crfcal bracket"]["rgb_choose"].get<double>(),
              json["summary"]["crfcal bracket"]["rgb_mean"].get<double>(), 1e-12);
  const auto skipped = test::run(crfcal + " bench references -q --data " + (dir / "absent").string());
  EXPECT_EQ(skipped.exit_code, 0) << skipped.output;
  EXPECT_NE(skipped.output.find("skipped"), std::string::npos) << skipped.output;
}

}  // namespace
}  // namespace crfcal
