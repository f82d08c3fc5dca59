// crfcal bench effects: detection and false-alarm rates of the residual diagnostics (effects.hpp). Pairs are made
// from real photographs (2×2 mosaics of the four bundled Levin et al. photos, 510 px, grey; colour:
// samples/effects/window.jpg, 640×480) through real
// camera curves (samples/camera_curves) and real kernels (Levin), with ONE effect planted at a random strength in
// [threshold, 2·threshold] (effect_planting.hpp) — or none — and run through calibratePair. Every case also runs
// its clean twin (same photo, curve, kernel, r, noise seed, no effect): "phi ok" = the reported φ is within the
// clean twin's accuracy (RMSE ≤ twin + 0.005, i.e. 1.3/255; for a planted plateau both over [0, plateau], the twin
// fitted with the same measurable range).
// --form held-out plants the effects in forms the detectors do not assume (effect_planting.hpp), --two-effects
// plants pairs of effects, --ratio R puts the pairs in the real regime (r ≈ R, the sharp shot underexposed by r);
// the confusion matrix (planted × named) follows the table. In the real regime (--ratio; or --sharp-noise sensor) the
// sharp shot gets a real camera's measured raw noise at its ISO (darktable profile, as `bench pairs`) on its
// irradiance, in place of the seed's Gaussian intensity noise (--sharp-noise intensity).
// --sweep: the φ bias each effect causes when it is ignored (effects off), per strength — the basis of the
// stated thresholds.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "bench_command.hpp"
#include "bench_real_regime.hpp"
#include "bench_statistics.hpp"
#include "option_checks.hpp"
#include "crfcal/effect_planting.hpp"
#include "crfcal/effects.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/jpeg_roundtrip.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/noise_profiles.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

constexpr double kPhiTolerance = 0.005;  // "within the clean-case accuracy": RMSE ≤ clean twin + this
const std::string kNoneEstimated = "none (kernel estimated)";

bool isClean(const std::string& effect) { return effect == "none" || effect == kNoneEstimated; }

struct EffectsArgs {
  std::vector<std::string> effects;  // default: none + all
  int seeds = 20;
  std::string json;
  double min_gain = EffectOptions{}.min_gain;
  double min_z = EffectOptions{}.min_z;
  int phi_terms = EffectOptions{}.phi_terms;
  double min_noise_contrast = EffectOptions{}.min_noise_contrast;
  int refit_rounds = EffectOptions{}.refit_rounds;
  bool sweep = false;
  std::vector<double> factors{0.25, 0.5, 1.0, 2.0};
  bool verbose = false;
  int threads = 2;  // cases in parallel (each case also uses OpenCV's own parallel loops; TBB nests them)
  bool force = false;  // --json/-o over files crfcal did not write (never deletes them)
  std::string form = "detector";  // PlantingOptions::form ("held-out" on the command line)
  bool two_effects = false;       // the default case list: pairs of effects
  double ratio = 0;               // > 0: r drawn in [0.9, 1.1]·ratio, the sharp shot's exposure divided by r
  int jpeg_quality = 0;           // > 0: both shots through a 4:2:0 JPEG of this quality
  bool handheld = false;          // B shifted 2–4 px and turned by up to 0.3°, registration on
  std::vector<std::string> photos;  // other scenes instead of the bundled ones (longest side scaled to 512 px)
  // intensity (the seed's Sec. 5), sensor (PlantingOptions::sharp_sensor_noise) or auto: sensor in the real regime
  // (--ratio), where the short high-ISO shot's noise is a camera's, as in `bench pairs`
  std::string sharp_noise = "auto";
  std::string noise_camera = "LGE Nexus 5";  // sensor: whose darktable profile (as `bench pairs`)
  std::string noise_profiles;                // sensor: darktable noiseprofiles.json (default: io::defaultNoiseProfiles)
  std::string pairs_out;  // each case's pairs as calibrated (after the JPEG round trip) and its truth, one directory each
};

// Pairs of effects planted together (--two-effects): each pairs effects whose detectors compete for the same misfit.
const std::vector<std::string> kEffectPairs{
    "vignetting+black_level_offset", "clipping+vignetting", "channel_mixing+black_level_offset",
    "spatially_varying_blur+clipping", "exposure_ratio_mismatch+vignetting"};

// "a+b" → {"a", "b"}; "a" → {"a"}; clean labels → {}.
std::vector<std::string> plantedNames(const std::string& label) {
  if (label == "none" || label == "none (kernel estimated)") return {};
  const auto plus = label.find('+');
  if (plus == std::string::npos) return {label};
  return {label.substr(0, plus), label.substr(plus + 1)};
}

bool isPlanted(const std::string& label, const std::string& name) {
  const auto names = plantedNames(label);
  return std::find(names.begin(), names.end(), name) != names.end();
}

struct CaseResult {
  std::string effect;
  int seed = 0;
  double strength = 0;
  std::string form;  // the planted pair's detail: which held-out form, which shot
  std::vector<std::string> detected;
  bool hit = false;          // effect: the right name detected; none: nothing detected
  bool exact = false;        // the right name and no other
  double rmse = 0, rmse_base = 0, rmse_clean = 0;
  bool phi_ok = false;
  // φ_G's shape where both the pair and its clean twin have data (their covered ranges' overlap, below a planted
  // plateau): RMSE after the best common factor. φ → bφ leaves Eq. 4 unchanged, so the RMSE over [0, 1] above also
  // carries the scale that φ(1) = 1 takes from the extrapolated top.
  double shape = 0, shape_base = 0, shape_clean = 0;
  bool shape_ok = false;
  double seconds = 0;  // the case: the planted pair and its clean twin
  // The planted pair's calibration alone (wall time) and its effect search within it: issue 18's cost target is
  // the search against the rest of the calibration.
  double calibration_seconds = 0, effects_seconds = 0;
  std::string error;
};

struct Sources {
  std::vector<cv::Mat> grey;    // Levin photos (255 px)
  std::vector<cv::Mat> mosaic;  // 2×2 mosaics of them (510 px): enough 32-px blocks for the paired tests
  cv::Mat colour;
  std::vector<fs::path> curves;
  std::optional<io::CameraNoiseProfile> noise_camera;  // --sharp-noise sensor
};

// Other scenes: each photo (longest side 512 px) serves as the grey scene and, in colour, as the colour scene.
Sources loadPhotos(const std::vector<std::string>& photos, Sources s) {
  s.mosaic.clear();
  s.colour.release();
  std::vector<cv::Mat> colours;
  for (const auto& path : photos) {
    cv::Mat m = io::readColorImage(path);
    const double scale = 512.0 / std::max(m.cols, m.rows);
    if (scale < 1) cv::resize(m, m, cv::Size(), scale, scale, cv::INTER_AREA);
    colours.push_back(m);
    cv::Mat grey;
    cv::cvtColor(m, grey, cv::COLOR_BGR2GRAY);
    s.mosaic.push_back(grey);
  }
  while (s.mosaic.size() < 4) s.mosaic.push_back(s.mosaic[s.mosaic.size() % photos.size()]);
  s.colour = colours.front();
  return s;
}

Sources loadSources() {
  const fs::path samples = io::samplesDirectory();
  Sources s;
  for (int i = 1; i <= 4; ++i) {
    cv::Mat m = io::readImage(samples / "levin09" / ("im" + std::to_string(i) + ".png"));
    if (m.depth() != CV_8U) m.convertTo(m, CV_8U, 255.0 / 65535.0);
    if (m.channels() == 3) cv::cvtColor(m, m, cv::COLOR_BGR2GRAY);
    s.grey.push_back(m);
  }
  for (int k = 0; k < 4; ++k) {  // four arrangements of the four photos
    cv::Mat top, bottom, m;
    cv::hconcat(s.grey[k % 4], s.grey[(k + 1) % 4], top);
    cv::hconcat(s.grey[(k + 2) % 4], s.grey[(k + 3) % 4], bottom);
    cv::vconcat(top, bottom, m);
    s.mosaic.push_back(m);
  }
  s.colour = io::readImage(samples / "effects" / "window.jpg");
  if (s.colour.depth() != CV_8U) s.colour.convertTo(s.colour, CV_8U, 255.0 / 65535.0);
  for (const auto& e : fs::directory_iterator(samples / "camera_curves"))
    if (e.path().extension() == ".csv") s.curves.push_back(e.path());
  std::sort(s.curves.begin(), s.curves.end());
  if (s.curves.empty()) throw Error("no camera curves", (samples / "camera_curves").string());
  return s;
}

struct Setup {
  cv::Mat photo, kernel;
  ResponseModel truth;
  PlantingOptions planting;
  PairCalibrationOptions calibration;
};

// The case of (effect, seed): photo, curve, kernel, r, noise seed drawn from the seed; strength factor × threshold.
Setup makeSetup(const Sources& src, const std::string& effect, int seed, double factor, const std::string& form,
                double ratio, bool handheld) {
  std::mt19937_64 rng(static_cast<std::uint64_t>(seed) * 7919 + std::hash<std::string>{}(effect));
  std::uniform_real_distribution<double> u(0, 1);
  Setup s;
  const std::vector<std::string> planted = plantedNames(effect);
  const bool colour = isPlanted(effect, "channel_mixing");
  // Blur effects need the kernel estimated (a given kernel is not tested for spatial variation); "none (kernel
  // estimated)" measures the false alarms of that path.
  const bool large = isPlanted(effect, "spatially_varying_blur") || effect == kNoneEstimated;
  const std::size_t pick = static_cast<std::size_t>(u(rng) * 4) % 4;
  s.photo = colour ? src.colour : src.mosaic[pick];
  const fs::path curve = src.curves[static_cast<std::size_t>(u(rng) * src.curves.size()) % src.curves.size()];
  const int kernel_index = 1 + static_cast<int>(u(rng) * 8) % 8;
  s.truth = TableModel{io::readCurveTable(curve)};
  s.kernel = io::kernelFromSpec("levin:" + std::to_string(kernel_index));
  const bool clean = effect == "none" || effect == kNoneEstimated;
  s.planting.effect = clean ? "none" : planted.front();
  s.planting.strength = clean ? 0.0 : plantingThreshold(planted.front()) * (factor > 0 ? factor : 1 + u(rng));
  if (factor > 0) u(rng);
  const double ratio_draw = u(rng);
  s.planting.ratio = ratio > 0 ? ratio * (0.9 + 0.2 * ratio_draw) : 0.8 + 0.6 * ratio_draw;
  // The real regime: the short sharp shot is underexposed by r, so that B keeps the usual brightness.
  if (ratio > 0) s.planting.exposure /= s.planting.ratio;
  if (planted.size() == 2) {
    s.planting.second_effect = planted.back();
    s.planting.second_strength = plantingThreshold(planted.back()) * (1 + u(rng));
  }
  s.planting.form = form;
  s.planting.seed = static_cast<std::uint64_t>(seed);
  // The short shot at the lowest profiled ISO × r (r× less light at r× the gain, as `bench pairs`).
  if (src.noise_camera)
    s.planting.sharp_sensor_noise = realExposure(*src.noise_camera, 0, std::max(1.0, s.planting.ratio)).noise_sharp;
  if (handheld) {  // its own stream: the cases without it stay what they were
    std::mt19937_64 motion(static_cast<std::uint64_t>(seed) * 104729 + 3);
    std::uniform_real_distribution<double> m(0, 1);
    const double angle = 2 * CV_PI * m(motion), shift = 2 + 2 * m(motion);
    s.planting.shift_x = shift * std::cos(angle);
    s.planting.shift_y = shift * std::sin(angle);
    s.planting.rotation_deg = 0.6 * m(motion) - 0.3;
  }
  PairCalibrationOptions& o = s.calibration;
  o.register_pair = handheld;
  o.rgb = colour;
  if (large) {
    o.kernel.kernel_size = 31;
    o.tiles.whole_image_below = 4096;
    o.rounds = 1;
  } else {
    o.given_kernel = s.kernel;
  }
  return s;
}

// --pairs-out: the staged directory, and the first write that failed (the bench then stops before committing it:
// nothing half-written).
struct PairsOutput {
  io::OutputDirectory directory;
  std::mutex mutex;
  std::exception_ptr first_error;
  PairsOutput(const std::string& path, const io::OutputPolicy& policy) : directory(path, policy) {}
};

// The directory name of a case in --pairs-out: the label without spaces or brackets, and the seed.
std::string caseDirectory(const std::string& effect, int seed) {
  std::string name = effect == kNoneEstimated ? "none-estimated" : effect;
  return name + "_seed" + std::to_string(seed);
}

// --pairs-out: the pair exactly as calibrated (8-bit PNG, after the JPEG round trip), with `prefix` "" for the planted
// pair and "twin_" for its clean twin; the planted pair also gets its kernel and a truth.json that says how the bench
// calibrated it, so that `crfcal calibrate` can re-run a case.
void writeCasePair(const std::filesystem::path& dir, const std::string& prefix, const PlantedPair& pair,
                   const Setup& s, const EffectsArgs& args, const std::string& effect, int seed) {
  std::filesystem::create_directories(dir);
  io::writeImage(dir / (prefix + "sharp.png"), pair.sharp);
  io::writeImage(dir / (prefix + "blurred.png"), pair.blurred);
  if (!prefix.empty()) return;
  io::writeKernelText(dir / "kernel.txt", s.kernel);
  const nlohmann::json truth = {{"effect", effect}, {"seed", seed}, {"strength", pair.strength},
                                {"detail", pair.detail}, {"exposure_ratio", pair.true_ratio},
                                {"exif_ratio", pair.exif_ratio}, {"plateau_intensity", pair.plateau_intensity},
                                {"inverse_crf", sampleInverse(s.truth)},
                                {"kernel_given", !s.calibration.given_kernel.empty()},
                                {"registered", s.calibration.register_pair}, {"jpeg_quality", args.jpeg_quality}};
  io::writeTextFile(dir / "truth.json", truth.dump(1) + "\n");
}

// G's covered range, below a planted plateau (above it any φ is an extrapolation); [0, plateau] without one.
IntensityRange coveredBelow(const PairCalibrationResult& result, double plateau) {
  IntensityRange range{0.0, 1.0};
  if (result.covered_range.count("G")) range = result.covered_range.at("G");
  range.second = std::min(range.second, plateau);
  return range;
}

CaseResult runCase(const Sources& src, const EffectsArgs& args, const std::string& effect, int seed, double factor,
                   bool effects_on, PairsOutput* pairs_out = nullptr) {
  Setup s = makeSetup(src, effect, seed, factor, args.form == "held-out" ? "held_out" : "detector", args.ratio,
                      args.handheld);
  CaseResult r;
  r.effect = effect;
  r.seed = seed;
  r.strength = s.planting.strength;
  const auto truth = sampleInverse(s.truth);
  const auto t0 = std::chrono::steady_clock::now();
  try {
    auto calibrate = [&](const PlantingOptions& po, const std::string& written_as) {
      PlantedPair pair = plantEffect(s.photo, s.truth, s.kernel, po);
      if (args.jpeg_quality > 0) {
        pair.sharp = io::jpegRoundTrip(pair.sharp, args.jpeg_quality);
        pair.blurred = io::jpegRoundTrip(pair.blurred, args.jpeg_quality);
      }
      if (pairs_out) {
        try {
          writeCasePair(pairs_out->directory.file(caseDirectory(effect, seed)), written_as, pair, s, args, effect,
                        seed);
        } catch (...) {
          const std::lock_guard<std::mutex> lock(pairs_out->mutex);
          if (!pairs_out->first_error) pairs_out->first_error = std::current_exception();
        }
      }
      PairCalibrationOptions options = s.calibration;
      options.fit.nominal_ratio = pair.exif_ratio;
      options.effects.enabled = effects_on;
      options.effects.min_gain = args.min_gain;
      options.effects.min_z = args.min_z;
      options.effects.phi_terms = args.phi_terms;
      options.effects.min_noise_contrast = args.min_noise_contrast;
      options.effects.refit_rounds = args.refit_rounds;
      return calibratePair(pair.sharp, pair.blurred, options);
    };
    const PlantedPair planted = plantEffect(s.photo, s.truth, s.kernel, s.planting);
    r.form = planted.detail;
    // φ is compared where the pair can measure it: up to B's plateau when one is planted (above it, any φ is an
    // extrapolation), else over [0, 1].
    const int top = static_cast<int>(std::lround(planted.plateau_intensity * (truth.size() - 1)));
    auto rmse = [&](const std::vector<double>& phi) {
      return curveRmse(std::vector<double>(phi.begin(), phi.begin() + top + 1),
                       std::vector<double>(truth.begin(), truth.begin() + top + 1));
    };
    const auto calibration_start = std::chrono::steady_clock::now();
    const PairCalibrationResult result = calibrate(s.planting, "");
    r.calibration_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - calibration_start).count();
    if (const auto effects = result.timings.find("effects"); effects != result.timings.end())
      r.effects_seconds = effects->second;
    r.detected = result.effects.detected();
    const std::vector<std::string> planted_names = plantedNames(effect);
    r.hit = std::all_of(planted_names.begin(), planted_names.end(), [&](const std::string& name) {
      return std::find(r.detected.begin(), r.detected.end(), name) != r.detected.end();
    });
    if (isClean(effect)) r.hit = r.detected.empty();
    r.exact = r.hit && r.detected.size() == planted_names.size();
    r.rmse = rmse(result.fits.at("G").inverse_crf);
    const auto& base_phi = (result.base_fits.empty() ? result.fits : result.base_fits).at("G").inverse_crf;
    r.rmse_base = rmse(base_phi);
    IntensityRange measured = coveredBelow(result, planted.plateau_intensity);
    // The reported and base fits' shape over `measured` (narrowed to the twin's covered range first, when there is one).
    const auto scoreShapes = [&] {
      r.shape = shapeError(truth, result.fits.at("G").inverse_crf, measured);
      r.shape_base = shapeError(truth, base_phi, measured);
    };
    if (isClean(effect)) {
      r.rmse_clean = r.rmse_base;
      scoreShapes();
      r.shape_clean = r.shape_base;
    } else {
      PlantingOptions clean = s.planting;
      clean.effect = "none";
      clean.second_effect = "none";
      // With a plateau, nothing above it is measurable: the twin gets the same measurable range (saturation at
      // the plateau), so that "clean-case accuracy" means the accuracy reachable from the same information.
      if (planted.plateau_intensity < 1)
        s.calibration.fit.saturation_high = std::min(s.calibration.fit.saturation_high, planted.plateau_intensity - 0.5 / 255);
      const PairCalibrationResult twin = calibrate(clean, "twin_");
      const auto& twin_phi = (twin.base_fits.empty() ? twin.fits : twin.base_fits).at("G").inverse_crf;
      r.rmse_clean = rmse(twin_phi);
      const IntensityRange twin_measured = coveredBelow(twin, planted.plateau_intensity);
      measured = {std::max(measured.first, twin_measured.first), std::min(measured.second, twin_measured.second)};
      scoreShapes();
      r.shape_clean = shapeError(truth, twin_phi, measured);
    }
    r.phi_ok = r.rmse <= r.rmse_clean + kPhiTolerance;
    r.shape_ok = r.shape <= r.shape_clean + kPhiTolerance;
    if (args.verbose) std::fprintf(stderr, "%s\n", result.effects.summary().c_str());
    if (args.verbose)
      for (const auto& w : result.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
  } catch (const std::exception& e) {
    r.error = e.what();
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

double quantile(std::vector<double> v, double q) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(q * (v.size() - 1) + 0.5)];
}

// Issue 18's cost target: the effect search no dearer than the rest of the calibration. Per planted pair, wall time
// of its effect stage over the rest of its calibratePair (cases run concurrently with --threads > 1 share the cores,
// so compare runs made with the same --threads).
std::string effectSearchCost(const std::vector<CaseResult>& results) {
  std::vector<double> ratios;
  double effects_total = 0, rest_total = 0;
  for (const auto& r : results) {
    const double rest = r.calibration_seconds - r.effects_seconds;
    if (!r.error.empty() || rest <= 0) continue;
    ratios.push_back(r.effects_seconds / rest);
    effects_total += r.effects_seconds;
    rest_total += rest;
  }
  if (ratios.empty()) return "";
  const long at_most_one = std::count_if(ratios.begin(), ratios.end(), [](double x) { return x <= 1; });
  char line[400];
  std::snprintf(line, sizeof line,
                "\nEffect search / rest of the calibration (wall time, planted pairs): median %.2fx, 90th percentile "
                "%.2fx, max %.2fx; at most 1x in %ld of %zu; in total %.1f s against %.1f s.\n",
                quantile(ratios, 0.5), quantile(ratios, 0.9), quantile(ratios, 1.0), at_most_one, ratios.size(),
                effects_total, rest_total);
  return line;
}

std::string range(const std::string& effect) {
  if (isClean(effect)) return "-";
  std::string out;
  for (const auto& name : plantedNames(effect)) {
    const double t = plantingThreshold(name);
    char buffer[64];
    std::snprintf(buffer, sizeof buffer, "%.3g–%.3g", t, 2 * t);
    out += (out.empty() ? "" : " + ") + std::string(buffer);
  }
  return out;
}

int runSweep(const Sources& src, const EffectsArgs& args, const std::vector<std::string>& effects) {
  std::ostringstream table;
  table << "| effect (ignored) | strength | cases | phi_G RMSE median | 90th pct | clean twin median | bias (median "
           "of RMSE − twin) |\n|---|---|---|---|---|---|---|\n";
  for (const auto& effect : effects) {
    if (isClean(effect)) continue;
    for (double factor : args.factors) {
      std::vector<double> rm, tw, diff;
      double strength = 0;
      for (int seed = 1; seed <= args.seeds; ++seed) {
        const CaseResult r = runCase(src, args, effect, seed, factor, false);
        strength = r.strength;
        if (!r.error.empty()) {
          std::fprintf(stderr, "%s seed %d: %s\n", effect.c_str(), seed, r.error.c_str());
          continue;
        }
        rm.push_back(r.rmse_base);
        tw.push_back(r.rmse_clean);
        diff.push_back(r.rmse_base - r.rmse_clean);
        std::fprintf(stderr, "sweep %-24s x%.2f seed %3d: rmse %.4f twin %.4f\n", effect.c_str(), factor, seed,
                     r.rmse_base, r.rmse_clean);
      }
      char line[400];
      std::snprintf(line, sizeof line, "| %s | %.4g (%.2g x threshold) | %zu | %.4f | %.4f | %.4f | %+.4f |\n",
                    effect.c_str(), strength, factor, rm.size(), median(rm), quantile(rm, 0.9), median(tw),
                    median(diff));
      table << line;
    }
  }
  std::printf("%s", table.str().c_str());
  return kExitOk;
}

// Planted × named: per planted label, in how many of its pairs each effect was named ("nothing": no effect named).
std::string confusionMatrix(const std::vector<std::string>& labels, const std::vector<CaseResult>& results) {
  const std::vector<std::string>& names = effectNames();
  std::ostringstream out;
  out << "\nConfusion matrix (rows: planted; columns: named; cells: pairs naming it / pairs):\n\n| planted |";
  for (const auto& n : names) out << ' ' << n << " |";
  out << " nothing |\n|---|";
  for (std::size_t i = 0; i <= names.size(); ++i) out << "---|";
  out << '\n';
  for (const auto& label : labels) {
    int n = 0, nothing = 0;
    std::vector<int> named(names.size(), 0);
    for (const auto& r : results) {
      if (r.effect != label || !r.error.empty()) continue;
      ++n;
      nothing += r.detected.empty();
      for (std::size_t i = 0; i < names.size(); ++i)
        named[i] += std::find(r.detected.begin(), r.detected.end(), names[i]) != r.detected.end();
    }
    out << "| " << label << " |";
    for (std::size_t i = 0; i < names.size(); ++i)
      out << ' ' << (isPlanted(label, names[i]) ? "**" : "") << named[i] << '/' << n
          << (isPlanted(label, names[i]) ? "**" : "") << " |";
    out << ' ' << nothing << '/' << n << " |\n";
  }
  out << "\n(bold: the planted effects.)\n";
  return out.str();
}

// The rows to run: --effect as given, the two-effect pairs with --two-effects, else clean pairs and every effect.
// Unknown names are refused here, before any work.
std::vector<std::string> effectsToRun(const EffectsArgs& args) {
  std::vector<std::string> effects = args.effects;
  if (effects.empty() && args.two_effects) effects = kEffectPairs;
  if (effects.empty()) {
    effects.push_back("none");
    effects.push_back(kNoneEstimated);
    for (const auto& n : effectNames()) effects.push_back(n);
  }
  for (auto& e : effects) {
    if (e == "none-estimated") e = kNoneEstimated;
    for (const auto& name : plantedNames(e)) plantingThreshold(name);  // unknown names: one-line error
  }
  return effects;
}

// Every (effect, seed) case is independent: run them `threads` at a time; the results come back in case order, so
// the table does not depend on the thread count (the progress lines come in completion order).
std::vector<CaseResult> runEffectCases(const Sources& src, const EffectsArgs& args,
                                       const std::vector<std::string>& effects, PairsOutput* pairs_out) {
  std::vector<std::pair<std::string, int>> cases;
  for (const auto& effect : effects)
    for (int seed = 1; seed <= args.seeds; ++seed) cases.emplace_back(effect, seed);
  std::vector<CaseResult> results(cases.size());
  std::mutex print;
  const int threads = std::max(1, std::min(args.threads, static_cast<int>(cases.size())));
  cv::parallel_for_(cv::Range(0, static_cast<int>(cases.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const auto& [effect, seed] = cases[static_cast<std::size_t>(i)];
      const CaseResult r = runCase(src, args, effect, seed, 0, true, pairs_out);
      std::string names;
      for (const auto& d : r.detected) names += (names.empty() ? "" : ",") + d;
      {
        const std::lock_guard<std::mutex> lock(print);
        std::fprintf(stderr,
                     "%-24s seed %3d strength %.4g: detected [%s] %s rmse %.4f (base %.4f, clean twin %.4f), shape "
                     "%.4f (base %.4f, twin %.4f) %.1f s%s\n",
                     effect.c_str(), seed, r.strength, names.c_str(), r.exact ? "OK" : "WRONG", r.rmse, r.rmse_base,
                     r.rmse_clean, r.shape, r.shape_base, r.shape_clean, r.seconds,
                     r.error.empty() ? "" : (" error: " + r.error).c_str());
      }
      results[static_cast<std::size_t>(i)] = r;
    }
  }, threads > 1 ? static_cast<double>(cases.size()) : 1.0);
  return results;
}

nlohmann::json caseJson(const CaseResult& r) {
  return {{"effect", r.effect}, {"seed", r.seed}, {"strength", r.strength}, {"form", r.form},
          {"detected", r.detected}, {"hit", r.hit}, {"exact", r.exact}, {"phi_rmse", r.rmse},
          {"phi_rmse_base", r.rmse_base},
          {"phi_rmse_clean_twin", r.rmse_clean}, {"phi_ok", r.phi_ok}, {"phi_shape", r.shape},
          {"phi_shape_base", r.shape_base}, {"phi_shape_clean_twin", r.shape_clean},
          {"shape_ok", r.shape_ok}, {"seconds", r.seconds},
          {"calibration_seconds", r.calibration_seconds}, {"effects_seconds", r.effects_seconds},
          {"error", r.error}};
}

// One row of the summary table: the cases of one planted effect (or pair of effects).
std::string effectRow(const std::string& effect, const std::vector<CaseResult>& results) {
  int n = 0, hit = 0, exact = 0, others = 0, ok = 0, shape_ok = 0, errors = 0;
  std::vector<double> rm, rb, rc, sm, sb, sc;
  double secs = 0;
  for (const auto& r : results) {
    if (r.effect != effect) continue;
    ++n;
    hit += r.hit;
    exact += r.exact;
    ok += r.phi_ok;
    shape_ok += r.shape_ok;
    for (const auto& d : r.detected)
      if (!isPlanted(effect, d)) ++others;
    if (r.error.empty()) {
      rm.push_back(r.rmse);
      rb.push_back(r.rmse_base);
      rc.push_back(r.rmse_clean);
      sm.push_back(r.shape);
      sb.push_back(r.shape_base);
      sc.push_back(r.shape_clean);
    } else {
      ++errors;
    }
    secs += r.seconds;
  }
  char line[600];
  std::snprintf(line, sizeof line,
                "| %s | %s | %d%s | %d (%.0f %%) | %d (%.0f %%) | %d | %d (%.0f %%) | %.4f | %.4f | %.4f | "
                "%d (%.0f %%) | %.4f | %.4f | %.4f | %.1f |\n",
                effect.c_str(), range(effect).c_str(), n,
                errors ? (" (" + std::to_string(errors) + " failed)").c_str() : "", hit, 100.0 * hit / std::max(1, n),
                exact, 100.0 * exact / std::max(1, n), others, ok, 100.0 * ok / std::max(1, n), median(rm),
                median(rb), median(rc), shape_ok, 100.0 * shape_ok / std::max(1, n), median(sm), median(sb),
                median(sc), secs / std::max(1, n));
  return line;
}

int runEffects(const EffectsArgs& args) {
  std::vector<fs::path> inputs(args.photos.begin(), args.photos.end());
  const io::OutputPolicy policy{"bench effects", inputs, args.force};
  if (!args.json.empty()) io::checkJsonOutputFile(args.json, policy);  // before the computation
  std::optional<PairsOutput> pairs_out;  // refused or unwritable: fails now
  if (!args.pairs_out.empty()) pairs_out.emplace(args.pairs_out, policy);
  Sources src = args.photos.empty() ? loadSources() : loadPhotos(args.photos, loadSources());
  if (args.sharp_noise == "sensor" || (args.sharp_noise == "auto" && args.ratio > 0))
    src.noise_camera = io::readCameraNoiseProfile(
        args.noise_profiles.empty() ? io::defaultNoiseProfiles() : fs::path(args.noise_profiles), args.noise_camera);
  const std::vector<std::string> effects = effectsToRun(args);
  if (args.sweep) return runSweep(src, args, effects);
  const std::vector<CaseResult> results = runEffectCases(src, args, effects, pairs_out ? &*pairs_out : nullptr);
  std::ostringstream table;
  if (src.noise_camera) table << "sharp shot: sensor noise of " << src.noise_camera->summary() << "\n\n";
  table << "| planted effect | strength range | cases | detected (right name) | exactly right (no other) | "
           "false names | phi ok (<= twin + 0.005) | phi_G RMSE median: reported | base | clean twin | "
           "shape ok (<= twin + 0.005) | phi_G shape median: reported | base | clean twin | s/case |\n"
           "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  nlohmann::json json = nlohmann::json::array();
  for (const auto& effect : effects) {
    for (const auto& r : results)
      if (r.effect == effect) json.push_back(caseJson(r));
    table << effectRow(effect, results);
  }
  table << "\n('none' rows: 'detected' = no effect reported; 1 − that is the false-alarm rate. 'none (kernel "
           "estimated)': clean pairs through the kernel-estimating path, where spatially_varying_blur is tested.)\n";
  table << confusionMatrix(effects, results) << effectSearchCost(results);
  std::printf("%s", table.str().c_str());
  if (pairs_out) {
    if (pairs_out->first_error) std::rethrow_exception(pairs_out->first_error);
    pairs_out->directory.commit();
  }
  if (!args.json.empty())
    io::writeJsonOutput(args.json,
                        {{"cases", json}, {"form", args.form}, {"ratio", args.ratio}, {"jpeg_quality", args.jpeg_quality},
                         {"handheld", args.handheld},
                         {"sharp_noise",
                          src.noise_camera ? "sensor: " + src.noise_camera->summary() : std::string("intensity")}},
                        policy.command);
  return kExitOk;
}

const BenchRegistration registration(
    60, "effects",
    "Detection / false-alarm rates of the residual effect diagnostics on pairs with one planted effect",
    [](CLI::App& command) {
      auto args = std::make_shared<EffectsArgs>();
      command.add_option("--effect", args->effects,
                         "Effects to plant (default: none, none-estimated (clean, kernel estimated) and every effect)");
      command.add_option("--seeds", args->seeds, "Pairs per effect (per strength with --sweep)")
          ->check(CLI::Range(1, 10000));
      command.add_option("--min-gain", args->min_gain, "EffectOptions::min_gain (relative held-out drop)");
      command.add_option("--min-z", args->min_z, "EffectOptions::min_z (paired block test)");
      command.add_option("--phi-terms", args->phi_terms, "EffectOptions::phi_terms (EMoR curves phi is re-fitted by)")
          ->check(CLI::Range(0, 10));
      command.add_option("--min-noise-contrast", args->min_noise_contrast,
                         "EffectOptions::min_noise_contrast (noise variance contrast over the levels)");
      command.add_option("--refit-rounds", args->refit_rounds,
                         "EffectOptions::refit_rounds (correct, refit, re-estimate rounds; caps the settle rounds)")
          ->check(CLI::Range(1, 10));
      command.add_flag("--sweep", args->sweep,
                       "Instead: the phi bias of each effect when ignored (effects off), per strength factor");
      command.add_option("--factors", args->factors, "--sweep: strengths as multiples of the threshold");
      command.add_option("--json", args->json, "Write the per-case results here ({\"cases\": [...]})");
      command.add_flag("--force", args->force, kForceHelp);
      command.add_flag("-v,--verbose", args->verbose, "Print every case's effect table");
      command.add_option("--threads", args->threads, "Cases in parallel")->check(CLI::Range(1, kMaxThreads));
      command.add_option("--form", args->form,
                         "detector: each effect in its detector's own model form; held-out: other physical forms "
                         "(cos^4 vignetting in either shot, per-channel offsets or a flare veil, a camera colour matrix, "
                         "a highlight knee, rotation or depth-scaled blur)")
          ->check(CLI::IsMember({"detector", "held-out"}))
          ->capture_default_str();
      command.add_flag("--two-effects", args->two_effects,
                       "Plant pairs of effects (default list; or --effect a+b)");
      command.add_option("--ratio", args->ratio,
                         "Real regime: r drawn in [0.9, 1.1] x this, the sharp shot underexposed by r (default: r in "
                         "[0.8, 1.4])")
          ->check(CLI::Range(1.0, 16.0));
      command.add_option("--jpeg", args->jpeg_quality, "Both shots through a 4:2:0 JPEG of this quality (0: off)")
          ->check(CLI::Range(0, 100));
      command.add_option("--photo", args->photos,
                         "Scenes instead of the bundled Levin mosaics and window photo (longest side 512 px; the first "
                         "also serves as the colour scene)")
          ->check(CLI::ExistingFile);
      command.add_option("--sharp-noise", args->sharp_noise,
                         "The sharp shot's noise: intensity (the seed's Gaussian noise on I), sensor (a camera's "
                         "measured raw noise at the short shot's ISO, lowest ISO x r, on its irradiance before the "
                         "curve) or auto (sensor with --ratio, the real regime; else intensity)")
          ->check(CLI::IsMember({"auto", "intensity", "sensor"}))
          ->capture_default_str();
      command.add_option("--noise-camera", args->noise_camera,
                         "--sharp-noise sensor: camera whose darktable noise profile the sharp shot gets, "
                         "\"maker model\"")
          ->capture_default_str();
      command.add_option("--noise-profiles", args->noise_profiles,
                         "--sharp-noise sensor: darktable noiseprofiles.json (default: the shared data's, else the "
                         "bundled excerpt samples/noise_profiles/)")
          ->check(CLI::ExistingFile);
      command.add_flag("--handheld", args->handheld,
                       "Handheld misregistration: B shifted 2-4 px and turned by up to 0.3 degrees; registration on");
      command.add_option("--pairs-out", args->pairs_out,
                         "Also write every case's pair as calibrated (PNG, after the JPEG round trip; twin_*.png its "
                         "clean twin), kernel.txt and truth.json here, one directory per case (EFFECT_seedN)");
      return [args] { return runEffects(*args); };
    });

}  // namespace
}  // namespace crfcal::app
