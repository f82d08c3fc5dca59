// crfcal bench chart: accuracy of the ColorChecker calibration (`crfcal chart`) against known curves.
//  1. Synthetic: the six grey patches rendered through known inverse responses (gamma 1.6–2.8, sRGB, film
//     shoulders, an S-curve, GGCM, EMoR) at four exposures one stop apart, 8-bit with noise, plus a linear
//     "RAW" rendering of the same shots; fitted from the grey reflectances (free exposure per shot) and from the
//     RAW reference (one scale), for each weight of the local-exponent penalty (ScaledFitOptions::
//     exponent_smoothness). Nothing here comes from ../shared: this is what chooses the default weight.
//  2. With the Middlebury data (--data, $CRFCAL_SHARED_DATA or ../shared/data; skipped when absent): the ten
//     cameras' JPEG chart shots calibrated from the reflectances vs the RAW→JPEG truth — the evidence table of
//     docs/RESULTS.md#chart, the same numbers as `crfcal chart … --truth`.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "bench_command.hpp"
#include "crfcal/chart_calibration.hpp"
#include "crfcal/colorchecker.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/chart_io.hpp"
#include "crfcal/io/datasets.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct ChartBenchArgs {
  int seeds = 4;
  std::vector<double> weights{0.0, 1e-4, 1e-3};
  std::vector<std::string> references{"neutral", "all"};  // chart::ReferenceSet names compared on the cameras
  bool per_scene = true;
  double colour_outlier_factor = ChartCalibrationOptions{}.colour_outlier_factor;  // --reference all
  double grey_weight = ChartCalibrationOptions{}.grey_weight;                      // --reference all   // also each scene's 4 shots alone (besides all 8 shots of a camera in one call)
  double noise = 1.0;      // σ of the JPEG renderings in 8-bit codes (RAW: 0.7 codes)
  std::string data;        // shared data root (Middlebury part)
  bool synthetic = true;
  bool middlebury = true;
  bool per_curve = false;
  std::string json;
  bool quiet = false;
  bool force = false;  // --json/-o over files crfcal did not write (never deletes them)
};

struct KnownCurve {
  std::string name;
  ResponseCurve curve;
};

// φ of a curve given as its forward ψ (monotone, ψ(0) = 0, ψ(1) = 1), by inverting a fine table.
ResponseCurve fromForward(double (*psi)(double)) {
  constexpr int kFine = 1 << 16;
  std::vector<double> e(kFine + 1), v(kFine + 1);
  for (int i = 0; i <= kFine; ++i) {
    e[static_cast<size_t>(i)] = double(i) / kFine;
    v[static_cast<size_t>(i)] = psi(e[static_cast<size_t>(i)]);
  }
  std::vector<double> phi(4097);
  size_t j = 0;
  for (size_t i = 0; i < phi.size(); ++i) {
    const double x = double(i) / double(phi.size() - 1);
    while (j + 1 < v.size() && v[j + 1] < x) ++j;
    const size_t k = std::min(j + 1, v.size() - 1);
    const double t = v[k] > v[j] ? std::clamp((x - v[j]) / (v[k] - v[j]), 0.0, 1.0) : 0.0;
    phi[i] = e[j] + t * (e[k] - e[j]);
  }
  phi.front() = 0;
  phi.back() = 1;
  return ResponseCurve::fromSamples(phi);
}

std::vector<KnownCurve> knownCurves() {
  std::vector<KnownCurve> curves;
  for (double g : {1.6, 2.2, 2.8}) {
    char name[32];
    std::snprintf(name, sizeof name, "gamma %.1f", g);
    curves.push_back({name, ResponseCurve(GammaModel{g})});
  }
  curves.push_back({"sRGB", fromForward([](double e) {
                      return e <= 0.0031308 ? 12.92 * e : 1.055 * std::pow(e, 1 / 2.4) - 0.055;
                    })});
  // Film-like shoulders: ψ(E) = (1 − e^{−kE}) / (1 − e^{−k}): the local exponent of φ grows towards x = 1.
  curves.push_back({"film k=3", fromForward([](double e) { return (1 - std::exp(-3 * e)) / (1 - std::exp(-3.0)); })});
  curves.push_back({"film k=6", fromForward([](double e) { return (1 - std::exp(-6 * e)) / (1 - std::exp(-6.0)); })});
  // Contrast S-curve on a gamma-0.45 encoding (toe and shoulder).
  curves.push_back({"S-curve", fromForward([](double e) {
                      return 0.5 + 0.5 * std::tanh(3 * (std::pow(e, 0.45) - 0.5)) / std::tanh(1.5);
                    })});
  curves.push_back({"GGCM a", ResponseCurve(GgcmModel{{0.45, 0.1, -0.05, 0.02, 0.01}})});
  curves.push_back({"GGCM b", ResponseCurve(GgcmModel{{0.38, 0.12, -0.04, 0.02, 0.01}})});
  curves.push_back({"EMoR g0", ResponseCurve(EmorModel{{}})});
  curves.push_back({"EMoR +h1", ResponseCurve(EmorModel{{1.0}})});
  curves.push_back({"EMoR mix", ResponseCurve(EmorModel{{-0.5, 0.4, -0.2}})});
  return curves;
}

// A rectified 390×260 chart (BGR, 8 bit) whose patch p shows value(p) in every channel, plus Gaussian noise.
cv::Mat renderChart(const std::function<double(int)>& value, double sigma, std::mt19937& rng) {
  std::normal_distribution<double> noise(0, sigma);
  cv::Mat chart(chart::kRows * 65, chart::kColumns * 65, CV_8UC3);
  for (int y = 0; y < chart.rows; ++y)
    for (int x = 0; x < chart.cols; ++x) {
      const double v = 255 * value((y / 65) * chart::kColumns + x / 65);
      auto& px = chart.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) px[c] = cv::saturate_cast<uchar>(std::lround(v + noise(rng)));
    }
  return chart;
}

struct Score {
  double full = 0, covered = 0, aligned = 0, fit_rmse = 0;
};

Score score(const std::vector<double>& truth, const ChartChannelResult& channel,
            const std::optional<IntensityRange>& truth_covered = {}) {
  const ChannelComparison e = compareCurves(truth, channel.fit.inverse, truth_covered, channel.fit.covered_range);
  return {e.rmse, e.rmse_covered, e.rmse_covered_aligned, channel.fit.rmse};
}

struct Summary {
  double mean_full = 0, median_full = 0, max_full = 0, mean_covered = 0, mean_aligned = 0, max_aligned = 0,
         mean_fit = 0;
};

Summary summarise(std::vector<Score> scores) {
  Summary s;
  if (scores.empty()) return s;
  std::vector<double> full;
  for (const auto& e : scores) {
    s.mean_full += e.full;
    s.mean_covered += e.covered;
    s.mean_aligned += e.aligned;
    s.mean_fit += e.fit_rmse;
    s.max_full = std::max(s.max_full, e.full);
    s.max_aligned = std::max(s.max_aligned, e.aligned);
    full.push_back(e.full);
  }
  const double n = double(scores.size());
  s.mean_full /= n;
  s.mean_covered /= n;
  s.mean_aligned /= n;
  s.mean_fit /= n;
  std::sort(full.begin(), full.end());
  s.median_full = full.size() % 2 ? full[full.size() / 2] : 0.5 * (full[full.size() / 2 - 1] + full[full.size() / 2]);
  return s;
}

nlohmann::json toJson(const Summary& s) {
  return {{"mean_full", s.mean_full},       {"median_full", s.median_full}, {"max_full", s.max_full},
          {"mean_covered", s.mean_covered}, {"mean_aligned", s.mean_aligned}, {"max_aligned", s.max_aligned},
          {"mean_fit_rmse", s.mean_fit}};
}

std::string weightText(double w) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", w);
  return text;
}

nlohmann::json runSynthetic(const ChartBenchArgs& args, Progress& progress) {
  const std::vector<KnownCurve> curves = knownCurves();
  const char* modes[2] = {"reflectance", "raw"};
  struct Case {
    size_t curve;
    int seed;
    std::vector<ChartShot> shots;
  };
  std::vector<Case> cases;
  for (size_t c = 0; c < curves.size(); ++c)
    for (int seed = 1; seed <= args.seeds; ++seed) {
      std::mt19937 rng(static_cast<unsigned>(1000 * seed + c));
      // Brightest shot: white at 1.0–1.6× the saturation exposure; the others 1, 2 and 3 stops darker.
      const double top = std::uniform_real_distribution<double>(1.0, 1.6)(rng);
      const double raw_scale = std::uniform_real_distribution<double>(0.7, 1.3)(rng);
      Case one{c, seed, {}};
      for (int k = 0; k < 4; ++k) {
        const double exposure = top / std::pow(2.0, 3 - k);
        auto irradiance = [&](int p) { return exposure * chart::reference()[static_cast<size_t>(p)].Y; };
        ChartShot shot;
        shot.name = curves[c].name + " e" + std::to_string(k);
        shot.measured = chart::sampleRectified(renderChart(
            [&](int p) { return curves[c].curve.forward(std::min(1.0, irradiance(p))); }, args.noise, rng));
        shot.raw = chart::sampleRectified(
            renderChart([&](int p) { return std::min(1.0, raw_scale * irradiance(p)); }, 0.7 * args.noise, rng));
        one.shots.push_back(std::move(shot));
      }
      cases.push_back(std::move(one));
    }

  // scores[weight][mode][case]
  std::vector<std::array<std::vector<Score>, 2>> scores(args.weights.size());
  for (auto& w : scores)
    for (auto& m : w) m.resize(cases.size());
  const int jobs = int(args.weights.size() * 2 * cases.size());
  std::mutex mutex;
  int done = 0;
  cv::parallel_for_(cv::Range(0, jobs), [&](const cv::Range& range) {
    for (int job = range.start; job < range.end; ++job) {
      const size_t w = size_t(job) / (2 * cases.size());
      const size_t m = (size_t(job) / cases.size()) % 2;
      const size_t i = size_t(job) % cases.size();
      ChartCalibrationOptions options;
      options.channels = {1};
      options.use_raw = m == 1;
      options.raw_neutral_only = true;
      options.fit.exponent_smoothness = args.weights[w];
      const ChartCalibrationResult result = calibrateChart(cases[i].shots, options);
      scores[w][m][i] = score(curves[cases[i].curve].curve.sample(kCurveSamples), result.channels.front());
      std::lock_guard lock(mutex);
      progress.update(double(++done) / jobs);
    }
  });
  progress.done();

  nlohmann::json json = nlohmann::json::array();
  std::printf("\nSynthetic grey charts: %zu curves x %d seeds, 4 exposures, noise %.2g codes (phi RMSE vs the known "
              "curve; G channel)\n",
              curves.size(), args.seeds, args.noise);
  std::printf("%-12s %-11s %9s %9s %9s %10s %10s %9s %9s\n", "exp. weight", "reference", "mean full", "median",
              "max full", "mean cov.", "mean align", "max align", "fit rmse");
  for (size_t w = 0; w < args.weights.size(); ++w)
    for (size_t m = 0; m < 2; ++m) {
      const Summary s = summarise(scores[w][m]);
      std::printf("%-12s %-11s %9.4f %9.4f %9.4f %10.4f %10.4f %9.4f %9.4f\n", weightText(args.weights[w]).c_str(),
                  modes[m], s.mean_full, s.median_full, s.max_full, s.mean_covered, s.mean_aligned, s.max_aligned,
                  s.mean_fit);
      nlohmann::json entry = toJson(s);
      entry["exponent_smoothness"] = args.weights[w];
      entry["reference"] = modes[m];
      json.push_back(entry);
    }
  if (args.per_curve) {
    std::printf("\nper curve: mean full RMSE over seeds (reflectance | raw) for each weight\n%-10s", "curve");
    for (double w : args.weights) std::printf(" %19s", ("w=" + weightText(w)).c_str());
    std::printf("\n");
    for (size_t c = 0; c < curves.size(); ++c) {
      std::printf("%-10s", curves[c].name.c_str());
      for (size_t w = 0; w < args.weights.size(); ++w) {
        double sum[2] = {0, 0};
        int n = 0;
        for (size_t i = 0; i < cases.size(); ++i)
          if (cases[i].curve == c) sum[0] += scores[w][0][i].full, sum[1] += scores[w][1][i].full, ++n;
        std::printf("     %6.4f | %6.4f", sum[0] / n, sum[1] / n);
      }
      std::printf("\n");
    }
  }
  return json;
}

// The cameras used to choose a default between reference sets, and the others on which the choice is reported: every
// other camera in name order (indices 0, 2, 4, 6, 8 choose; 1, 3, 5, 7, 9 report), fixed before any result was seen.
bool choosingCamera(size_t index) { return index % 2 == 0; }

double medianOf(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

// One calibration of the Middlebury part: a camera's shots (all, or one scene's) with one reference set and weight.
struct MiddleburyCase {
  size_t camera = 0;
  int scene = 0;  // 0 = all shots of the camera
  size_t reference = 0, weight = 0;
  std::array<Score, 3> scores{};
};

// The shape error over the covered range ("aligned") per channel, averaged over the cases of a camera set.
void printReferenceComparison(const ChartBenchArgs& args, const std::vector<MiddleburyCase>& cases, size_t weight,
                              nlohmann::json& json) {
  std::printf("\nreference sets, exponent weight %s: shape error over the covered range (aligned), mean per channel; "
              "choose = cameras 1, 3, 5, 7, 9 in name order, report = 2, 4, 6, 8, 10\n",
              weightText(args.weights[weight]).c_str());
  std::printf("| reference | shots | cameras | R | G | B | RGB mean | R/G | B/G |\n|---|---|---|---|---|---|---|---|---|\n");
  for (size_t r = 0; r < args.references.size(); ++r)
    for (const bool scene : {false, true}) {
      if (scene && !args.per_scene) continue;
      for (const bool choosing : {true, false}) {
        double sum[3] = {0, 0, 0};
        int n = 0;
        for (const auto& c : cases) {
          if (c.reference != r || c.weight != weight || (c.scene != 0) != scene || choosingCamera(c.camera) != choosing)
            continue;
          for (int ch = 0; ch < 3; ++ch) sum[ch] += c.scores[static_cast<size_t>(ch)].aligned;
          ++n;
        }
        if (n == 0) continue;
        const double R = sum[0] / n, G = sum[1] / n, B = sum[2] / n;
        std::printf("| %s | %s | %s | %.4f | %.4f | %.4f | %.4f | %.2f | %.2f |\n", args.references[r].c_str(),
                    scene ? "4 (one scene)" : "8 (both scenes)", choosing ? "choose" : "report", R, G, B,
                    (R + G + B) / 3, R / G, B / G);
        json.push_back({{"reference", args.references[r]}, {"shots", scene ? 4 : 8},
                        {"cameras", choosing ? "choose" : "report"}, {"R", R}, {"G", G}, {"B", B},
                        {"rgb", (R + G + B) / 3}, {"exponent_smoothness", args.weights[weight]}});
      }
    }
}

// One Middlebury camera's chart shots, sampled from the JPEG and from the RAW.
struct MiddleburyCamera {
  std::string name;
  std::vector<ChartShot> shots;
  std::vector<int> scenes;  // the scene numbers its shots belong to
};

std::vector<MiddleburyCamera> loadMiddleburyCameras(const fs::path& root) {
  const std::vector<std::string> cameras = io::listMiddleburyCameras(root);
  if (cameras.empty()) throw Error("no Middlebury camera folders", root.string());
  std::vector<MiddleburyCamera> data;
  for (const auto& camera : cameras) {
    MiddleburyCamera one{camera, {}, {}};
    for (const auto& shot : io::listMiddleburyShots(root / camera)) {
      ChartShot s;
      s.name = shot.name;
      s.scene = shot.scene;
      s.measured = chart::sampleRectified(io::loadChart(shot.jpg, io::ChartLayout::Rectified).rectified);
      s.raw = chart::sampleRectified(io::loadChart(shot.raw, io::ChartLayout::Rectified).rectified);
      one.shots.push_back(std::move(s));
      if (std::find(one.scenes.begin(), one.scenes.end(), shot.scene) == one.scenes.end()) one.scenes.push_back(shot.scene);
    }
    data.push_back(std::move(one));
  }
  return data;
}

// Every case (camera × reference × weight, and per scene with --per-scene) calibrated from the JPEG shots and scored
// against the truth of its camera and weight: `crfcal chart JPEG… --raw RAW…` on all shots (grey patches, one RAW
// scale).
std::vector<MiddleburyCase> scoreMiddleburyCases(const ChartBenchArgs& args,
                                                 const std::vector<chart::ReferenceSet>& references,
                                                 const std::vector<MiddleburyCamera>& data, Progress& progress) {
  std::vector<std::vector<ChartCalibrationResult>> truth(args.weights.size(), std::vector<ChartCalibrationResult>(data.size()));
  std::vector<MiddleburyCase> cases;
  for (size_t w = 0; w < args.weights.size(); ++w)
    for (size_t r = 0; r < references.size(); ++r)
      for (size_t i = 0; i < data.size(); ++i) {
        cases.push_back({i, 0, r, w, {}});
        if (args.per_scene)
          for (int scene : data[i].scenes) cases.push_back({i, scene, r, w, {}});
      }
  const int truth_jobs = int(args.weights.size() * data.size());
  const int jobs = truth_jobs + int(cases.size());
  std::mutex mutex;
  int done = 0;
  cv::parallel_for_(cv::Range(0, truth_jobs), [&](const cv::Range& range) {
    for (int job = range.start; job < range.end; ++job) {
      const size_t w = size_t(job) / data.size(), i = size_t(job) % data.size();
      ChartCalibrationOptions truth_options;
      truth_options.use_raw = true;
      truth_options.raw_neutral_only = true;
      truth_options.fit.exponent_smoothness = args.weights[w];
      truth[w][i] = calibrateChart(data[i].shots, truth_options);
      std::lock_guard lock(mutex);
      progress.update(double(++done) / jobs);
    }
  });
  cv::parallel_for_(cv::Range(0, int(cases.size())), [&](const cv::Range& range) {
    for (int job = range.start; job < range.end; ++job) {
      MiddleburyCase& one = cases[static_cast<size_t>(job)];
      ChartCalibrationOptions options;  // `crfcal chart JPEG… --reference R` (no exposures: free per shot)
      options.reference = references[one.reference];
      options.colour_outlier_factor = args.colour_outlier_factor;
      options.grey_weight = args.grey_weight;
      options.fit.exponent_smoothness = args.weights[one.weight];
      std::vector<ChartShot> shots;
      for (const auto& s : data[one.camera].shots)
        if (one.scene == 0 || s.scene == one.scene) shots.push_back(s);
      const ChartCalibrationResult fit = calibrateChart(shots, options);
      const ChartCalibrationResult& t = truth[one.weight][one.camera];
      for (size_t c = 0; c < 3; ++c)
        one.scores[c] = score(t.channels[c].fit.inverse, fit.channels[c], t.channels[c].fit.covered_range);
      std::lock_guard lock(mutex);
      progress.update(double(++done) / jobs);
    }
  });
  progress.done();
  return cases;
}

// The summary per weight and reference set (all shots of each camera per call); its JSON array.
nlohmann::json printMiddleburySummary(const ChartBenchArgs& args, const std::vector<MiddleburyCamera>& data,
                                      const std::vector<MiddleburyCase>& cases) {
  nlohmann::json json = nlohmann::json::array();
  std::printf("%-12s %-10s %9s %9s %9s %10s %10s %9s\n", "exp. weight", "reference", "median", "mean full", "max full",
              "median cov", "med. align", "max align");
  for (size_t w = 0; w < args.weights.size(); ++w)
    for (size_t r = 0; r < args.references.size(); ++r) {
      std::vector<Score> all;
      std::vector<double> covered, aligned;
      nlohmann::json per_camera = nlohmann::json::object();
      for (const auto& c : cases) {
        if (c.weight != w || c.reference != r || c.scene != 0) continue;
        for (size_t ch = 0; ch < 3; ++ch) {
          const Score& s = c.scores[ch];
          all.push_back(s), covered.push_back(s.covered), aligned.push_back(s.aligned);
          per_camera[data[c.camera].name][channelName(int(ch))] = {
              {"full", s.full}, {"covered", s.covered}, {"aligned", s.aligned}};
        }
      }
      const Summary s = summarise(all);
      std::printf("%-12s %-10s %9.4f %9.4f %9.4f %10.4f %10.4f %9.4f\n", weightText(args.weights[w]).c_str(),
                  args.references[r].c_str(), s.median_full, s.mean_full, s.max_full, medianOf(covered),
                  medianOf(aligned), s.max_aligned);
      nlohmann::json entry = toJson(s);
      entry["exponent_smoothness"] = args.weights[w];
      entry["reference"] = args.references[r];
      entry["median_covered"] = medianOf(covered);
      entry["median_aligned"] = medianOf(aligned);
      entry["cameras"] = per_camera;
      json.push_back(entry);
    }
  return json;
}

// The per-camera tables of one weight, one per reference set.
void printMiddleburyPerCamera(const ChartBenchArgs& args, const std::vector<MiddleburyCamera>& data,
                              const std::vector<MiddleburyCase>& cases, size_t shown) {
  for (size_t r = 0; r < args.references.size(); ++r) {
    std::printf("\nper camera, reference %s, exponent weight %s, all 8 shots: phi RMSE full [0,1] / covered / covered "
                "scale-aligned\n", args.references[r].c_str(), weightText(args.weights[shown]).c_str());
    std::printf("| camera | R: full / covered / aligned | G: full / covered / aligned | B: full / covered / aligned |\n");
    std::printf("|---|---|---|---|\n");
    for (const auto& c : cases) {
      if (c.weight != shown || c.reference != r || c.scene != 0) continue;
      std::printf("| %s |", data[c.camera].name.c_str());
      for (const auto& s : c.scores) std::printf(" %.3f / %.3f / %.3f |", s.full, s.covered, s.aligned);
      std::printf("\n");
    }
  }
}

nlohmann::json runMiddlebury(const ChartBenchArgs& args, const fs::path& root, Progress& progress) {
  const std::vector<MiddleburyCamera> data = loadMiddleburyCameras(root);
  std::vector<chart::ReferenceSet> references;
  for (const auto& name : args.references) references.push_back(chart::parseReferenceSet(name));
  const std::vector<MiddleburyCase> cases = scoreMiddleburyCases(args, references, data, progress);

  std::printf("\nMiddlebury (%s): chart calibration from the JPEG shots (all 8 shots of a camera per call) vs "
              "RAW->JPEG truth\n", root.string().c_str());
  const nlohmann::json json = printMiddleburySummary(args, data, cases);
  // The per-camera tables for the library's default weight (or the last one given).
  size_t shown = args.weights.size() - 1;
  for (size_t w = 0; w < args.weights.size(); ++w)
    if (args.weights[w] == ScaledFitOptions{}.exponent_smoothness) shown = w;
  printMiddleburyPerCamera(args, data, cases, shown);
  nlohmann::json comparison = nlohmann::json::array();
  printReferenceComparison(args, cases, shown, comparison);
  return {{"weights", json}, {"reference_comparison", comparison}};
}

int runChartBench(const ChartBenchArgs& args) {
  if (args.seeds < 1) throw InvalidInput("--seeds must be at least 1");
  if (args.weights.empty()) throw InvalidInput("--exponent-smoothness needs at least one weight");
  if (args.references.empty()) throw InvalidInput("--reference needs at least one reference set");
  for (const auto& r : args.references) chart::parseReferenceSet(r);  // refused before the computation
  for (double w : args.weights)
    if (!(w >= 0)) throw InvalidInput("--exponent-smoothness weights must be >= 0");
  const io::OutputPolicy policy{"bench chart", {io::defaultSharedData(args.data)}, args.force};
  if (!args.json.empty()) io::checkJsonOutputFile(args.json, policy);  // before the computation
  Progress progress(args.quiet);
  nlohmann::json json;
  if (args.synthetic) {
    progress.stage("synthetic charts");
    json["synthetic"] = runSynthetic(args, progress);
  }
  if (args.middlebury) {
    const fs::path root = io::defaultSharedData(args.data) / "middlebury";
    if (!fs::is_directory(root)) {
      std::printf("\nMiddlebury data not found at %s (give --data or set CRFCAL_SHARED_DATA): skipped\n",
                  root.string().c_str());
    } else {
      progress.stage("middlebury");
      json["middlebury"] = runMiddlebury(args, root, progress);
    }
  }
  if (!args.json.empty()) io::writeJsonOutput(args.json, json, policy.command);
  return kExitOk;
}

const BenchRegistration registration(
    40, "chart",
    "ColorChecker calibration vs known curves: synthetic grey charts (known phi) and, with the data, the ten "
    "Middlebury cameras vs their RAW->JPEG truth",
    [](CLI::App& command) {
      auto args = std::make_shared<ChartBenchArgs>();
      command.add_option("--seeds", args->seeds, "Random shot sets per synthetic curve")->check(CLI::Range(1, 1000));
      command.add_option("--exponent-smoothness", args->weights,
                         "Weights of the local-exponent penalty to compare (ScaledFitOptions::exponent_smoothness)")
          ->delimiter(',');
      command.add_option("--reference", args->references,
                         "Reference sets to compare on the cameras (crfcal chart --reference): neutral, all, srgb, "
                         "luminance")
          ->delimiter(',');
      command.add_flag("!--no-per-scene", args->per_scene,
                       "Only all 8 shots of a camera per call (not also each scene's 4 shots alone)");
      command.add_option("--colour-outliers", args->colour_outlier_factor,
                         "--reference all: coloured patches misfitting by more than this many times the median are "
                         "left out (0 = keep all)")
          ->check(CLI::NonNegativeNumber);
      command.add_option("--grey-weight", args->grey_weight,
                         "--reference all: weight of a grey patch sample relative to a coloured one")
          ->check(CLI::PositiveNumber);
      command.add_option("--noise", args->noise, "Noise sigma of the synthetic JPEG renderings, 8-bit codes")
          ->check(CLI::NonNegativeNumber);
      command.add_option("--data", args->data, "Shared data directory (default $CRFCAL_SHARED_DATA or ../shared/data)");
      command.add_flag("!--no-synthetic", args->synthetic, "Skip the synthetic charts");
      command.add_flag("!--no-middlebury", args->middlebury, "Skip the Middlebury cameras");
      command.add_flag("--per-curve", args->per_curve, "Also print the synthetic error per curve");
      command.add_option("--json", args->json, "Write all numbers to this JSON file (atomic)");
      command.add_flag("--force", args->force, kForceHelp);
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runChartBench(*args); };
    });

}  // namespace
}  // namespace crfcal::app
