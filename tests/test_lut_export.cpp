// LUT export: every format is loaded back with the reader of the tool it is meant for (OpenColorIO for .cube,
// .spi1d and CLF; OpenCV FileStorage + MergeDebevec for the OpenCV response; a re-implementation of pfstools'
// responseLoad()/weightsLoad(); Hugin's EMoR evaluation from samples/emor/emor.txt) and the curve it applies is
// checked against φ (or ψ) within the format's precision.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <sstream>

#include <gtest/gtest.h>
#include <OpenColorIO/OpenColorIO.h>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/photo.hpp>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/lut_export.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/response_curve.hpp"
#include "test_support.hpp"

namespace OCIO = OCIO_NAMESPACE;

namespace crfcal::io {
namespace {

namespace fs = std::filesystem;

// Three different curves so that a channel swap is caught.
CalibrationReport rgbReport() {
  CalibrationReport report;
  report.command = "test";
  const ResponseModel r = GammaModel{1.8}, g = GammaModel{2.2}, b = GgcmModel{{0.38, 0.12, -0.04, 0.02, 0.01}};
  report.inverse_crf["R"] = sampleInverse(r);
  report.inverse_crf["G"] = sampleInverse(g);
  report.inverse_crf["B"] = sampleInverse(b);
  report.models["R"] = r;
  report.models["G"] = g;
  report.models["B"] = b;
  return report;
}

// A grey report whose curve is only known by its samples (no model).
CalibrationReport greyReport() {
  CalibrationReport report;
  report.command = "test";
  std::vector<double> phi(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) {
    const double x = double(i) / (kCurveSamples - 1);
    phi[static_cast<size_t>(i)] = 0.7 * std::pow(x, 2.4) + 0.3 * x * x;
  }
  report.inverse_crf["G"] = phi;
  return report;
}

double curveValue(const ResponseCurve& curve, LutDirection direction, double x) {
  return direction == LutDirection::Inverse ? curve.inverse(x) : curve.forward(x);
}

// The LUT's own piecewise-linear curve through its exact node values (what a reader computes, up to rounding).
double lutCurve(const ResponseCurve& curve, const LutExportOptions& o, int size, double x) {
  const double lo = o.range_min, hi = o.range_max;
  const double position = std::clamp((x - lo) / (hi - lo), 0.0, 1.0) * (size - 1);
  const int i = std::min(static_cast<int>(position), size - 2);
  const double t = position - i;
  const double a = curveValue(curve, o.direction, lo + (hi - lo) * i / (size - 1));
  const double b = curveValue(curve, o.direction, lo + (hi - lo) * (i + 1) / (size - 1));
  return a + t * (b - a);
}

// Applies a LUT file through an OpenColorIO FileTransform (linear interpolation, CPU processor).
std::vector<std::array<float, 3>> applyOcio(const fs::path& file, const std::vector<float>& xs) {
  OCIO::ConstConfigRcPtr config = OCIO::Config::CreateRaw();
  OCIO::FileTransformRcPtr transform = OCIO::FileTransform::Create();
  transform->setSrc(file.c_str());
  transform->setInterpolation(OCIO::INTERP_LINEAR);
  transform->setDirection(OCIO::TRANSFORM_DIR_FORWARD);
  OCIO::ConstProcessorRcPtr processor = config->getProcessor(transform);
  OCIO::ConstCPUProcessorRcPtr cpu = processor->getDefaultCPUProcessor();
  std::vector<std::array<float, 3>> out;
  for (float x : xs) {
    std::array<float, 3> rgb{x, x, x};
    cpu->applyRGB(rgb.data());
    out.push_back(rgb);
  }
  return out;
}

std::vector<float> probePoints(const LutExportOptions& o, int size) {
  std::vector<float> xs;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(o.range_min, o.range_max);
  for (int k = 0; k < 2000; ++k) xs.push_back(static_cast<float>(uniform(rng)));
  for (int i = 0; i < size; i += std::max(1, size / 97)) {  // nodes and mid-points
    const double x = o.range_min + (o.range_max - o.range_min) * i / (size - 1);
    xs.push_back(static_cast<float>(x));
    if (i + 1 < size) xs.push_back(static_cast<float>(x + 0.5 * (o.range_max - o.range_min) / (size - 1)));
  }
  xs.push_back(static_cast<float>(o.range_min));
  xs.push_back(static_cast<float>(o.range_max));
  return xs;
}

struct OcioCheck {
  double vs_lut = 0;    // max |OCIO − LUT's piecewise-linear curve|
  double vs_curve = 0;  // max |OCIO − exact curve|
};

// Writes `options` from `report`, applies the file with OCIO, compares with the LUT's curve and the exact one.
OcioCheck checkWithOcio(const CalibrationReport& report, const LutExportOptions& options, const fs::path& file,
                        LutExportResult* result_out = nullptr) {
  const LutExportResult result = exportLut(report, file, options);
  if (result_out) *result_out = result;
  const ExportCurves curves = exportCurves(report, options.channel);
  const std::vector<float> xs = probePoints(options, result.size);
  const auto applied = applyOcio(file, xs);
  OcioCheck check;
  for (size_t k = 0; k < xs.size(); ++k)
    for (size_t c = 0; c < 3; ++c) {
      const double x = static_cast<double>(xs[k]);
      check.vs_lut = std::max(check.vs_lut, std::abs(applied[k][c] - lutCurve(curves.rgb[c], options, result.size, x)));
      check.vs_curve = std::max(check.vs_curve, std::abs(applied[k][c] - curveValue(curves.rgb[c], options.direction, x)));
    }
  std::printf("%s (%d nodes): OCIO vs LUT nodes %.2e, OCIO vs curve %.2e, exporter's claim %.2e\n",
              file.filename().c_str(), result.size, check.vs_lut, check.vs_curve, result.max_error);
  return check;
}

// float reader (6e-8 for values ≤ 1) + %.9f (5e-10) + float arithmetic of the reader's interpolation
constexpr double kFloatLutTolerance = 2.5e-7;

TEST(LutExport, CubeThroughOpenColorIO) {
  test::TempDir dir;
  const CalibrationReport report = rgbReport();
  for (auto direction : {LutDirection::Inverse, LutDirection::Forward}) {
    LutExportOptions options;
    options.format = LutFormat::Cube;
    options.direction = direction;
    LutExportResult result;
    const auto check = checkWithOcio(report, options, dir / (direction == LutDirection::Inverse ? "phi.cube" : "psi.cube"), &result);
    EXPECT_EQ(result.size, 4096);
    EXPECT_LT(check.vs_lut, kFloatLutTolerance) << "direction " << int(direction);
    // The exported precision claim holds for what OCIO applies (plus float arithmetic).
    EXPECT_LT(check.vs_curve, result.max_error + kFloatLutTolerance) << "direction " << int(direction);
    if (direction == LutDirection::Inverse) {
      EXPECT_LT(result.max_error, 1e-6);
    }
  }
}

TEST(LutExport, CubeDomainRangeThroughOpenColorIO) {
  test::TempDir dir;
  LutExportOptions options;
  options.format = LutFormat::Cube;
  options.size = 1024;
  options.range_min = 0.1;
  options.range_max = 0.6;
  const fs::path file = dir / "range.cube";
  const auto check = checkWithOcio(rgbReport(), options, file);
  EXPECT_LT(check.vs_lut, kFloatLutTolerance);
  std::ifstream in(file);
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_NE(text.str().find("DOMAIN_MIN 0.100000000 0.100000000 0.100000000"), std::string::npos);
  EXPECT_NE(text.str().find("LUT_1D_SIZE 1024"), std::string::npos);
  // Outside the domain OCIO clamps to the end nodes.
  const ExportCurves curves = exportCurves(rgbReport());
  const auto outside = applyOcio(file, {0.02f, 0.9f});
  EXPECT_NEAR(outside[0][1], curves.rgb[1].inverse(0.1), 1e-6);
  EXPECT_NEAR(outside[1][1], curves.rgb[1].inverse(0.6), 1e-6);
}

// φ and ψ at the default size read back by OpenColorIO, then a table over a sub-range.
void expectBothDirectionsThroughOcio(LutFormat format, const test::TempDir& dir, const LutExportOptions& ranged) {
  const CalibrationReport report = rgbReport();
  const std::string extension = format == LutFormat::Spi1d ? ".spi1d" : ".clf";
  for (auto direction : {LutDirection::Inverse, LutDirection::Forward}) {
    LutExportOptions options;
    options.format = format;
    options.direction = direction;
    LutExportResult result;
    const auto check = checkWithOcio(report, options,
                                     dir / ((direction == LutDirection::Inverse ? "phi" : "psi") + extension), &result);
    EXPECT_LT(check.vs_lut, kFloatLutTolerance);
    EXPECT_LT(check.vs_curve, result.max_error + kFloatLutTolerance);
  }
  EXPECT_LT(checkWithOcio(report, ranged, dir / ("range" + extension)).vs_lut, kFloatLutTolerance);
}

TEST(LutExport, Spi1dThroughOpenColorIO) {
  test::TempDir dir;
  LutExportOptions ranged;
  ranged.format = LutFormat::Spi1d;
  ranged.size = 777;
  ranged.range_min = 0.25;
  ranged.range_max = 0.75;
  expectBothDirectionsThroughOcio(LutFormat::Spi1d, dir, ranged);
}

TEST(LutExport, ClfThroughOpenColorIO) {
  test::TempDir dir;
  LutExportOptions ranged;
  ranged.format = LutFormat::Clf;
  ranged.size = 512;
  ranged.range_min = 0.0;
  ranged.range_max = 0.5;
  ranged.title = "a <title> & \"quotes\"";
  expectBothDirectionsThroughOcio(LutFormat::Clf, dir, ranged);
}

TEST(LutExport, GreyReportIsReplicatedAndChannelOptionSelects) {
  test::TempDir dir;
  LutExportOptions options;
  options.format = LutFormat::Spi1d;
  const CalibrationReport grey = greyReport();
  const auto check = checkWithOcio(grey, options, dir / "grey.spi1d");
  EXPECT_LT(check.vs_lut, kFloatLutTolerance);
  const ExportCurves curves = exportCurves(grey);
  EXPECT_EQ(curves.source[0], "samples");
  EXPECT_EQ(curves.source_channel[2], "G");
  // --channel R on an RGB report: R everywhere.
  options.channel = "R";
  const auto applied = (exportLut(rgbReport(), dir / "r.spi1d", options), applyOcio(dir / "r.spi1d", {0.5f}));
  EXPECT_NEAR(applied[0][0], std::pow(0.5, 1.8), 1e-6);
  EXPECT_NEAR(applied[0][2], std::pow(0.5, 1.8), 1e-6);
}

TEST(LutExport, CsvRoundTrip) {
  test::TempDir dir;
  LutExportOptions options;
  options.format = LutFormat::Csv;
  options.direction = LutDirection::Forward;
  const LutExportResult result = exportLut(rgbReport(), dir / "psi.csv", options);
  std::ifstream in(dir / "psi.csv");
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "x,R,G,B");
  const ExportCurves curves = exportCurves(rgbReport());
  int rows = 0;
  double worst = 0;
  while (std::getline(in, line)) {
    double x = 0, r = 0, g = 0, b = 0;
    ASSERT_EQ(std::sscanf(line.c_str(), "%lf,%lf,%lf,%lf", &x, &r, &g, &b), 4) << line;
    EXPECT_NEAR(x, double(rows) / 1023, 1e-9);
    const double exact_x = double(rows) / 1023;
    worst = std::max({worst, std::abs(r - curves.rgb[0].forward(exact_x)), std::abs(g - curves.rgb[1].forward(exact_x)),
                      std::abs(b - curves.rgb[2].forward(exact_x))});
    ++rows;
  }
  EXPECT_EQ(rows, 1024);
  EXPECT_LT(worst, 1e-9);
  EXPECT_LT(result.rounding_error, 1e-9);
}

// The inverse csv that export writes ("x,R,G,B") is a curve table `table:` reads back, each channel by its column.
TEST(LutExport, InverseCsvReadsBackAsACurveTablePerChannel) {
  test::TempDir dir;
  LutExportOptions options;
  options.format = LutFormat::Csv;
  options.direction = LutDirection::Inverse;
  exportLut(rgbReport(), dir / "phi.csv", options);
  const CalibrationReport report = rgbReport();
  for (const std::string channel : {"R", "G", "B"}) {
    const std::vector<double> phi = readCurveTable(dir / "phi.csv", channel);
    ASSERT_EQ(phi.size(), report.inverse_crf.at(channel).size());
    double worst = 0;
    for (std::size_t i = 0; i < phi.size(); ++i) worst = std::max(worst, std::abs(phi[i] - report.inverse_crf.at(channel)[i]));
    EXPECT_LT(worst, 1e-8) << channel;
  }
  // a column the header does not name is refused with the file named
  try {
    readCurveTable(dir / "phi.csv", "Y");
    FAIL() << "no Y column";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("phi.csv"), std::string::npos) << e.what();
  }
}

TEST(LutExport, OpenCvResponseLoadsWithFileStorage) {
  test::TempDir dir;
  const CalibrationReport report = rgbReport();
  const ExportCurves curves = exportCurves(report);
  for (const char* name : {"response.yml", "response.xml", "response.json"}) {
    LutExportOptions options;
    options.format = LutFormat::OpenCv;
    exportLut(report, dir / name, options);
    cv::FileStorage storage((dir / name).string(), cv::FileStorage::READ);
    ASSERT_TRUE(storage.isOpened()) << name;
    cv::Mat response;
    storage["response"] >> response;
    ASSERT_EQ(response.type(), CV_32FC3) << name;
    ASSERT_EQ(response.rows, 256);
    ASSERT_EQ(response.cols, 1);
    EXPECT_EQ(static_cast<std::string>(storage["crfcal_channel_order"]), "BGR");
    for (int i = 1; i < 256; ++i) {
      const cv::Vec3f v = response.at<cv::Vec3f>(i);
      for (int c = 0; c < 3; ++c) {  // BGR: index 0 is B = rgb[2]
        const double expected = curves.rgb[static_cast<size_t>(2 - c)].inverse(i / 255.0);
        EXPECT_NEAR(v[c], expected, 1e-7 * std::max(1.0, expected)) << name << " i=" << i << " c=" << c;
      }
    }
    const cv::Vec3f zero = response.at<cv::Vec3f>(0), one = response.at<cv::Vec3f>(1);
    for (int c = 0; c < 3; ++c) EXPECT_GT(zero[c], 0.0f) << "log(response) must be finite";
    for (int c = 0; c < 3; ++c) EXPECT_FLOAT_EQ(zero[c], one[c]);
  }
}

// A synthetic bracket made with the same curves: MergeDebevec with the exported response must give an HDR image
// linear in the true irradiance (HDR/E constant), per channel — which also checks the BGR order.
TEST(LutExport, OpenCvResponseLinearisesMergeDebevec) {
  test::TempDir dir;
  const CalibrationReport report = rgbReport();
  const ExportCurves curves = exportCurves(report);
  LutExportOptions options;
  options.format = LutFormat::OpenCv;
  exportLut(report, dir / "response.yml", options);
  cv::Mat response;
  cv::FileStorage(std::string((dir / "response.yml").string()), cv::FileStorage::READ)["response"] >> response;

  // Irradiance: 64×64, log-spaced over 2.3 decades, a grey ramp tinted per channel. (MergeDebevec weighs a pixel
  // by the mean of its channels' weights, so channels must saturate together for the merge itself to be linear.)
  const int side = 64;
  cv::Mat irradiance(side, side, CV_64FC3);
  for (int y = 0; y < side; ++y)
    for (int x = 0; x < side; ++x) {
      const double t = double(y * side + x) / (side * side - 1);
      const double e = 0.004 * std::pow(225.0, t);
      irradiance.at<cv::Vec3d>(y, x) = {e, 0.85 * e, 0.7 * e};  // BGR
    }
  const std::vector<float> times = {0.25f, 1.0f, 4.0f};
  std::vector<cv::Mat> images;
  for (float dt : times) {
    cv::Mat image(side, side, CV_8UC3);
    for (int y = 0; y < side; ++y)
      for (int x = 0; x < side; ++x)
        for (int c = 0; c < 3; ++c) {
          const double e = std::min(1.0, irradiance.at<cv::Vec3d>(y, x)[c] * dt);
          const double v = curves.rgb[static_cast<size_t>(2 - c)].forward(e);
          image.at<cv::Vec3b>(y, x)[c] = cv::saturate_cast<uchar>(std::lround(255.0 * v));
        }
    images.push_back(image);
  }
  auto linearity = [&](const cv::Mat& resp) {
    cv::Mat hdr;
    cv::createMergeDebevec()->process(images, hdr, times, resp);
    // Relative deviation of HDR/E from its median, per channel; 95th percentile over the pixels bright enough
    // (E ≥ 0.03) that 8-bit quantisation of the darkest exposures does not dominate.
    std::vector<double> worst;
    for (int c = 0; c < 3; ++c) {
      std::vector<double> ratio;
      for (int y = 0; y < side; ++y)
        for (int x = 0; x < side; ++x)
          if (irradiance.at<cv::Vec3d>(y, x)[c] >= 0.03)
            ratio.push_back(hdr.at<cv::Vec3f>(y, x)[c] / irradiance.at<cv::Vec3d>(y, x)[c]);
      std::vector<double> sorted = ratio;
      std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
      const double median = sorted[sorted.size() / 2];
      std::vector<double> deviation;
      for (double r : ratio) deviation.push_back(std::abs(r / median - 1));
      std::sort(deviation.begin(), deviation.end());
      worst.push_back(deviation[deviation.size() * 95 / 100]);
      EXPECT_NEAR(median, 1.0, 0.02) << "channel " << c;  // φ(1) = 1: absolute scale is kept
    }
    return *std::max_element(worst.begin(), worst.end());
  };
  const double exported = linearity(response);
  std::printf("MergeDebevec with the exported response: 95th percentile |HDR/E / median - 1| = %.4f\n", exported);
  EXPECT_LT(exported, 0.02);
  ::testing::Test::RecordProperty("merge_debevec_p95_deviation", std::to_string(exported));
  // Control: the same table with R and B swapped (RGB instead of BGR) is far from linear.
  cv::Mat swapped = response.clone();
  for (int i = 0; i < 256; ++i) std::swap(swapped.at<cv::Vec3f>(i)[0], swapped.at<cv::Vec3f>(i)[2]);
  cv::Mat hdr;
  cv::createMergeDebevec()->process(images, hdr, times, swapped);
  double wrong = 0;
  for (int y = 0; y < side; ++y)
    for (int x = 0; x < side; ++x)
      for (int c = 0; c < 3; ++c)
        wrong = std::max(wrong, std::abs(std::log(hdr.at<cv::Vec3f>(y, x)[c] / irradiance.at<cv::Vec3d>(y, x)[c])));
  std::printf("same table with R and B swapped: max |log(HDR/E)| = %.3f\n", wrong);
  EXPECT_GT(wrong, 10 * exported);
}

// ---- pfstools: a reader that follows responseLoad()/weightsLoad() of pfstools' src/camera/responses.cpp ----
bool pfsResponseLoad(FILE* file, std::vector<float>& response, int levels) {
  char line[1024];
  int rows = 0, columns = 0;
  while (std::fgets(line, sizeof line, file))
    if (std::sscanf(line, "# rows: %d\n", &rows) == 1) break;
  if (rows != levels) return false;
  while (std::fgets(line, sizeof line, file))
    if (std::sscanf(line, "# columns: %d\n", &columns) == 1) break;
  if (columns != 3) return false;
  response.assign(static_cast<size_t>(levels), 0.0f);
  for (int i = 0; i < levels; ++i) {
    float ignore = 0, value = 0;
    int m = 0;
    if (std::fscanf(file, " %f %d %f\n", &ignore, &m, &value) != 3) return false;
    if (m < 0 || m >= levels) return false;
    response[static_cast<size_t>(m)] = value;
  }
  return true;
}

bool pfsWeightsLoad(FILE* file, std::vector<float>& weights, int levels) {
  char line[1024];
  int rows = 0, columns = 0;
  while (std::fgets(line, sizeof line, file))
    if (std::sscanf(line, "# rows: %d\n", &rows) == 1) break;
  if (rows != levels) return false;
  while (std::fgets(line, sizeof line, file))
    if (std::sscanf(line, "# columns: %d\n", &columns) == 1) break;
  if (columns != 2) return false;
  weights.assign(static_cast<size_t>(levels), 0.0f);
  for (int i = 0; i < levels; ++i) {
    int m = 0;
    if (std::fscanf(file, " %f %d\n", &weights[static_cast<size_t>(i)], &m) != 2) return false;
  }
  return true;
}

TEST(LutExport, PfstoolsResponseFileReadsLikePfshdrcalibrate) {
  test::TempDir dir;
  const CalibrationReport report = rgbReport();
  const ExportCurves curves = exportCurves(report);
  for (int levels : {256, 4096}) {
    LutExportOptions options;
    options.format = LutFormat::Pfstools;
    options.size = levels;
    const fs::path path = dir / ("response" + std::to_string(levels) + ".m");
    const LutExportResult result = exportLut(report, path, options);
    EXPECT_LT(result.rounding_error, 5e-7);
    // RGB mode of pfshdrcalibrate --response-file: IR, IG, IB, then W.
    FILE* file = std::fopen(path.c_str(), "r");
    ASSERT_NE(file, nullptr);
    std::array<std::vector<float>, 3> rgb;
    std::vector<float> weights;
    EXPECT_TRUE(pfsResponseLoad(file, rgb[0], levels));
    EXPECT_TRUE(pfsResponseLoad(file, rgb[1], levels));
    EXPECT_TRUE(pfsResponseLoad(file, rgb[2], levels));
    EXPECT_TRUE(pfsWeightsLoad(file, weights, levels));
    std::fclose(file);
    double worst = 0;
    for (size_t c = 0; c < 3; ++c)
      for (int m = 0; m < levels; ++m)
        worst = std::max(worst, std::abs(rgb[c][static_cast<size_t>(m)] - curves.rgb[c].inverse(double(m) / (levels - 1))));
    EXPECT_LT(worst, 5e-7) << levels;  // %e: 7 significant digits, φ ≤ 1
    EXPECT_GT(*std::min_element(weights.begin(), weights.end()), 0.0f);
    EXPECT_FLOAT_EQ(weights[static_cast<size_t>(levels / 2)], 1.0f - 1.0f / float(levels - 1));
    // A different M (pfshdrcalibrate --bpp) is refused by the reader, as in pfstools.
    file = std::fopen(path.c_str(), "r");
    std::vector<float> other;
    EXPECT_FALSE(pfsResponseLoad(file, other, levels * 2));
    std::fclose(file);
  }
  // --channel: one luminance curve "IY" + W (pfshdrcalibrate --luminance).
  LutExportOptions options;
  options.format = LutFormat::Pfstools;
  options.channel = "G";
  exportLut(report, dir / "luminance.m", options);
  FILE* file = std::fopen((dir / "luminance.m").c_str(), "r");
  ASSERT_NE(file, nullptr);
  std::vector<float> y, w;
  EXPECT_TRUE(pfsResponseLoad(file, y, 256));
  EXPECT_TRUE(pfsWeightsLoad(file, w, 256));
  std::fclose(file);
  EXPECT_NEAR(y[128], std::pow(128 / 255.0, 2.2), 5e-7);
}

// ---- Hugin: Ra..Re re-evaluated with the EMoR tables read from emor.txt (what Hugin compiles in) ----
std::map<std::string, std::vector<double>> readEmorTxt(const fs::path& path) {
  std::ifstream in(path);
  std::map<std::string, std::vector<double>> tables;
  std::string token, current;
  while (in >> token) {
    if (token == "=") continue;
    const auto eq = token.find('=');
    if (std::isalpha(static_cast<unsigned char>(token[0]))) {
      current = token.substr(0, eq);
      continue;
    }
    tables[current].push_back(std::stod(token));
  }
  return tables;
}

std::vector<double> parseHuginLine(const fs::path& path) {
  std::ifstream in(path);
  std::string line, last;
  while (std::getline(in, line))
    if (!line.empty() && line[0] != '#') last = line;
  std::vector<double> c(5);
  EXPECT_EQ(std::sscanf(last.c_str(), "Ra%lf Rb%lf Rc%lf Rd%lf Re%lf", &c[0], &c[1], &c[2], &c[3], &c[4]), 5) << last;
  return c;
}

TEST(LutExport, HuginEmorCoefficientsReproducePsi) {
  const auto tables = readEmorTxt(test::samples() / "emor" / "emor.txt");
  ASSERT_EQ(tables.at("f0").size(), 1024u);
  ASSERT_EQ(tables.at("h(5)").size(), 1024u);
  test::TempDir dir;

  auto evaluate = [&](const std::vector<double>& c) {
    std::vector<double> psi(tables.at("f0"));
    for (size_t k = 0; k < 5; ++k)
      for (size_t i = 0; i < psi.size(); ++i) psi[i] += c[k] * tables.at("h(" + std::to_string(k + 1) + ")")[i];
    return psi;
  };

  // 1. A camera whose ψ is exactly EMoR-5: the coefficients are recovered (checks basis, order and sign).
  const std::vector<double> truth = {-0.9, 0.35, -0.12, 0.05, 0.02};
  const std::vector<double> psi = evaluate(truth);
  ASSERT_TRUE(std::is_sorted(psi.begin(), psi.end()));
  const ResponseCurve psi_as_curve = ResponseCurve::fromSamples(psi);  // its ψ is our φ
  CalibrationReport report;
  std::vector<double> phi(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) phi[static_cast<size_t>(i)] = psi_as_curve.forward(double(i) / (kCurveSamples - 1));
  report.inverse_crf["G"] = phi;
  LutExportOptions options;
  options.format = LutFormat::Hugin;
  options.direction = LutDirection::Forward;
  const LutExportResult exact = exportLut(report, dir / "exact.pto", options);
  const std::vector<double> c = parseHuginLine(dir / "exact.pto");
  for (size_t k = 0; k < 5; ++k) EXPECT_NEAR(c[k], truth[k], 2e-3) << "coefficient " << k;
  EXPECT_LT(exact.max_error, 2e-4);

  // 2. A gamma camera: re-evaluating f0 + Σ c_k h_k reproduces ψ within the reported EMoR-5 error.
  const CalibrationReport rgb = rgbReport();
  const LutExportResult result = exportLut(rgb, dir / "gamma.pto", options);
  const std::vector<double> fitted = evaluate(parseHuginLine(dir / "gamma.pto"));
  const ExportCurves curves = exportCurves(rgb, "G");
  double sum = 0, worst = 0;
  for (int i = 0; i < 1024; ++i) {
    const double e = fitted[static_cast<size_t>(i)] - curves.rgb[1].forward(i / 1023.0);
    sum += e * e;
    worst = std::max(worst, std::abs(e));
  }
  EXPECT_NEAR(std::sqrt(sum / 1024), result.emor_rmse, 1e-6);
  EXPECT_LE(worst, result.max_error + 1e-6);
  EXPECT_LT(result.emor_rmse, 5e-3);  // ψ = x^(1/2.2): infinite slope at 0 is the hard part for EMoR-5
  EXPECT_EQ(result.hugin_coefficients.size(), 5u);
}

TEST(LutExport, OptionsAreChecked) {
  LutExportOptions options;
  options.format = LutFormat::OpenCv;
  options.size = 512;
  EXPECT_THROW(options.check(), InvalidInput);
  options.size = 256;
  options.direction = LutDirection::Forward;
  EXPECT_THROW(options.check(), InvalidInput);
  options = {};
  options.format = LutFormat::Pfstools;
  options.size = 300;
  EXPECT_THROW(options.check(), InvalidInput);
  options = {};
  options.format = LutFormat::Hugin;
  EXPECT_THROW(options.check(), InvalidInput);  // inverse requested: hugin holds ψ
  options = {};
  options.range_min = 0.5;
  options.range_max = 0.5;
  EXPECT_THROW(options.check(), InvalidInput);
  options = {};
  options.format = LutFormat::OpenCv;
  options.range_max = 0.5;
  EXPECT_THROW(options.check(), InvalidInput);
  EXPECT_THROW(parseLutFormat("tiff"), InvalidInput);
  EXPECT_EQ(parseLutFormat("CUBE"), LutFormat::Cube);
  EXPECT_EQ(lutFormatFromExtension("a/b.spi1d"), LutFormat::Spi1d);
  EXPECT_THROW(exportCurves(rgbReport(), "Y"), InvalidInput);
}

TEST(LutExport, WritesAreAtomic) {
  test::TempDir dir;
  const fs::path file = dir / "keep.cube";
  { std::ofstream(file) << "previous\n"; }
  // A curve that is not monotone fails before anything is written; the old file stays.
  CalibrationReport bad;
  bad.inverse_crf["G"] = {0.0, 0.8, 0.3, 1.0};
  LutExportOptions options;
  EXPECT_THROW(exportLut(bad, file, options), InvalidInput);
  std::ifstream in(file);
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "previous");
  // Into a missing directory: an Error naming the file.
  try {
    exportLut(rgbReport(), dir / "missing" / "x.cube", options);
    ADD_FAILURE() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("x.cube"), std::string::npos);
  }
  exportLut(rgbReport(), file, options);
  int entries = 0;
  for ([[maybe_unused]] const auto& entry : fs::directory_iterator(dir.path())) ++entries;
  EXPECT_EQ(entries, 1);  // no temporary left behind
}

TEST(LutExport, CommandLineWritesEveryFormat) {
  test::TempDir dir;
  writeReport(dir / "report.json", rgbReport());
  const std::string binary = test::crfcalBinary().string();
  const std::string report = (dir / "report.json").string();
  for (const char* spec : {"csv:out.csv", "opencv:out.yml", "cube:out.cube", "spi1d:out.spi1d", "clf:out.clf",
                           "pfstools:out.m", "hugin:out.pto"}) {
    const std::string s(spec);
    const std::string format = s.substr(0, s.find(':')), name = s.substr(s.find(':') + 1);
    const auto result = test::run(binary + " export " + report + " --format " + format + " -o " + (dir / name).string());
    EXPECT_EQ(result.exit_code, 0) << format << ": " << result.output;
    EXPECT_TRUE(fs::exists(dir / name)) << format;
  }
  // --range / --direction / --size reach the file; the format can come from the extension.
  auto result = test::run(binary + " export " + report + " --direction forward --size 64 --range 0.2,0.4 -o " +
                          (dir / "psi.spi1d").string());
  EXPECT_EQ(result.exit_code, 0) << result.output;
  std::ifstream in(dir / "psi.spi1d");
  std::stringstream text;
  text << in.rdbuf();
  EXPECT_NE(text.str().find("From 0.200000000 0.400000000"), std::string::npos);
  EXPECT_NE(text.str().find("Length 64"), std::string::npos);
  // One-line errors, exit 1.
  result = test::run(binary + " export " + (dir / "nope.json").string() + " -f cube -o " + (dir / "x.cube").string());
  EXPECT_EQ(result.exit_code, 1);
  EXPECT_NE(result.output.find("nope.json: file not found"), std::string::npos) << result.output;
  EXPECT_EQ(std::count(result.output.begin(), result.output.end(), '\n'), 1) << result.output;
  result = test::run(binary + " export " + report + " -f opencv --size 100 -o " + (dir / "x.yml").string());
  EXPECT_EQ(result.exit_code, 1) << result.output;
  EXPECT_FALSE(fs::exists(dir / "x.yml"));
}

// ---- the real programs, when installed (Debian: pfstools, hugin-tools); skipped otherwise ----

bool installed(const std::string& program) { return test::run("command -v " + program + " >/dev/null 2>&1").exit_code == 0; }

TEST(LutExport, PfstoolsFileLinearisesRealPfshdrcalibrate) {
  for (const char* tool : {"pfsinhdrgen", "pfshdrcalibrate", "pfsoutpfm"})
    if (!installed(tool)) GTEST_SKIP() << tool << " not installed (Debian package pfstools)";
  // A 3-exposure bracket (t = 1/4, 1, 4) of a log ramp rendered with the three different ψ of rgbReport();
  // pfshdrcalibrate merges it with the exported response: HDR ∝ E in each channel, the same factor in all three.
  test::TempDir dir;
  const CalibrationReport report = rgbReport();
  const ExportCurves curves = exportCurves(report);
  LutExportOptions options;
  options.format = LutFormat::Pfstools;
  exportLut(report, dir / "response.m", options);
  const int width = 512;
  std::vector<double> irradiance(width);
  for (int i = 0; i < width; ++i) irradiance[static_cast<size_t>(i)] = std::pow(10.0, -2.5 + 2.8 * i / (width - 1));
  std::ofstream script(dir / "bracket.hdrgen");
  const double times[3] = {0.25, 1.0, 4.0};
  for (int k = 0; k < 3; ++k) {
    cv::Mat image(8, width, CV_8UC3);
    for (int y = 0; y < image.rows; ++y)
      for (int x = 0; x < width; ++x)
        for (int c = 0; c < 3; ++c)  // BGR in memory
          image.at<cv::Vec3b>(y, x)[2 - c] = cv::saturate_cast<uchar>(
              std::lround(255 * curves.rgb[static_cast<size_t>(c)].forward(std::min(1.0, irradiance[static_cast<size_t>(x)] * times[k]))));
    const fs::path file = dir / ("b" + std::to_string(k) + ".ppm");
    ASSERT_TRUE(cv::imwrite(file.string(), image));
    script << file.string() << " " << 1 / times[k] << " 1 100 0\n";  // <file> <1/t> <N> <ISO> 0
  }
  script.close();
  const auto result = test::run("cd '" + dir.path().string() + "' && pfsinhdrgen bracket.hdrgen | pfshdrcalibrate " +
                                "--response-file response.m | pfsoutpfm hdr.pfm");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const cv::Mat hdr = cv::imread((dir / "hdr.pfm").string(), cv::IMREAD_UNCHANGED);
  ASSERT_EQ(hdr.type(), CV_32FC3);
  std::array<std::vector<double>, 3> ratio;  // HDR / E per channel, where some exposure is well exposed
  for (int x = 0; x < width; ++x) {
    const double e = irradiance[static_cast<size_t>(x)];
    if (e < 0.03 || e > 1.2) continue;  // below, even the longest exposure is < 50 codes in R (quantisation)
    const cv::Vec3f v = hdr.at<cv::Vec3f>(4, x);
    for (int c = 0; c < 3; ++c) ratio[static_cast<size_t>(c)].push_back(v[2 - c] / e);
  }
  std::array<double, 3> median{};
  for (size_t c = 0; c < 3; ++c) {
    auto sorted = ratio[c];
    std::sort(sorted.begin(), sorted.end());
    median[c] = sorted[sorted.size() / 2];
    std::vector<double> deviation;
    for (double r : ratio[c]) deviation.push_back(std::abs(r / median[c] - 1));
    std::sort(deviation.begin(), deviation.end());
    EXPECT_LT(deviation[deviation.size() * 95 / 100], 0.03) << "channel " << c;  // 8-bit quantisation dominates
  }
  // One factor for all channels: a swapped or wrong curve would tint the merge.
  EXPECT_NEAR(median[0] / median[1], 1.0, 0.02);
  EXPECT_NEAR(median[2] / median[1], 1.0, 0.02);
}

TEST(LutExport, HuginCoefficientsLineariseRealNona) {
  if (!installed("nona")) GTEST_SKIP() << "nona not installed (Debian package hugin-tools)";
  // A 0..255 ramp remapped by Hugin's nona in HDR mode: each output pixel is Hugin's inverse of the EMoR response
  // given by the exported Ra..Re, i.e. φ within the EMoR-5 representation error.
  test::TempDir dir;
  const CalibrationReport report = rgbReport();
  LutExportOptions options;
  options.format = LutFormat::Hugin;
  options.direction = LutDirection::Forward;
  const LutExportResult exported = exportLut(report, dir / "camera.pto", options);
  std::ifstream in(dir / "camera.pto");
  std::string line, fragment;
  while (std::getline(in, line))
    if (!line.empty() && line[0] == 'R') fragment = line;
  ASSERT_FALSE(fragment.empty());
  cv::Mat ramp(8, 256, CV_8UC3);
  for (int x = 0; x < 256; ++x) ramp.col(x).setTo(cv::Scalar(x, x, x));
  ASSERT_TRUE(cv::imwrite((dir / "ramp.png").string(), ramp));
  std::ofstream pto(dir / "project.pto");
  pto << "p f0 w256 h8 v10 E0 R0 n\"TIFF_m c:NONE\"\nm i0\n"
      << "i w256 h8 f0 v10 Rt0 " << fragment
      << " Eev0 Er1 Eb1 r0 p0 y0 TrX0 TrY0 TrZ0 j0 a0 b0 c0 d0 e0 g0 t0 Va1 Vb0 Vc0 Vd0 Vx0 Vy0 Vm0 n\"ramp.png\"\n";
  pto.close();
  const auto result =
      test::run("cd '" + dir.path().string() + "' && nona -r hdr -m TIFF_m -p FLOAT -o linear project.pto");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const cv::Mat linear = cv::imread((dir / "linear0000.tif").string(), cv::IMREAD_UNCHANGED);
  ASSERT_FALSE(linear.empty()) << result.output;
  ASSERT_EQ(linear.depth(), CV_32F);
  // φ of Hugin's own curve (f0 + Σ c_k h_k, inverted) and of the true curve (G = gamma 2.2).
  const std::vector<double> psi = emor::evaluateForward(exported.hugin_coefficients);
  const ResponseCurve hugin_curve = ResponseCurve::fromSamples([&] {
    std::vector<double> phi(kCurveSamples);  // invert the monotone ψ table
    size_t j = 0;
    for (int i = 0; i < kCurveSamples; ++i) {
      const double x = double(i) / (kCurveSamples - 1);
      while (j + 2 < psi.size() && psi[j + 1] < x) ++j;
      const double t = psi[j + 1] > psi[j] ? std::clamp((x - psi[j]) / (psi[j + 1] - psi[j]), 0.0, 1.0) : 0.0;
      phi[static_cast<size_t>(i)] = (double(j) + t) / (psi.size() - 1);
    }
    phi.front() = 0;
    phi.back() = 1;
    return phi;
  }());
  double to_hugin = 0, to_truth = 0;
  for (int x = 1; x < 256; ++x) {
    const float* v = linear.ptr<float>(4) + x * linear.channels();
    to_hugin = std::max(to_hugin, std::abs(double(v[1]) - hugin_curve.inverse(x / 255.0)));
    to_truth = std::max(to_truth, std::abs(double(v[1]) - std::pow(x / 255.0, 2.2)));
  }
  EXPECT_LT(to_hugin, 3e-3);  // nona applies exactly the curve the coefficients describe
  EXPECT_LT(to_truth, 0.03);  // … which is φ up to the EMoR-5 error of ψ (worst near 0)
}

}  // namespace
}  // namespace crfcal::io
