// crfcal bench synthetic: runs the seed's Sec. 5 protocol (10 camera CRFs ×
// 8 Levin kernels × 3 noise variances on I = 240 cases) for the seed's method as published and for crfcal's
// fitter, and prints the table the seed printed (mean φ RMSE 0.0155 / 0.0137 / 0.0169) beside ours.
#include <algorithm>
#include <atomic>
#include <optional>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <numeric>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "bench_command.hpp"
#include "command.hpp"
#include "option_checks.hpp"
#include "crfcal/blur_model.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_estimation.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/simex.hpp"
#include "crfcal/simulation.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/curve_prior_io.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/io/response_io.hpp"
#include "progress.hpp"

namespace fs = std::filesystem;

namespace crfcal::app {
namespace {

// ------------------------------------------------------------------------------------------------------------
// bench synthetic

constexpr double kSeedMean[3] = {0.0155, 0.0137, 0.0169};  // Sec. 5, mean φ RMSE at σ² = 0.001, 0.005, 0.01
double kNoiseVariances[3] = {0.001, 0.005, 0.01};

struct SyntheticArgs {
  std::vector<std::string> images;
  std::string curves;
  std::string json;
  std::string plot;
  std::string method = "both";
  std::vector<std::string> variants;
  int cases_limit = 0;
  std::vector<double> noise_vars;
  std::string noise_units = "unit";  // unit: I in [0,1], the seed's Sec. 5; 8bit: levels² (÷ 255²), noise-free control
  int threads = 2;
  double ratio = 1.0;
  bool quiet = false;
  bool timing = true;
  bool curve_split = false;  // print the means on the even- and odd-numbered curves (choose / held out)
  bool force = false;  // --json/-o over files crfcal did not write (never deletes them)
};

struct Curve {
  std::string name;
  std::vector<double> phi;  // 1024 samples
  // The top of the x range the curve's own data measure (its table's "data cover x in [lo, hi]" header; 1 for the
  // stand-ins, which are exact everywhere): above it the truth is itself an extrapolation.
  double measured_top = 1;
  // The learned prior (calib/learned_curve_prior.hpp) from every other curve of the set: what a variant with
  // `learned_prior_loco` fits this curve's pairs with, so no curve's pairs see a prior that saw the curve.
  std::shared_ptr<const LearnedCurvePrior> prior_without_this{};
};

struct Variant {
  std::string name;
  std::string description;
  CrfFitOptions options;
  bool true_sigma = false;  // oracle σ (ablation only)
  std::optional<SimexOptions> simex{};  // set: SIMEX around the fit (calib/include/crfcal/simex.hpp)
  // > 0: the variant's options only when I's estimated noise σ̂ is below this many 8-bit levels, else the
  // default's (the corrected score pays at σ ≈ 8 levels and costs at 18–25: docs/RESULTS.md, issue 23)
  double below_sigma_levels = 0;
  double above_sigma_levels = 0;  // and (when > 0) only when σ̂ is above this many levels
  // The fit gets the learned prior of the other curves (Curve::prior_without_this): leave one camera out.
  bool learned_prior_loco = false;
};

// The options one fit of variant v uses on a pair whose sharp shot is `sharp` (CV_64F in [0, 1]).
CrfFitOptions variantOptions(const Variant& v, const cv::Mat& sharp) {
  if (!(v.below_sigma_levels > 0) && !(v.above_sigma_levels > 0)) return v.options;
  const double sigma = estimateNoiseSigma(sharp).sigma;  // the estimate the fitter makes itself
  const bool below = !(v.below_sigma_levels > 0) || sigma * 255 < v.below_sigma_levels;
  const bool above = sigma * 255 > v.above_sigma_levels;
  CrfFitOptions options = below && above ? v.options : CrfFitOptions{};
  options.noise_sigma = sigma;
  return options;
}

std::vector<Variant> allVariants() {
  std::vector<Variant> v;
  const CrfFitOptions seed = CrfFitOptions::seed();
  v.push_back({"seed", "seed as published: Eq. 22, Gamma weights, GGCM n=4, Nelder-Mead, noisy I as is", seed});
  CrfFitOptions s = seed;
  s.experimental.noise = NoiseHandling::denoise;
  v.push_back({"seed+denoise", "seed + bilateral denoising of I (sigma estimated)", s});
  s = seed;
  s.experimental.noise = NoiseHandling::debias;
  v.push_back({"seed+debias", "seed + debiased level functions g = R phi in the mixtures (sigma estimated)", s});
  s = seed;
  s.fit_ratio = false;
  v.push_back({"seed-fixr", "seed with r fixed at its initial value (no Eq. 25)", s});
  CrfFitOptions d;
  d.experimental.noise = NoiseHandling::debias;
  v.push_back({"moments+debias", "default + debiased level functions g = R phi (sigma estimated; Tikhonov deconvolution)", d});
  d.experimental.variance_correction = true;
  v.push_back({"moments+debias+cue", "default + debias + continuously-updated GMM variances", d});
  d = CrfFitOptions{};
  d.experimental.variance_correction = true;
  v.push_back({"moments+cue", "default + continuously-updated GMM variances (no debias)", d});
  d = CrfFitOptions{};
  d.experimental.noise = NoiseHandling::denoise;
  v.push_back({"moments+denoise", "default on a bilateral-denoised I", d});
  d = CrfFitOptions{};
  d.position_bins = 1;
  v.push_back({"moments-1pos", "default with B-level bins only (no local min/max instruments)", d});
  SimexOptions simex;
  v.push_back({"simex", "default + SIMEX: refits at added noise 0.5-2 sigma^2 (2 draws each), quadratic back to zero noise",
               CrfFitOptions{}, false, simex});
  simex.extrapolation_degree = 1;
  v.push_back({"simex-linear", "default + SIMEX with a linear extrapolation", CrfFitOptions{}, false, simex});
  d.position_bins = 8;
  v.push_back({"moments-8pos", "default with 8x8 local min/max bins per B level", d});
  d = CrfFitOptions{};
  v.push_back({"default", "crfcal default: binned B-instrument moments (B level x local min/max of B), EMoR/GGCM by 2-fold CV", d});
  v.push_back({"default+true-sigma", "crfcal default with the true sigma (oracle)", d, true});
  d.model = CrfModelChoice::ggcm;
  v.push_back({"default-ggcm", "crfcal default, GGCM only", d});
  d.model = CrfModelChoice::emor;
  v.push_back({"default-emor", "crfcal default, EMoR only", d});
  d = CrfFitOptions{};
  d.model = CrfModelChoice::ggcm;
  d.experimental.optimizer = CrfOptimizer::nelder_mead;
  v.push_back({"default-ggcm-nm", "crfcal default objective, GGCM only, Nelder-Mead (r profiled) instead of LM", d});
  d = CrfFitOptions{};
  d.fit_ratio = false;
  v.push_back({"default-fixr", "crfcal default with r fixed at its initial value", d});
  Variant learned{"learned-loco", "crfcal default + the learned prior of the other cameras' curves (calibrate --shoulder learned; leave one camera out)",
                  CrfFitOptions{}};
  learned.learned_prior_loco = true;
  v.push_back(learned);
  return v;
}

std::vector<Curve> loadCurves(const std::string& dir_arg, bool& stand_ins) {
  std::vector<Curve> curves;
  const fs::path dir = dir_arg.empty() ? io::samplesDirectory() / "camera_curves" : fs::path(dir_arg);
  stand_ins = false;
  if (fs::is_directory(dir)) {
    std::vector<fs::path> files;
    for (const auto& entry : fs::directory_iterator(dir))
      if (entry.path().extension() == ".csv") files.push_back(entry.path());
    std::sort(files.begin(), files.end());
    for (const auto& f : files) {
      const auto coverage = io::readCurveTableCoverage(f);
      curves.push_back({f.stem().string(), io::readCurveTable(f), coverage ? coverage->second : 1.0});
    }
  }
  if (curves.empty()) {  // stand-ins: γ curves and EMoR curves
    stand_ins = true;
    for (double g : {1.8, 2.2, 2.6}) curves.push_back({"gamma" + std::to_string(g).substr(0, 3), sampleInverse(GammaModel{g})});
    const std::vector<std::vector<double>> coeffs{{0.3, -0.2}, {-0.5, 0.1}, {0.8, 0.2, -0.1}, {-0.2, -0.3}, {0.5, 0.0, 0.2},
                                                  {-0.8, 0.3}, {0.1, 0.4}};
    int i = 0;
    for (const auto& c : coeffs) curves.push_back({"emor" + std::to_string(i++), sampleInverse(EmorModel{c})});
  }
  if (curves.size() > 10) curves.resize(10);
  return curves;
}

// Shape error: RMSE over x ∈ [0, kShapeLimit] after the best common factor s (min ‖s·φ̂ − φ‖). The φ(1) = 1
// normalisation ties the whole curve to its steep highlight shoulder above ≈ 0.9, the part of a camera curve
// that a noisy sharp image informs least; this separates the shape from that normalisation.
constexpr double kShapeLimit = 0.9;
double shapeRmse(const std::vector<double>& estimate, const std::vector<double>& truth) {
  const int n = static_cast<int>(truth.size());
  const int m = static_cast<int>(std::floor(kShapeLimit * (n - 1))) + 1;
  double ee = 0, et = 0;
  for (int i = 0; i < m; ++i) ee += estimate[i] * estimate[i], et += estimate[i] * truth[i];
  const double s = ee > 0 ? et / ee : 1.0;
  double sum = 0;
  for (int i = 0; i < m; ++i) sum += (s * estimate[i] - truth[i]) * (s * estimate[i] - truth[i]);
  return std::sqrt(sum / m);
}

// RMSE of φ as it is (φ(1) = 1 normalisation included) over the samples with x ≤ top (`below`) or x > top.
double rangeRmse(const std::vector<double>& estimate, const std::vector<double>& truth, double top, bool below) {
  const int n = static_cast<int>(truth.size());
  double sum = 0;
  int count = 0;
  for (int i = 0; i < n; ++i) {
    if ((double(i) / (n - 1) <= top) != below) continue;
    sum += (estimate[i] - truth[i]) * (estimate[i] - truth[i]);
    ++count;
  }
  return count > 0 ? std::sqrt(sum / count) : 0.0;
}

struct CaseResult {
  int curve = 0, kernel = 0, level = 0, image = 0;
  // rmse over [0, 1]; measured / top: the same over the part of the truth its data measure and above it.
  std::map<std::string, double> rmse, seconds, shape, measured, top;
  std::map<std::string, std::vector<double>> phi;
  std::map<std::string, std::string> chosen;
  double sigma_true = 0, sigma_est = 0;
};

struct Stats {
  double mean = 0, median = 0, max = 0, seconds = 0;
  int n = 0;
};
Stats stats(std::vector<double> v, double seconds) {
  Stats s;
  s.n = static_cast<int>(v.size());
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  s.mean = std::accumulate(v.begin(), v.end(), 0.0) / v.size();
  s.median = v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  s.max = v.back();
  s.seconds = seconds / v.size();
  return s;
}

double since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// The inputs every case of `bench synthetic` shares, loaded once before the cases run.
struct SyntheticCase {
  int curve, kernel, level, image;
};

struct SyntheticSetup {
  double variance_scale = 1.0;  // the --noise-units factor applied to kNoiseVariances
  bool stand_ins = false;       // true when samples/camera_curves was absent
  std::vector<Curve> curves;
  std::vector<cv::Mat> images;
  std::vector<cv::Mat> kernels;  // Levin kernels 1..8
  std::vector<Variant> variants;
  std::vector<SyntheticCase> cases;
};

// `corrected-score[:lambda=X][:ridge][:bins=N][:cue][:below=S][:above=S]`: the corrected score (Nakamura 1990;
// Stefanski 1989) — φ evaluated at the noisy I replaced by h = R φ with E[h(clip(I + n))] = φ(I) under the
// clipped, quantised noise law (noise_debias.hpp) — with its regularisation λ (relative, default 1e-4), ridge
// instead of the smoothness penalty, N B-level bins instead of 64, and the CUE variances. Used to choose λ on some curves and
// report on others (docs/RESULTS.md, "Corrected score, measured"). `:below=S`, `:above=S`: only when I's estimated
// σ is below / above S 8-bit levels, else the default.
std::optional<Variant> correctedScoreVariant(const std::string& name) {
  const std::string stem = "corrected-score";
  if (name.rfind(stem, 0) != 0) return std::nullopt;
  Variant v{name, "corrected score h = R phi (clipped noise law)", CrfFitOptions{}};
  v.options.experimental.noise = NoiseHandling::debias;
  std::size_t pos = stem.size();
  while (pos < name.size()) {
    if (name[pos] != ':') throw InvalidInput("bench: bad variant '" + name + "' (options follow ':')");
    const std::size_t end = std::min(name.find(':', pos + 1), name.size());
    const std::string part = name.substr(pos + 1, end - pos - 1);
    try {
      if (part.rfind("lambda=", 0) == 0) v.options.experimental.debias_regularization = std::stod(part.substr(7));
      else if (part == "ridge") v.options.experimental.debias_regularizer = DebiasRegularizer::ridge;
      else if (part.rfind("bins=", 0) == 0) v.options.level_bins = std::stoi(part.substr(5));
      else if (part == "cue") v.options.experimental.variance_correction = true;
      else if (part.rfind("below=", 0) == 0) v.below_sigma_levels = std::stod(part.substr(6));
      else if (part.rfind("above=", 0) == 0) v.above_sigma_levels = std::stod(part.substr(6));
      else throw InvalidInput("");
    } catch (const std::exception&) {
      throw InvalidInput("bench: bad option '" + part + "' of variant '" + name +
                         "' (lambda=X, ridge, bins=N, cue, below=S, above=S)");
    }
    v.description += ", " + part;
    pos = end;
  }
  v.options.check();
  return v;
}

Variant findVariant(const std::vector<Variant>& all, const std::string& name) {
  for (const auto& v : all)
    if (v.name == name) return v;
  if (auto v = correctedScoreVariant(name)) return *v;
  throw InvalidInput("bench: unknown variant '" + name + "'");
}

std::vector<Variant> selectVariants(const SyntheticArgs& args) {
  std::vector<Variant> variants;
  const auto all = allVariants();
  if (args.method == "seed" || args.method == "both") variants.push_back(findVariant(all, "seed"));
  if (args.method == "default" || args.method == "both") variants.push_back(findVariant(all, "default"));
  for (const auto& name : args.variants)
    if (std::none_of(variants.begin(), variants.end(), [&](const Variant& v) { return v.name == name; }))
      variants.push_back(findVariant(all, name));
  return variants;
}

// Every (curve, kernel, level) with the latent image rotating over them; --cases keeps a subset spread over all.
std::vector<SyntheticCase> buildCases(const SyntheticArgs& args, int curve_count, int image_count) {
  std::vector<SyntheticCase> cases;
  for (int level = 0; level < 3; ++level)
    for (int c = 0; c < curve_count; ++c)
      for (int k = 0; k < 8; ++k) cases.push_back({c, k, level, (c + k) % image_count});
  if (args.cases_limit > 0 && args.cases_limit < static_cast<int>(cases.size())) {
    // spread the subset over curves, kernels and levels
    std::vector<SyntheticCase> subset;
    const double step = double(cases.size()) / args.cases_limit;
    for (int i = 0; i < args.cases_limit; ++i) subset.push_back(cases[static_cast<std::size_t>(i * step)]);
    cases = subset;
  }
  return cases;
}

SyntheticSetup loadSetup(const SyntheticArgs& args) {
  SyntheticSetup setup;
  if (args.noise_vars.size() == 3)
    for (int i = 0; i < 3; ++i) kNoiseVariances[i] = args.noise_vars[i];
  setup.variance_scale = args.noise_units == "8bit" ? 1.0 / (255.0 * 255.0) : 1.0;
  setup.curves = loadCurves(args.curves, setup.stand_ins);
  std::vector<std::string> image_paths = args.images;
  if (image_paths.empty())
    for (int i = 1; i <= 4; ++i) image_paths.push_back((io::samplesDirectory() / "levin09" / ("im" + std::to_string(i) + ".png")).string());
  for (const auto& p : image_paths) setup.images.push_back(io::readGrayUnit(p));
  for (int k = 1; k <= 8; ++k) setup.kernels.push_back(io::kernelFromSpec("levin:" + std::to_string(k)));
  setup.variants = selectVariants(args);
  if (std::any_of(setup.variants.begin(), setup.variants.end(), [](const Variant& v) { return v.learned_prior_loco; })) {
    if (setup.stand_ins) throw InvalidInput("bench: the learned prior needs camera curves (samples/camera_curves or --curves)");
    const fs::path dir = args.curves.empty() ? io::samplesDirectory() / "camera_curves" : fs::path(args.curves);
    for (Curve& c : setup.curves) c.prior_without_this = io::learnPriorFromCameraCurves({c.name}, dir);
  }
  setup.cases = buildCases(args, static_cast<int>(setup.curves.size()), static_cast<int>(setup.images.size()));
  return setup;
}

// One variant's fit of one simulated pair, scored against the true curve.
void fitVariant(const Variant& v, const SimulationResult& pair, const cv::Mat& kernel, const Curve& true_curve,
                CaseResult& out) {
  const std::vector<double>& truth = true_curve.phi;
  const auto score = [&](const std::vector<double>& phi) {
    out.rmse[v.name] = curveRmse(phi, truth);
    out.shape[v.name] = shapeRmse(phi, truth);
    out.measured[v.name] = rangeRmse(phi, truth, true_curve.measured_top, true);
    out.top[v.name] = rangeRmse(phi, truth, true_curve.measured_top, false);
  };
  const auto t0 = std::chrono::steady_clock::now();
  CrfFitOptions options = variantOptions(v, pair.sharp);
  options.threads = 1;
  if (v.true_sigma) options.noise_sigma = out.sigma_true;
  if (v.learned_prior_loco) options.learned_prior = true_curve.prior_without_this;
  try {
    const CrfFitResult fit = v.simex ? fitInverseCrfSimex(pair.sharp, pair.blurred, kernel, options, *v.simex)
                                     : fitInverseCrf(pair.sharp, pair.blurred, kernel, options);
    out.seconds[v.name] = since(t0);
    score(fit.inverse_crf);
    out.phi[v.name] = fit.inverse_crf;
    out.chosen[v.name] = fit.chosen;
    if (v.name == "default") out.sigma_est = fit.noise_sigma;
  } catch (const InvalidInput&) {
    // a rejected pair (e.g. too few usable pixels): counted, scored as the gamma 2.2 curve
    out.seconds[v.name] = since(t0);
    const auto fallback = sampleInverse(GammaModel{2.2});
    score(fallback);
    out.phi[v.name] = fallback;
    out.chosen[v.name] = "rejected";
  }
}

// The cases, run in parallel: each simulates its pair and fits it with every variant.
struct SyntheticRun {
  const SyntheticArgs& args;
  const SyntheticSetup& setup;
  Progress& progress;
  std::vector<CaseResult> results;
  std::atomic<int> done{0};
  std::mutex progress_mutex;
  std::string failure;  // the last case's exception text, if any failed

  SyntheticRun(const SyntheticArgs& a, const SyntheticSetup& s, Progress& p) : args(a), setup(s), progress(p) {}

  void runCase(int i) {
    const SyntheticCase& cs = setup.cases[i];
    CaseResult& out = results[i];
    out.curve = cs.curve;
    out.kernel = cs.kernel;
    out.level = cs.level;
    out.image = cs.image;
    try {
      SimulationOptions sim;
      sim.noise_variance = kNoiseVariances[cs.level] * setup.variance_scale;
      sim.ratio = args.ratio;
      sim.seed = 1000003ULL * (cs.curve + 1) + 1009ULL * (cs.kernel + 1) + cs.level + 1;
      const ResponseModel truth = TableModel{setup.curves[cs.curve].phi};
      const SimulationResult pair = simulatePair(setup.images[cs.image], truth, setup.kernels[cs.kernel], sim);
      out.sigma_true = std::sqrt(sim.noise_variance);
      for (const Variant& v : setup.variants)
        fitVariant(v, pair, setup.kernels[cs.kernel], setup.curves[cs.curve], out);
    } catch (const std::exception& e) {
      std::lock_guard lock(progress_mutex);
      failure = e.what();
    }
    const int n = ++done;
    std::lock_guard lock(progress_mutex);
    progress.update(double(n) / setup.cases.size(), std::to_string(n) + "/" + std::to_string(setup.cases.size()));
  }

  // Returns the wall time in seconds.
  double runAll() {
    results.assign(setup.cases.size(), CaseResult{});
    progress.stage("bench synthetic: " + std::to_string(setup.cases.size()) + " cases x " +
                   std::to_string(setup.variants.size()) + " methods");
    const auto t_all = std::chrono::steady_clock::now();
    cv::parallel_for_(
        cv::Range(0, static_cast<int>(setup.cases.size())),
        [this](const cv::Range& range) {
          for (int i = range.start; i < range.end; ++i) runCase(i);
        },
        std::max(1, args.threads) == 1 ? 1.0 : static_cast<double>(setup.cases.size()));
    const double wall = since(t_all);
    progress.done();
    if (!failure.empty()) throw Error("bench synthetic: a case failed: " + failure);
    return wall;
  }
};

std::string curveNames(const std::vector<Curve>& curves) {
  std::string s;
  for (const auto& c : curves) s += (s.empty() ? "" : ", ") + c.name;
  return s;
}

void printSyntheticHeader(const SyntheticArgs& args, const SyntheticSetup& setup, double wall) {
  std::printf("crfcal bench synthetic - seed Sec. 5 protocol: %zu CRFs x 8 Levin kernels x 3 noise variances on I "
              "(%zu cases), %zu latent image(s)\n",
              setup.curves.size(), setup.cases.size(), setup.images.size());
  std::printf("curves: %s%s\n", setup.stand_ins ? "STAND-INS (samples/camera_curves absent): " : "",
              curveNames(setup.curves).c_str());
  const double to_levels = args.noise_units == "8bit" ? 1.0 : 255.0;  // σ in 8-bit levels
  std::printf("noise: Gaussian on I with the variances below %s (sigma %.2g to %.2g of 255 levels)\n",
              args.noise_units == "8bit" ? "in 8-bit levels^2 (I in [0,255])" : "for I in [0,1]",
              std::sqrt(*std::min_element(kNoiseVariances, kNoiseVariances + 3)) * to_levels,
              std::sqrt(*std::max_element(kNoiseVariances, kNoiseVariances + 3)) * to_levels);
  std::printf("error: RMSE of phi over 1024 points of [0,1]; wall time %.1f s on %d thread(s)\n\n", wall, args.threads);
  std::printf("%-20s %9s %9s %9s %9s %9s %10s %9s %9s %9s\n", "method", "noise var", "mean", "median", "max", "seed mean",
              "s/case", "shape", "measured", "top");
}

// One variant's row per noise level (printed), returned as the JSON "levels" array.
nlohmann::json printVariantRows(const Variant& v, const std::vector<CaseResult>& results) {
  nlohmann::json levels = nlohmann::json::array();
  for (int level = 0; level < 3; ++level) {
    std::vector<double> errs, shapes, measured, top;
    double secs = 0;
    for (const auto& r : results)
      if (r.level == level && r.rmse.count(v.name)) {
        errs.push_back(r.rmse.at(v.name));
        shapes.push_back(r.shape.at(v.name));
        measured.push_back(r.measured.at(v.name));
        top.push_back(r.top.at(v.name));
        secs += r.seconds.at(v.name);
      }
    if (errs.empty()) continue;
    const Stats s = stats(errs, secs);
    const auto average = [](const std::vector<double>& x) { return std::accumulate(x.begin(), x.end(), 0.0) / x.size(); };
    const double shape = average(shapes);
    std::printf("%-20s %9.3f %9.4f %9.4f %9.4f %9.4f %10.3f %9.4f %9.4f %9.4f\n", v.name.c_str(), kNoiseVariances[level],
                s.mean, s.median, s.max, kSeedMean[level], s.seconds, shape, average(measured), average(top));
    levels.push_back({{"noise_var", kNoiseVariances[level]}, {"mean_rmse", s.mean}, {"median_rmse", s.median},
                      {"max_rmse", s.max}, {"seconds_per_case", s.seconds}, {"cases", s.n},
                      {"mean_shape_rmse", shape}, {"mean_measured_rmse", average(measured)},
                      {"mean_top_rmse", average(top)}});
  }
  return levels;
}

// The table (printed) and the JSON summary of it, per case included; the GGCM floor is the best GGCM fit of
// each true curve.
nlohmann::json printSyntheticTable(const SyntheticArgs& args, const SyntheticSetup& setup,
                                   const std::vector<CaseResult>& results, double wall) {
  std::vector<double> floor_rmse;
  for (const auto& c : setup.curves) floor_rmse.push_back(ggcm::fitInverse(c.phi).rmse);
  const double floor_mean = std::accumulate(floor_rmse.begin(), floor_rmse.end(), 0.0) / floor_rmse.size();

  printSyntheticHeader(args, setup, wall);
  nlohmann::json json;
  json["cases"] = setup.cases.size();
  json["curves"] = nlohmann::json::array();
  for (const auto& c : setup.curves) json["curves"].push_back(c.name);
  json["stand_in_curves"] = setup.stand_ins;
  json["noise_units"] = args.noise_units;
  json["seed_published_mean_rmse"] = {kSeedMean[0], kSeedMean[1], kSeedMean[2]};
  json["ggcm_floor"] = {{"mean_rmse", floor_mean}, {"per_curve", floor_rmse}};
  json["wall_seconds"] = wall;
  for (const Variant& v : setup.variants) {
    const nlohmann::json levels = printVariantRows(v, results);
    if (v.name == "default") json["levels"] = levels;
    else if (v.name == "seed") json["seed_method"] = levels;
    json["variants"][v.name] = {{"description", v.description}, {"levels", levels}};
  }
  // Per case (for per-curve or paired comparisons of the variants).
  json["per_case"] = nlohmann::json::array();
  for (const auto& r : results)
    json["per_case"].push_back({{"curve", setup.curves[r.curve].name}, {"kernel", r.kernel + 1}, {"image", r.image + 1},
                                {"noise_var", kNoiseVariances[r.level]}, {"rmse", r.rmse}, {"shape_rmse", r.shape},
                                {"measured_rmse", r.measured}, {"top_rmse", r.top},
                                {"chosen", r.chosen}});
  std::printf("%-20s %9s %9.4f   (best GGCM fit of each true curve: the lower bound for GGCM fits)\n", "ggcm floor",
              "-", floor_mean);
  std::printf("shape: mean RMSE over x <= %.1f after the best common factor (phi's shape without the phi(1) = 1 "
              "normalisation)\n", kShapeLimit);
  std::printf("measured / top: mean RMSE of phi as it is over the x the true curve's own data measure (its table's "
              "'data cover' top) / above it, where the truth is itself extrapolated\n");
  return json;
}

// σ estimation accuracy, model choice and rejected pairs.
void printSigmaAndChoices(const std::vector<Variant>& variants, const std::vector<CaseResult>& results) {
  std::map<int, std::vector<double>> rel;
  std::map<std::string, int> chosen;
  for (const auto& r : results) {
    if (r.sigma_est > 0) rel[r.level].push_back(r.sigma_est / r.sigma_true);
    if (r.chosen.count("default")) ++chosen[r.chosen.at("default")];
  }
  for (auto& [level, v] : rel)
    std::printf("default: estimated/true noise sigma at var %.3f: mean %.3f\n", kNoiseVariances[level],
                std::accumulate(v.begin(), v.end(), 0.0) / v.size());
  for (auto& [kind, n] : chosen) std::printf("default: model chosen %s in %d cases\n", kind.c_str(), n);
  for (const Variant& v : variants) {
    int rejected = 0;
    for (const auto& r : results)
      if (r.chosen.count(v.name) && r.chosen.at(v.name) == "rejected") ++rejected;
    if (rejected) std::printf("%s: %d case(s) rejected by the fitter (scored as gamma 2.2)\n", v.name.c_str(), rejected);
  }
}

// Held-out split (issue 23): the mean φ RMSE of every variant per noise level on the even-numbered curves (where a
// variant's parameters are chosen) and on the odd-numbered ones (where it is reported).
void printCurveSplit(const SyntheticSetup& setup, const std::vector<CaseResult>& results) {
  std::printf("\ncurve split: mean RMSE (shape) on the even-numbered curves (choose) | on the odd-numbered (held out)\n");
  for (const Variant& v : setup.variants)
    for (int level = 0; level < 3; ++level) {
      double sum[2] = {0, 0}, shape[2] = {0, 0};
      int n[2] = {0, 0};
      for (const auto& r : results)
        if (r.level == level && r.rmse.count(v.name)) {
          const int part = r.curve % 2;
          sum[part] += r.rmse.at(v.name);
          shape[part] += r.shape.at(v.name);
          ++n[part];
        }
      if (n[0] + n[1] == 0) continue;
      auto mean = [](double a, int k) { return k ? a / k : 0.0; };
      std::printf("%-34s %9.3f   %.4f (%.4f, %d cases) | %.4f (%.4f, %d cases)\n", v.name.c_str(), kNoiseVariances[level],
                  mean(sum[0], n[0]), mean(shape[0], n[0]), n[0], mean(sum[1], n[1]), mean(shape[1], n[1]), n[1]);
    }
}

// Mean time of `reps` evaluations of a level mixture.
double timeMix(const LevelMixture& mixture, const std::vector<double>& lut, std::vector<double>& out, int reps) {
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < reps; ++i) mixture.mix(lut, out);
  return since(t0) / reps;
}

// Speed: sparse level mixture vs direct convolution, and one fit of a 512x384 pair with a 27x27 kernel.
void measureSpeed(const SyntheticSetup& setup, nlohmann::json& json) {
  const std::vector<Curve>& curves = setup.curves;
  cv::Mat big;
  cv::resize(setup.images[0], big, cv::Size(512, 384), 0, 0, cv::INTER_CUBIC);
  cv::min(cv::max(big, 0.0), 1.0, big);
  const cv::Mat k27 = io::kernelFromSpec("levin:4");
  SimulationOptions sim;
  sim.noise_variance = 0.005;
  const SimulationResult pair = simulatePair(big, TableModel{curves[0].phi}, k27, sim);
  const ResponseCurve curve(TableModel{curves[0].phi});
  const int reps = 20;
  auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < reps; ++i) {
    const cv::Mat blurred = convolve(curve.inverse(pair.sharp), k27);
    (void)blurred;
  }
  const double direct = since(t0) / reps;
  // the pixels the default fitter uses (B edges), mixture built once
  const LevelImage levels = toLevels(pair.sharp, 256);
  const cv::Rect inside = interiorRect(big.size(), k27);
  const LocalRange range = localRange(pair.blurred, k27);
  std::vector<cv::Point> pixels;
  for (int y = inside.y; y < inside.y + inside.height; ++y)
    for (int x = inside.x; x < inside.x + inside.width; ++x)
      if (range.max.at<double>(y, x) - range.min.at<double>(y, x) > 0.02) pixels.emplace_back(x, y);
  t0 = std::chrono::steady_clock::now();
  const LevelMixture mixture = LevelMixture::build(levels, k27, pixels);
  const double build = since(t0);
  std::vector<double> lut = curve.inverseLut(8), out(pixels.size());
  const double sparse = timeMix(mixture, lut, out, reps);
  std::vector<cv::Point> sub = pixels;
  if (sub.size() > 20000) {
    std::vector<cv::Point> s2;
    for (std::size_t i = 0; i < sub.size(); i += sub.size() / 20000 + 1) s2.push_back(sub[i]);
    sub = s2;
  }
  const LevelMixture mixture_sub = LevelMixture::build(levels, k27, sub);
  std::vector<double> out_sub(sub.size());
  const double sparse_sub = timeMix(mixture_sub, lut, out_sub, reps);
  CrfFitOptions options;
  options.threads = 1;
  t0 = std::chrono::steady_clock::now();
  const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, k27, options);
  const double fit_s = since(t0);
  CrfFitOptions seed = CrfFitOptions::seed();
  seed.threads = 1;
  t0 = std::chrono::steady_clock::now();
  const CrfFitResult fit_seed = fitInverseCrf(pair.sharp, pair.blurred, k27, seed);
  const double seed_s = since(t0);
  std::printf("\nspeed (512x384, 27x27 Levin kernel 4, one core):\n");
  std::printf("  direct: phi LUT + full-image convolution per evaluation: %.3f ms\n", direct * 1e3);
  std::printf("  sparse mixture over %zu edge pixels (%zu non-zeros, built once in %.1f ms): %.3f ms  (%.1fx)\n",
              pixels.size(), mixture.nonZeros(), build * 1e3, sparse * 1e3, direct / sparse);
  std::printf("  sparse mixture over the %zu pixels the default keeps: %.3f ms  (%.1fx)\n", sub.size(),
              sparse_sub * 1e3, direct / sparse_sub);
  std::printf("  one fit, crfcal default: %.3f s (%d evaluations, phi RMSE %.4f); seed method: %.3f s (%d evaluations, "
              "phi RMSE %.4f)\n",
              fit_s, fit.evaluations, curveRmse(fit.inverse_crf, curves[0].phi), seed_s, fit_seed.evaluations,
              curveRmse(fit_seed.inverse_crf, curves[0].phi));
  json["speed"] = {{"direct_convolution_ms", direct * 1e3}, {"sparse_mixture_ms", sparse * 1e3},
                   {"sparse_mixture_default_pixels_ms", sparse_sub * 1e3}, {"speedup", direct / sparse},
                   {"speedup_default_pixels", direct / sparse_sub}, {"fit_default_seconds", fit_s},
                   {"fit_seed_seconds", seed_s}, {"edge_pixels", pixels.size()}};
  // the extra variants on the same pair (one core): the 0.5 s budget of one fit (issue 23)
  for (const Variant& v : setup.variants) {
    if (v.name == "default" || v.name == "seed") continue;
    t0 = std::chrono::steady_clock::now();
    CrfFitOptions vo = variantOptions(v, pair.sharp);
    vo.threads = 1;
    const CrfFitResult vf = v.simex ? fitInverseCrfSimex(pair.sharp, pair.blurred, k27, vo, *v.simex)
                                    : fitInverseCrf(pair.sharp, pair.blurred, k27, vo);
    const double vs = since(t0);
    std::printf("  one fit, %s: %.3f s (phi RMSE %.4f)\n", v.name.c_str(), vs, curveRmse(vf.inverse_crf, curves[0].phi));
    json["speed"]["fit_variant_seconds"][v.name] = vs;
  }
}

// Fig. 5 left: the estimates of the first curve over the 8 kernels, per variant and noise level.
void plotEstimates(io::OutputDirectory& out, const Variant& v, const SyntheticSetup& setup,
                   const std::vector<CaseResult>& results) {
  const int curve = 0;
  for (int level = 0; level < 3; ++level) {
    std::vector<io::PlotSeries> series;
    std::vector<double> x(kCurveSamples);
    for (int i = 0; i < kCurveSamples; ++i) x[i] = double(i) / (kCurveSamples - 1);
    int count = 0;
    for (const auto& r : results)
      if (r.curve == curve && r.level == level && r.phi.count(v.name)) {
        io::PlotSeries s{x, r.phi.at(v.name), cv::Scalar(200, 80, 0), count == 0 ? "estimated (8 kernels)" : "", 1};
        series.push_back(s);
        ++count;
      }
    if (count == 0) continue;
    series.push_back({x, setup.curves[curve].phi, cv::Scalar(0, 0, 220), "true " + setup.curves[curve].name, 2});
    io::PlotOptions po;
    std::ostringstream title;
    title << v.name << ": noise var " << kNoiseVariances[level];
    po.title = title.str();
    po.x_label = "intensity";
    po.y_label = "phi (irradiance)";
    po.x_min = 0; po.x_max = 1; po.y_min = 0; po.y_max = 1;
    io::writePlot(out.file("fig5_" + v.name + "_var" + std::to_string(level) + ".png"), series, po);
  }
}

// Fig. 5 right: the mean error per curve, one series per noise level.
void plotErrorPerCurve(io::OutputDirectory& out, const Variant& v, const SyntheticSetup& setup,
                       const std::vector<CaseResult>& results) {
  std::vector<io::PlotSeries> per;
  for (int level = 0; level < 3; ++level) {
    io::PlotSeries s;
    s.color = io::seriesColor(level);
    std::ostringstream label;
    label << "var " << kNoiseVariances[level];
    s.label = label.str();
    s.markers = false;
    for (int c = 0; c < static_cast<int>(setup.curves.size()); ++c) {
      std::vector<double> e;
      for (const auto& r : results)
        if (r.curve == c && r.level == level && r.rmse.count(v.name)) e.push_back(r.rmse.at(v.name));
      if (e.empty()) continue;
      s.x.push_back(c + 1);
      s.y.push_back(std::accumulate(e.begin(), e.end(), 0.0) / e.size());
    }
    if (!s.x.empty()) per.push_back(s);
  }
  io::PlotOptions po;
  po.title = v.name + ": mean RMSE per CRF";
  po.x_label = "CRF";
  po.y_label = "mean phi RMSE";
  po.y_min = 0;
  if (!per.empty()) io::writePlot(out.file("fig5_" + v.name + "_rmse_per_crf.png"), per, po);
}

int runSynthetic(const SyntheticArgs& args) {
  // Decided before the computation: a refused or unwritable output fails at once.
  std::vector<fs::path> inputs(args.images.begin(), args.images.end());
  inputs.push_back(args.curves);
  const io::OutputPolicy policy{"bench synthetic", inputs, args.force};
  if (!args.json.empty()) io::checkJsonOutputFile(args.json, policy);
  std::optional<io::OutputDirectory> plots;
  if (!args.plot.empty()) plots.emplace(args.plot, policy);
  Progress progress(args.quiet);
  const SyntheticSetup setup = loadSetup(args);

  SyntheticRun run(args, setup, progress);
  const double wall = run.runAll();

  nlohmann::json json = printSyntheticTable(args, setup, run.results, wall);
  printSigmaAndChoices(setup.variants, run.results);
  if (args.curve_split) printCurveSplit(setup, run.results);
  if (args.timing) measureSpeed(setup, json);

  if (!args.json.empty()) io::writeJsonOutput(args.json, json, policy.command, 2);
  if (plots) {
    io::OutputDirectory& out = *plots;
    for (const Variant& v : setup.variants) {
      plotEstimates(out, v, setup, run.results);
      plotErrorPerCurve(out, v, setup, run.results);
    }
    out.commit();
    std::printf("wrote plots to %s\n", args.plot.c_str());
  }
  return kExitOk;
}

const BenchRegistration synthetic_registration(
    10, "synthetic",
    "The seed's Sec. 5 benchmark: 10 camera CRFs x 8 Levin kernels x noise var 0.001/0.005/0.01 on I (240 cases)",
    [](CLI::App& command) {
      auto args = std::make_shared<SyntheticArgs>();
      command.add_option("--images", args->images, "Latent (irradiance) images; default: the 4 bundled Levin images");
      command.add_option("--curves", args->curves,
                         "Directory of camera curve tables (<Camera>.csv); default: samples/camera_curves");
      command.add_option("--noise-vars", args->noise_vars, "Override the three noise variances (diagnostics)")->expected(3);
      command.add_option("--noise-units", args->noise_units,
                         "Units of the noise variances: unit (I in [0,1], the protocol the seed states in Sec. 5) or "
                         "8bit (8-bit levels^2: sigma below one grey level, the noise-free control)")
          ->check(CLI::IsMember({"unit", "8bit"}))
          ->capture_default_str();
      command.add_option("--cases-limit", args->cases_limit, "Run only this many cases (spread over the grid)");
      command.add_flag("--curve-split", args->curve_split,
                       "Also print each variant's mean on the even-numbered curves (to choose a parameter on) and on "
                       "the odd-numbered ones (held out)");
      command.add_option("--json", args->json, "Write the numbers as JSON");
      command.add_option("--plot", args->plot, "Write the seed's Fig. 5 (estimated vs true phi) as PNGs here");
      command.add_flag("--force", args->force, kForceHelp);
      command.add_option("--method", args->method, "seed | default | both")->check(CLI::IsMember({"seed", "default", "both"}));
      command.add_option("--variants", args->variants,
                         "Extra ablation variants: seed+denoise seed+debias seed-fixr moments+debias moments+debias+cue "
                         "moments+cue moments+denoise moments-1pos moments-8pos default+true-sigma default-ggcm "
                         "default-emor default-ggcm-nm default-fixr learned-loco simex simex-linear "
                         "corrected-score[:lambda=X][:ridge][:bins=N][:cue][:below=S][:above=S]");
      command.add_option("--threads", args->threads, "Cases in parallel")->check(CLI::Range(1, kMaxThreads));
      command.add_option("--ratio", args->ratio, "Exposure ratio r of the simulated pairs (seed: 1)")
          ->check(exposureRatioOption(false));
      command.add_flag("!--no-timing", args->timing, "Skip the speed measurements");
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] {
        const int previous = cv::getNumThreads();
        cv::setNumThreads(args->threads);
        try {
          const int rc = runSynthetic(*args);
          cv::setNumThreads(previous);
          return rc;
        } catch (...) {
          cv::setNumThreads(previous);
          throw;
        }
      };
    });

}  // namespace
}  // namespace crfcal::app
