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

nlohmann::json runMiddlebury(const ChartBenchArgs& args, const fs::path& root, Progress& progress) {
  const std::vector<std::string> cameras = io::listMiddleburyCameras(root);
  if (cameras.empty()) throw Error("no Middlebury camera folders", root.string());
  struct Camera {
    std::string name;
    std::vector<ChartShot> shots;
  };
  std::vector<Camera> data;
  for (const auto& camera : cameras) {
    Camera one{camera, {}};
    for (const auto& shot : io::listMiddleburyShots(root / camera)) {
      ChartShot s;
      s.name = shot.name;
      s.measured = chart::sampleRectified(io::loadChart(shot.jpg, io::ChartLayout::Rectified).rectified);
      s.raw = chart::sampleRectified(io::loadChart(shot.raw, io::ChartLayout::Rectified).rectified);
      one.shots.push_back(std::move(s));
    }
    data.push_back(std::move(one));
  }
  // results[weight][camera] = 3 channel scores
  std::vector<std::vector<std::array<Score, 3>>> results(args.weights.size(),
                                                         std::vector<std::array<Score, 3>>(data.size()));
  const int jobs = int(args.weights.size() * data.size());
  std::mutex mutex;
  int done = 0;
  cv::parallel_for_(cv::Range(0, jobs), [&](const cv::Range& range) {
    for (int job = range.start; job < range.end; ++job) {
      const size_t w = size_t(job) / data.size(), i = size_t(job) % data.size();
      ChartCalibrationOptions truth_options;  // `crfcal chart JPEG… --raw RAW…` (grey patches, one RAW scale)
      truth_options.use_raw = true;
      truth_options.raw_neutral_only = true;
      truth_options.fit.exponent_smoothness = args.weights[w];
      ChartCalibrationOptions options;  // `crfcal chart JPEG…` (grey reflectances, a free scale per shot)
      options.fit.exponent_smoothness = args.weights[w];
      const ChartCalibrationResult truth = calibrateChart(data[i].shots, truth_options);
      const ChartCalibrationResult fit = calibrateChart(data[i].shots, options);
      for (size_t c = 0; c < 3; ++c)
        results[w][i][c] = score(truth.channels[c].fit.inverse, fit.channels[c], truth.channels[c].fit.covered_range);
      std::lock_guard lock(mutex);
      progress.update(double(++done) / jobs);
    }
  });
  progress.done();

  nlohmann::json json = nlohmann::json::array();
  std::printf("\nMiddlebury (%s): chart calibration from the JPEG shots (grey reflectances) vs RAW->JPEG truth\n",
              root.string().c_str());
  std::printf("%-12s %9s %9s %9s %10s %10s %9s\n", "exp. weight", "median", "mean full", "max full", "median cov",
              "med. align", "max align");
  for (size_t w = 0; w < args.weights.size(); ++w) {
    std::vector<Score> all;
    std::vector<double> covered, aligned;
    for (const auto& camera : results[w])
      for (const auto& s : camera) all.push_back(s), covered.push_back(s.covered), aligned.push_back(s.aligned);
    const Summary s = summarise(all);
    std::sort(covered.begin(), covered.end());
    std::sort(aligned.begin(), aligned.end());
    const auto median = [](const std::vector<double>& v) {
      return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
    };
    std::printf("%-12s %9.4f %9.4f %9.4f %10.4f %10.4f %9.4f\n", weightText(args.weights[w]).c_str(), s.median_full,
                s.mean_full, s.max_full, median(covered), median(aligned), s.max_aligned);
    nlohmann::json entry = toJson(s);
    entry["exponent_smoothness"] = args.weights[w];
    entry["median_covered"] = median(covered);
    entry["median_aligned"] = median(aligned);
    entry["cameras"] = nlohmann::json::object();
    for (size_t i = 0; i < data.size(); ++i)
      for (size_t c = 0; c < 3; ++c)
        entry["cameras"][data[i].name][channelName(int(c))] = {{"full", results[w][i][c].full},
                                                              {"covered", results[w][i][c].covered},
                                                              {"aligned", results[w][i][c].aligned}};
    json.push_back(entry);
  }
  // The per-camera table for the library's default weight (or the last one given).
  size_t shown = args.weights.size() - 1;
  for (size_t w = 0; w < args.weights.size(); ++w)
    if (args.weights[w] == ScaledFitOptions{}.exponent_smoothness) shown = w;
  std::printf("\nper camera, exponent weight %s: phi RMSE full [0,1] / covered / covered scale-aligned\n",
              weightText(args.weights[shown]).c_str());
  std::printf("| camera | R: full / covered / aligned | G: full / covered / aligned | B: full / covered / aligned |\n");
  std::printf("|---|---|---|---|\n");
  for (size_t i = 0; i < data.size(); ++i) {
    std::printf("| %s |", data[i].name.c_str());
    for (const auto& s : results[shown][i]) std::printf(" %.3f / %.3f / %.3f |", s.full, s.covered, s.aligned);
    std::printf("\n");
  }
  return json;
}

int runChartBench(const ChartBenchArgs& args) {
  if (args.seeds < 1) throw InvalidInput("--seeds must be at least 1");
  if (args.weights.empty()) throw InvalidInput("--exponent-smoothness needs at least one weight");
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
