// crfcal bench effects: detection and false-alarm rates of the residual diagnostics (effects.hpp). Pairs are made
// from real images (bundled Levin et al. photos; colour: the bundled semi-real pair's sharp photo) through real
// camera curves (samples/camera_curves) and real kernels (Levin), with ONE effect planted at a random strength in
// [threshold, 2·threshold] (effect_planting.hpp) — or none — and run through calibratePair.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "bench_command.hpp"
#include "crfcal/effect_planting.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct EffectsArgs {
  std::vector<std::string> effects;  // default: none + all
  int seeds = 20;
  int max_side = 255;
  std::string json;
  double min_gain = EffectOptions{}.min_gain;
  double min_z = EffectOptions{}.min_z;
  int phi_terms = EffectOptions{}.phi_terms;
  double min_nll_gain = EffectOptions{}.min_nll_gain;
  bool verbose = false;
};

struct CaseResult {
  std::string effect;
  int seed = 0;
  double strength = 0;
  std::vector<std::string> detected;
  bool hit = false;          // effect: the right name detected; none: nothing detected
  bool exact = false;        // the right name and no other
  double rmse = 0, rmse_base = 0;
  double seconds = 0;
  std::string error;
};

int runEffects(const EffectsArgs& args) {
  const fs::path samples = io::samplesDirectory();
  std::vector<cv::Mat> grey;
  for (int i = 1; i <= 4; ++i) grey.push_back(io::readImage(samples / "levin09" / ("im" + std::to_string(i) + ".png")));
  cv::Mat colour = io::readImage(samples / "pairs" / "sharp.jpg");
  auto fit = [&](cv::Mat m) {
    if (m.depth() != CV_8U) m.convertTo(m, CV_8U, 255.0 / 65535.0);
    const double s = std::min(1.0, static_cast<double>(args.max_side) / std::max(m.cols, m.rows));
    if (s < 1) cv::resize(m, m, cv::Size(), s, s, cv::INTER_AREA);
    return m;
  };
  for (auto& g : grey) g = fit(g);
  colour = fit(colour);
  std::vector<fs::path> curves;
  for (const auto& e : fs::directory_iterator(samples / "camera_curves"))
    if (e.path().extension() == ".csv") curves.push_back(e.path());
  std::sort(curves.begin(), curves.end());
  if (curves.empty()) throw Error("no camera curves", (samples / "camera_curves").string());

  std::vector<std::string> effects = args.effects;
  if (effects.empty()) {
    effects.push_back("none");
    for (const auto& n : effectNames()) effects.push_back(n);
  }
  std::vector<CaseResult> results;
  for (const auto& effect : effects) {
    for (int seed = 1; seed <= args.seeds; ++seed) {
      std::mt19937_64 rng(static_cast<std::uint64_t>(seed) * 7919 + std::hash<std::string>{}(effect));
      std::uniform_real_distribution<double> u(0, 1);
      const bool need_colour = effect == "channel_mixing";
      const cv::Mat& photo = need_colour ? colour : grey[static_cast<std::size_t>(u(rng) * grey.size()) % grey.size()];
      const fs::path curve = curves[static_cast<std::size_t>(u(rng) * curves.size()) % curves.size()];
      const int kernel_index = 1 + static_cast<int>(u(rng) * 8) % 8;
      const ResponseModel truth = TableModel{io::readCurveTable(curve)};
      const cv::Mat kernel = io::kernelFromSpec("levin:" + std::to_string(kernel_index));
      PlantingOptions po;
      po.effect = effect;
      po.strength = plantingThreshold(effect) * (1 + u(rng));
      po.ratio = 0.8 + 0.6 * u(rng);
      po.seed = static_cast<std::uint64_t>(seed);
      CaseResult r;
      r.effect = effect;
      r.seed = seed;
      r.strength = po.strength;
      const auto t0 = std::chrono::steady_clock::now();
      try {
        const PlantedPair pair = plantEffect(photo, truth, kernel, po);
        PairCalibrationOptions options;
        options.register_pair = false;
        options.rgb = need_colour;
        options.fit.initial_ratio = pair.exif_ratio;
        options.effects.min_gain = args.min_gain;
        options.effects.min_z = args.min_z;
        options.effects.phi_terms = args.phi_terms;
        options.effects.min_nll_gain = args.min_nll_gain;
        if (effect == "spatially_varying_blur") {
          options.kernel.kernel_size = 31;
          options.tiles.whole_image_below = 4096;
          options.rounds = 1;
        } else {
          options.given_kernel = kernel;
        }
        const PairCalibrationResult result = calibratePair(pair.sharp, pair.blurred, options);
        r.detected = result.effects.detected();
        r.hit = effect == "none" ? r.detected.empty()
                                 : std::find(r.detected.begin(), r.detected.end(), effect) != r.detected.end();
        r.exact = effect == "none" ? r.detected.empty() : (r.hit && r.detected.size() == 1);
        r.rmse = curveRmse(result.fits.at("G").inverse_crf, sampleInverse(truth));
        r.rmse_base = curveRmse((result.base_fits.empty() ? result.fits : result.base_fits).at("G").inverse_crf,
                                sampleInverse(truth));
        if (args.verbose) std::fprintf(stderr, "%s\n", result.effects.summary().c_str());
        if (args.verbose)
          for (const auto& w : result.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
      } catch (const std::exception& e) {
        r.error = e.what();
      }
      r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      std::string names;
      for (const auto& d : r.detected) names += (names.empty() ? "" : ",") + d;
      std::fprintf(stderr, "%-24s seed %3d strength %.4g: detected [%s] %s rmse %.4f (base %.4f) %.1f s%s\n",
                   effect.c_str(), seed, r.strength, names.c_str(), r.exact ? "OK" : "WRONG", r.rmse, r.rmse_base,
                   r.seconds, r.error.empty() ? "" : (" error: " + r.error).c_str());
      results.push_back(r);
    }
  }
  // Table.
  std::ostringstream table;
  table << "| planted effect | strength range | cases | detected (right name) | exactly right (no other) | "
           "false names | phi_G RMSE median (extended) | median (base) | s/case |\n|---|---|---|---|---|---|---|---|---|\n";
  nlohmann::json json = nlohmann::json::array();
  for (const auto& effect : effects) {
    int n = 0, hit = 0, exact = 0, others = 0;
    std::vector<double> rm, rb;
    double secs = 0;
    for (const auto& r : results) {
      if (r.effect != effect) continue;
      ++n;
      hit += r.hit;
      exact += r.exact;
      for (const auto& d : r.detected)
        if (d != effect) ++others;
      if (r.error.empty()) {
        rm.push_back(r.rmse);
        rb.push_back(r.rmse_base);
      }
      secs += r.seconds;
      json.push_back({{"effect", r.effect}, {"seed", r.seed}, {"strength", r.strength}, {"detected", r.detected},
                      {"hit", r.hit}, {"exact", r.exact}, {"phi_rmse", r.rmse}, {"phi_rmse_base", r.rmse_base},
                      {"seconds", r.seconds}, {"error", r.error}});
    }
    auto median = [](std::vector<double> v) -> double {
      if (v.empty()) return NAN;
      std::sort(v.begin(), v.end());
      return v[v.size() / 2];
    };
    const double t = plantingThreshold(effect);
    char line[512];
    std::snprintf(line, sizeof line, "| %s | %s | %d | %d (%.0f %%) | %d (%.0f %%) | %d | %.4f | %.4f | %.1f |\n",
                  effect.c_str(), effect == "none" ? "-" : (std::to_string(t) + "–" + std::to_string(2 * t)).c_str(), n,
                  hit, 100.0 * hit / std::max(1, n), exact, 100.0 * exact / std::max(1, n), others, median(rm),
                  median(rb), secs / std::max(1, n));
    table << line;
  }
  table << "\n('none' row: 'detected' = no effect reported; 1 − that is the false-alarm rate.)\n";
  std::printf("%s", table.str().c_str());
  if (!args.json.empty()) io::writeTextFile(args.json, json.dump(1));
  return kExitOk;
}

const BenchRegistration registration(
    60, "effects",
    "Detection / false-alarm rates of the residual effect diagnostics on pairs with one planted effect",
    [](CLI::App& command) {
      auto args = std::make_shared<EffectsArgs>();
      command.add_option("--effect", args->effects, "Effects to plant (default: none and every effect)");
      command.add_option("--seeds", args->seeds, "Pairs per effect")->check(CLI::Range(1, 10000));
      command.add_option("--max-side", args->max_side, "Downscale the photos to this longest side")
          ->check(CLI::Range(128, 4096));
      command.add_option("--min-gain", args->min_gain, "EffectOptions::min_gain (relative held-out drop)");
      command.add_option("--min-z", args->min_z, "EffectOptions::min_z (paired block test)");
      command.add_option("--phi-terms", args->phi_terms, "EffectOptions::phi_terms (EMoR curves phi may re-adjust by)")
          ->check(CLI::Range(0, 10));
      command.add_option("--min-nll-gain", args->min_nll_gain, "EffectOptions::min_nll_gain (noise test, nats)");
      command.add_option("--json", args->json, "Write the per-case results here");
      command.add_flag("-v,--verbose", args->verbose, "Print every case's effect table");
      return [args] { return runEffects(*args); };
    });

}  // namespace
}  // namespace crfcal::app
