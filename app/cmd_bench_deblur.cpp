// crfcal bench deblur: the seed's Sec. 3.2 measured. The four Levin et al. photos (samples/levin09, centre-cropped
// to --size px for speed) × the Levin kernels × response curves (gamma 2.2 and real camera curves) are blurred in
// irradiance (B = ψ(φ(I) ⊗ K), 8-bit, no noise) and deblurred with the true kernel and the true φ, once in the
// intensity domain (B directly) and once in irradiance (φ(B), deconvolve, ψ). Prints the mean PSNR per curve.
#include <sys/resource.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "bench_command.hpp"
#include "bench_deblur_real.hpp"
#include "crfcal/blur_model.hpp"
#include "crfcal/curve_perturbation.hpp"
#include "crfcal/deconvolution.hpp"
#include "crfcal/image_quality.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/error.hpp"
#include "crfcal/handheld_simulation.hpp"
#include "crfcal/residual_deconvolution.hpp"
#include "crfcal/io/noise_profiles.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/output_guard.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct DeblurBenchArgs {
  std::vector<std::string> curves;  // default: gamma 2.2, Nikon D70, Canon EOS-1Ds Mark II
  int kernels = 8;                  // levin:1 … levin:N
  int images = 4;                   // im1 … imN
  int size = 128;                   // centre crop (0: the full 255 px)
  std::string method = "tv";
  double lambda = DeconvolutionOptions{}.lambda;
  std::string json;
  bool force = false;  // --json over a file crfcal did not write (never deletes it)
  bool per_case = false;
  bool speed = false;               // only the speed measurement (a large RGB image)
  int speed_width = 4000, speed_height = 3000;
  int speed_threads = 0;            // --speed: OpenCV worker threads (0: OpenCV's default, one per core)
  int tile_size = DeconvolutionOptions{}.tile_size;
  double beta_factor = DeconvolutionOptions{}.beta_factor;
  int inner_iterations = DeconvolutionOptions{}.inner_iterations;
  bool double_precision = false;
  bool bregman = DeconvolutionOptions{}.bregman;
  double beta_start = DeconvolutionOptions{}.beta_start;
  double beta_max = DeconvolutionOptions{}.beta_max;
  bool fast = false;  // DeconvolutionOptions::withFastSchedule (overrides --inner, --beta-start, --beta-max)
  double phi_error = 0.02;  // RMSE of the perturbed φ (φ^a, a > 1 and a < 1 on alternate cases)
  bool estimated_phi = false;  // also deblur with the φ crfcal estimates from each simulated pair
  // The pair's sharp shot as extra information (residual deconvolution, Yuan et al. 2007): a simulated sharp shot
  // underexposed by pair_ratio with the noise camera's raw noise at ISO blurred_iso · pair_ratio.
  bool pair = true;
  double pair_ratio = 4;
  double blurred_iso = 100;
  std::string noise_camera = "LGE Nexus 5";  // darktable's phone profile (samples/noise_profiles excerpt)
  std::string noise_profiles;                // default: io::defaultNoiseProfiles()
  double denoise_strength = ResidualDeconvolutionOptions{}.denoise_strength;
  double residual_lambda = 0;                // TV λ of the residual (0: --lambda)
  std::string real, reports;                 // --real DIR --reports CALDIR: the phone triplets
};

// One deblurred result's scores against the sharp image.
struct Scores {
  double psnr = 0, ssim = 0, edge_rmse = 0;
  Scores& operator+=(const Scores& other) {
    psnr += other.psnr, ssim += other.ssim, edge_rmse += other.edge_rmse;
    return *this;
  }
};

Scores score(const cv::Mat& estimate, const cv::Mat& sharp) {
  return {crfcal::psnr(estimate, sharp), ssim(estimate, sharp), edgeBandError(estimate, sharp).rmse};
}

struct Means {
  int cases = 0;
  Scores blurred, intensity, irradiance, irradiance_off;  // irradiance_off: φ off by --phi-error
  int irradiance_ahead = 0;
  Scores estimated;             // --estimated-phi: irradiance domain with crfcal's φ of the pair
  int estimated_cases = 0;      // pairs whose calibration succeeded
  double estimated_phi_rmse = 0;
  Scores residual, sharp_prior;  // with the pair's sharp shot: residual deconvolution, the denoised shot alone
  int residual_ahead = 0;
};

std::string curveLabel(const std::string& spec) {
  if (spec.rfind("table:", 0) == 0) return fs::path(spec.substr(6)).stem().string();
  return spec;
}

cv::Mat centreCrop(const cv::Mat& image, int size) {
  if (size <= 0 || size >= std::min(image.cols, image.rows)) return image;
  return image(cv::Rect((image.cols - size) / 2, (image.rows - size) / 2, size, size)).clone();
}

DeconvolutionOptions optionsOf(const DeblurBenchArgs& args) {
  DeconvolutionOptions options;
  options.method = parseDeconvolutionMethod(args.method);
  options.lambda = args.lambda;
  options.tile_size = args.tile_size;
  options.beta_factor = args.beta_factor;
  options.inner_iterations = args.inner_iterations;
  options.single_precision = !args.double_precision;
  options.bregman = args.bregman;
  options.beta_start = args.beta_start;
  options.beta_max = args.beta_max;
  if (args.fast) options = options.withFastSchedule();
  options.check();
  return options;
}

// A colour scene of `size`: im1, im2, im3 of the Levin set as B, G, R, each mirror-tiled at its own scale (the
// detail density of a photo, not of a 16x upscale).
cv::Mat tiledScene(const fs::path& samples, cv::Size size) {
  std::vector<cv::Mat> planes;
  for (int i = 1; i <= 3; ++i) {
    const cv::Mat image = io::readGrayUnit(samples / "levin09" / ("im" + std::to_string(i) + ".png"));
    cv::Mat tiled = image;
    while (tiled.cols < size.width || tiled.rows < size.height) {  // each pass doubles it (mirrored copies)
      cv::Mat grown;
      cv::copyMakeBorder(tiled, grown, 0, tiled.rows, 0, tiled.cols, cv::BORDER_REFLECT);
      tiled = grown;
    }
    planes.push_back(tiled(cv::Rect({0, 0}, size)).clone());
  }
  cv::Mat scene;
  cv::merge(planes, scene);
  return scene;
}

// A 25×25 motion kernel: a 2 px wide diagonal stroke (the "25 px kernel").
cv::Mat strokeKernel25() {
  cv::Mat kernel = cv::Mat::zeros(25, 25, CV_64F);
  cv::line(kernel, {2, 20}, {22, 4}, cv::Scalar(1), 2);
  return kernel / cv::sum(kernel)[0];
}

// The speed target: deblur a 12 MP RGB image (gamma 2.2, irradiance domain) and report wall time and the
// process's peak resident memory (getrusage; it includes the scene's synthesis).
int runSpeedBench(const DeblurBenchArgs& args, const DeconvolutionOptions& base) {
  const cv::Size size(args.speed_width, args.speed_height);
  const ResponseCurve curve(io::parseResponseSpec("gamma:2.2"));
  const cv::Mat kernel = strokeKernel25();
  const cv::Mat sharp = tiledScene(io::samplesDirectory(), size);
  std::vector<cv::Mat> planes;
  cv::split(sharp, planes);
  for (cv::Mat& plane : planes) plane = quantize(irradianceBlur(plane, curve, kernel), 8);
  cv::Mat blurred, blurred8;
  cv::merge(planes, blurred);
  blurred.convertTo(blurred8, CV_8UC3, 255.0);  // what a camera hands over
  DeconvolutionOptions options = base;
  options.domain = DeconvolutionDomain::Irradiance;
  const int default_threads = cv::getNumThreads();
  if (args.speed_threads > 0) cv::setNumThreads(args.speed_threads);
  std::printf("speed: %dx%d RGB (%.1f MP), 25x25 kernel, %s in the irradiance domain, %d threads\n", size.width,
              size.height, size.area() / 1e6, toString(options.method), cv::getNumThreads());
  const auto cpuSeconds = [] {
    rusage usage{};
    getrusage(RUSAGE_SELF, &usage);
    return usage.ru_utime.tv_sec + usage.ru_stime.tv_sec + 1e-6 * (usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
  };
  const double cpu_start = cpuSeconds();
  const auto start = std::chrono::steady_clock::now();
  const DeconvolutionResult result = deconvolve(blurred8, kernel, {curve}, options);
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const double cpu = cpuSeconds() - cpu_start;
  cv::setNumThreads(default_threads);
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  std::printf("%s\n", result.summary().c_str());
  std::printf("stages (wall): phi and masks %.2f s, tile solves with psi %.2f s, rest %.2f s\n",
              result.prepare_seconds, result.solve_seconds,
              result.seconds - result.prepare_seconds - result.solve_seconds);
  std::printf("wall %.1f s, CPU %.1f s, peak RSS %.0f MB; PSNR blurred %.2f dB, deblurred %.2f dB (%d px from the "
              "border)\n", wall, cpu, usage.ru_maxrss / 1024.0, psnr(blurred, sharp, 40),
              psnr(result.deblurred, sharp, 40), 40);
  return kExitOk;
}

// φ (G) crfcal estimates from the simulated pair: the full 255 px sharp image and its blur, 8-bit, r = 1.
// Empty when the calibration refuses the pair.
std::optional<ResponseCurve> estimatedCurve(const cv::Mat& sharp, const cv::Mat& blurred) {
  cv::Mat sharp8, blurred8;
  sharp.convertTo(sharp8, CV_8U, 255.0);
  blurred.convertTo(blurred8, CV_8U, 255.0);
  PairCalibrationOptions options;
  options.fit.nominal_ratio = 1.0;
  try {
    const PairCalibrationResult result = calibratePair(sharp8, blurred8, options);
    return ResponseCurve::fromSamples(result.fits.at("G").inverse_crf);
  } catch (const InvalidInput&) {
    return std::nullopt;
  }
}

void printEstimatedTable(const std::vector<std::pair<std::string, Means>>& rows);

void printTables(const std::vector<std::pair<std::string, Means>>& rows) {
  std::printf("PSNR\n%-22s %5s %11s %13s %14s %9s %8s %16s\n", "curve", "cases", "blurred dB", "intensity dB",
              "irradiance dB", "gain dB", "ahead", "irr. phi off dB");
  for (const auto& [label, m] : rows)
    std::printf("%-22s %5d %11.2f %13.2f %14.2f %+9.2f %4d/%-3d %16.2f\n", label.c_str(), m.cases,
                m.blurred.psnr / m.cases, m.intensity.psnr / m.cases, m.irradiance.psnr / m.cases,
                (m.irradiance.psnr - m.intensity.psnr) / m.cases, m.irradiance_ahead, m.cases,
                m.irradiance_off.psnr / m.cases);
  std::printf("SSIM (Wang 2004) and edge-band RMSE (within 4 px of sharp edges of 3x3 contrast >= 0.3)\n");
  std::printf("%-22s %9s %9s %9s %9s | %9s %9s %9s %9s\n", "curve", "SSIM blur", "intensity", "irrad.",
              "phi off", "edge blur", "intensity", "irrad.", "phi off");
  for (const auto& [label, m] : rows)
    std::printf("%-22s %9.4f %9.4f %9.4f %9.4f | %9.4f %9.4f %9.4f %9.4f\n", label.c_str(), m.blurred.ssim / m.cases,
                m.intensity.ssim / m.cases, m.irradiance.ssim / m.cases, m.irradiance_off.ssim / m.cases,
                m.blurred.edge_rmse / m.cases, m.intensity.edge_rmse / m.cases, m.irradiance.edge_rmse / m.cases,
                m.irradiance_off.edge_rmse / m.cases);
  if (rows.front().second.estimated_cases == 0 && rows.back().second.estimated_cases == 0) return;
  printEstimatedTable(rows);
}

void printPairTable(const std::vector<std::pair<std::string, Means>>& rows, const std::string& setting) {
  std::printf("with the pair's sharp shot (%s): residual deconvolution (Yuan et al. 2007) vs blind TV of the blurred "
              "shot, both irradiance, true phi and kernel\n", setting.c_str());
  std::printf("%-22s %5s %9s %9s %9s %8s %8s | %9s %9s %9s | %9s %9s %9s\n", "curve", "cases", "blind dB",
              "sharp dB", "resid. dB", "gain dB", "ahead", "SSIM bl.", "sharp", "resid.", "edge bl.", "sharp", "resid.");
  for (const auto& [label, m] : rows)
    std::printf("%-22s %5d %9.2f %9.2f %9.2f %+8.2f %4d/%-3d | %9.4f %9.4f %9.4f | %9.4f %9.4f %9.4f\n",
                label.c_str(), m.cases, m.irradiance.psnr / m.cases, m.sharp_prior.psnr / m.cases,
                m.residual.psnr / m.cases, (m.residual.psnr - m.irradiance.psnr) / m.cases, m.residual_ahead, m.cases,
                m.irradiance.ssim / m.cases, m.sharp_prior.ssim / m.cases, m.residual.ssim / m.cases,
                m.irradiance.edge_rmse / m.cases, m.sharp_prior.edge_rmse / m.cases, m.residual.edge_rmse / m.cases);
}

void printEstimatedTable(const std::vector<std::pair<std::string, Means>>& rows) {
  std::printf("irradiance domain with the phi crfcal estimates from each pair (full 255 px images)\n");
  std::printf("%-22s %9s %10s %9s %9s %9s\n", "curve", "pairs ok", "phi RMSE", "PSNR dB", "SSIM", "edge RMSE");
  for (const auto& [label, m] : rows) {
    const int n = std::max(m.estimated_cases, 1);
    std::printf("%-22s %4d/%-4d %10.4f %9.2f %9.4f %9.4f\n", label.c_str(), m.estimated_cases, m.cases,
                m.estimated_phi_rmse / n, m.estimated.psnr / n, m.estimated.ssim / n, m.estimated.edge_rmse / n);
  }
}

// The seed's claim that the intensity-domain artefact grows with Imax − Imin (Eq. 18 with Theorem 1): a vertical
// step from 0.1 to 0.1 + contrast, blurred under gamma 2.2 by levin:2 (8-bit), deblurred in both domains; the
// error RMS within 8 px of the step.
void printContrastTable(DeconvolutionOptions options) {
  const ResponseCurve curve(io::parseResponseSpec("gamma:2.2"));
  const cv::Mat kernel = io::kernelFromSpec("levin:2");
  std::printf("step edge 0.1 -> 0.1 + contrast, gamma 2.2, levin:2: error RMS within 8 px of the step\n");
  std::printf("%9s %11s %11s %11s\n", "contrast", "blurred", "intensity", "irradiance");
  for (double contrast : {0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9}) {
    cv::Mat step(96, 96, CV_64F, cv::Scalar(0.1));
    step.colRange(48, 96).setTo(0.1 + contrast);
    const cv::Mat blurred = quantize(irradianceBlur(step, curve, kernel), 8);
    EdgeBandOptions band;
    band.contrast = 0.5 * contrast;
    band.band = 8;
    options.domain = DeconvolutionDomain::Intensity;
    const double intensity = edgeBandError(deconvolve(blurred, kernel, {curve}, options).deblurred, step, band).rmse;
    options.domain = DeconvolutionDomain::Irradiance;
    const double irradiance = edgeBandError(deconvolve(blurred, kernel, {curve}, options).deblurred, step, band).rmse;
    std::printf("%9.1f %11.4f %11.4f %11.4f\n", contrast, edgeBandError(blurred, step, band).rmse, intensity,
                irradiance);
  }
}

// --pair: the sharp shot underexposed by --pair-ratio with a camera's raw noise at its ISO, and the options of the
// residual deconvolution that uses it.
struct PairSetting {
  std::optional<PoissonGaussian> sharp_noise;  // empty without --pair
  ResidualDeconvolutionOptions residual;
  std::string description;  // the pair table's heading
};

PairSetting pairSettingOf(const DeblurBenchArgs& args, const DeconvolutionOptions& options) {
  PairSetting setting;
  if (!args.pair) return setting;
  const io::CameraNoiseProfile camera = io::readCameraNoiseProfile(
      args.noise_profiles.empty() ? io::defaultNoiseProfiles() : fs::path(args.noise_profiles), args.noise_camera);
  const double sharp_iso = args.blurred_iso * args.pair_ratio;
  setting.sharp_noise = camera.atIso(sharp_iso).green;
  setting.residual.deconvolution = options;
  setting.residual.deconvolution.domain = DeconvolutionDomain::Irradiance;
  if (args.residual_lambda > 0) setting.residual.deconvolution.lambda = args.residual_lambda;
  setting.residual.denoise_strength = args.denoise_strength;
  setting.residual.check();
  char text[200];
  std::snprintf(text, sizeof text, "sharp shot underexposed by r = %g, %s raw noise at ISO %g, 8-bit; residual TV "
                "lambda %g, NL-means h = %g sigma", args.pair_ratio, camera.camera().c_str(), sharp_iso,
                setting.residual.deconvolution.lambda, args.denoise_strength);
  setting.description = text;
  return setting;
}

// One case of the bench: a Levin photo blurred by one kernel under one curve.
struct DeblurCase {
  const std::string& spec;
  const ResponseCurve& curve;
  const ResponseCurve& curve_off;  // φ off by --phi-error
  const cv::Mat& image;            // the crop deblurred and scored
  const cv::Mat& full_image;       // the whole photo, for --estimated-phi
  const cv::Mat& kernel;
  size_t image_index, kernel_index;
};

nlohmann::json scoresJson(const Scores& s) {
  return nlohmann::json{{"psnr", s.psnr}, {"ssim", s.ssim}, {"edge_rmse", s.edge_rmse}};
}

// Deblurs one case by every method the arguments ask for and adds its scores to `means` and `all`.
nlohmann::json runDeblurCase(const DeblurBenchArgs& args, DeconvolutionOptions options, const PairSetting& pair,
                             const DeblurCase& c, Means& means, Means& all) {
  const cv::Mat blurred = quantize(irradianceBlur(c.image, c.curve, c.kernel), 8);
  options.domain = DeconvolutionDomain::Intensity;
  const Scores intensity = score(deconvolve(blurred, c.kernel, {c.curve}, options).deblurred, c.image);
  options.domain = DeconvolutionDomain::Irradiance;
  const Scores irradiance = score(deconvolve(blurred, c.kernel, {c.curve}, options).deblurred, c.image);
  const Scores irradiance_off = score(deconvolve(blurred, c.kernel, {c.curve_off}, options).deblurred, c.image);
  const Scores before = score(blurred, c.image);
  std::optional<ResponseCurve> estimated;
  if (args.estimated_phi)
    estimated = estimatedCurve(c.full_image, quantize(irradianceBlur(c.full_image, c.curve, c.kernel), 8));
  if (estimated) {
    const Scores with_estimate = score(deconvolve(blurred, c.kernel, {*estimated}, options).deblurred, c.image);
    const double phi_rmse = curveRmse(*estimated, c.curve);
    for (Means* m : {&means, &all}) {
      m->estimated += with_estimate;
      ++m->estimated_cases;
      m->estimated_phi_rmse += phi_rmse;
    }
  }
  Scores residual, sharp_prior;
  if (pair.sharp_noise) {
    const cv::Mat shot = underexposedSharpShot(c.image, io::parseResponseSpec(c.spec), args.pair_ratio,
                                               *pair.sharp_noise, 1 + 16 * c.image_index + c.kernel_index);
    const ResidualDeconvolutionResult r =
        deconvolveResidual(blurred, shot, cv::Mat(), c.kernel, {c.curve}, pair.residual);
    residual = score(r.deblurred, c.image);
    sharp_prior = score(r.sharp_denoised, c.image);
    for (Means* m : {&means, &all}) {
      m->residual += residual;
      m->sharp_prior += sharp_prior;
      m->residual_ahead += residual.psnr > irradiance.psnr;
    }
  }
  for (Means* m : {&means, &all}) {
    ++m->cases;
    m->blurred += before;
    m->intensity += intensity;
    m->irradiance += irradiance;
    m->irradiance_off += irradiance_off;
    m->irradiance_ahead += irradiance.psnr > intensity.psnr;
  }
  nlohmann::json entry = {{"curve", curveLabel(c.spec)}, {"image", c.image_index + 1}, {"kernel", c.kernel_index + 1},
                          {"blurred", scoresJson(before)}, {"intensity", scoresJson(intensity)},
                          {"irradiance", scoresJson(irradiance)}, {"irradiance_phi_off", scoresJson(irradiance_off)},
                          {"blurred_psnr", before.psnr}, {"intensity_psnr", intensity.psnr},
                          {"irradiance_psnr", irradiance.psnr}};
  if (pair.sharp_noise) {
    entry["residual_with_sharp"] = scoresJson(residual);
    entry["sharp_denoised"] = scoresJson(sharp_prior);
  }
  if (args.per_case)
    std::printf("  %s im%zu levin:%zu  %.2f  %.2f  %.2f  %.2f  %.2f\n", curveLabel(c.spec).c_str(), c.image_index + 1,
                c.kernel_index + 1, before.psnr, intensity.psnr, irradiance.psnr, irradiance_off.psnr, residual.psnr);
  return entry;
}

int runDeblurBench(const DeblurBenchArgs& args) {
  const fs::path samples = io::samplesDirectory();
  std::vector<std::string> curves = args.curves;
  if (curves.empty())
    curves = {"gamma:2.2", "table:" + (samples / "camera_curves" / "NikonD70.csv").string(),
              "table:" + (samples / "camera_curves" / "CanonEOS1DsMarkII.csv").string()};
  DeconvolutionOptions options = optionsOf(args);
  if (args.speed) return runSpeedBench(args, options);
  if (!args.real.empty()) {
    if (args.reports.empty()) throw InvalidInput("--real needs --reports CALDIR (CALDIR/N/report.json)", ErrorSubject::options);
    ResidualDeconvolutionOptions residual;
    residual.deconvolution = options;
    if (args.residual_lambda > 0) residual.deconvolution.lambda = args.residual_lambda;
    residual.denoise_strength = args.denoise_strength;
    residual.check();
    return runRealDeblurBench(args.real, args.reports, residual);
  }
  if (!args.json.empty()) io::checkJsonOutputFile(args.json, {"bench deblur", {}, args.force});  // before the work

  std::vector<cv::Mat> images, full_images;
  for (int i = 1; i <= args.images; ++i) {
    full_images.push_back(io::readGrayUnit(samples / "levin09" / ("im" + std::to_string(i) + ".png")));
    images.push_back(centreCrop(full_images.back(), args.size));
  }
  std::vector<cv::Mat> kernels;
  for (int k = 1; k <= args.kernels; ++k) kernels.push_back(io::kernelFromSpec("levin:" + std::to_string(k)));

  const auto start = std::chrono::steady_clock::now();
  nlohmann::json json = {{"method", args.method}, {"lambda", args.lambda}, {"size", args.size},
                         {"phi_error", args.phi_error}, {"cases", nlohmann::json::array()}};
  std::printf("%s deblurring, %zu images (%dx%d) x %zu Levin kernels, true kernel, 8-bit, no noise; irradiance with "
              "the true phi and with phi off by RMSE %.3f (phi^a, a > 1 and a < 1 on alternate cases)\n",
              args.method.c_str(), images.size(), images[0].cols, images[0].rows, kernels.size(), args.phi_error);
  const PairSetting pair = pairSettingOf(args, options);
  std::vector<std::pair<std::string, Means>> rows;
  Means all;
  for (const std::string& spec : curves) {
    const ResponseCurve curve(io::parseResponseSpec(spec));
    const ResponseCurve steeper = powerPerturbedCurve(curve, args.phi_error, true);
    const ResponseCurve flatter = powerPerturbedCurve(curve, args.phi_error, false);
    Means means;
    for (size_t i = 0; i < images.size(); ++i)
      for (size_t k = 0; k < kernels.size(); ++k) {
        const DeblurCase c{spec, curve, (i + k) % 2 == 0 ? steeper : flatter, images[i], full_images[i], kernels[k],
                           i, k};
        json["cases"].push_back(runDeblurCase(args, options, pair, c, means, all));
      }
    rows.emplace_back(curveLabel(spec), means);
  }
  if (curves.size() > 1) rows.emplace_back("all", all);
  printTables(rows);
  printContrastTable(options);
  if (args.pair) printPairTable(rows, pair.description);
  std::printf("%.1f s\n", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  if (!args.json.empty()) io::writeJsonOutput(args.json, json, "bench deblur");
  return kExitOk;
}

const BenchRegistration registration(
    65, "deblur",
    "Intensity- vs irradiance-domain deblurring (Sec. 3.2) on the Levin photos x kernels x curves, true phi",
    [](CLI::App& command) {
      auto args = std::make_shared<DeblurBenchArgs>();
      command.add_option("--curve", args->curves,
                         "Response specs (repeatable; default gamma:2.2 and the Nikon D70 and Canon EOS-1Ds Mark II "
                         "tables of samples/camera_curves)");
      command.add_option("--kernels", args->kernels, "Use levin:1 .. levin:N")->check(CLI::Range(1, 8));
      command.add_option("--images", args->images, "Use im1 .. imN of samples/levin09")->check(CLI::Range(1, 4));
      command.add_option("--size", args->size, "Centre crop in px (0: the full 255 px images)")
          ->check(CLI::Range(0, 255));
      command.add_option("--method", args->method, "tv or wiener")->check(CLI::IsMember({"tv", "wiener"}));
      command.add_option("--lambda", args->lambda, "TV data weight")->check(CLI::PositiveNumber);
      command.add_flag("--per-case", args->per_case, "Print one row per image and kernel");
      command.add_flag("--speed", args->speed,
                       "Only time a large RGB image (--speed-width x --speed-height, default 12 MP): wall s, peak RSS");
      command.add_option("--speed-width", args->speed_width, "Width of the --speed image")->check(CLI::Range(64, 12000));
      command.add_option("--speed-height", args->speed_height, "Height of the --speed image")->check(CLI::Range(64, 12000));
      command.add_option("--speed-threads", args->speed_threads, "--speed: OpenCV threads (0: one per core)")
          ->check(CLI::Range(0, 64));
      command.add_option("--tile-size", args->tile_size, "FFT tile size (0: whole images)")->check(CLI::Range(0, 16384));
      command.add_option("--beta-factor", args->beta_factor, "TV continuation factor of beta")->check(CLI::Range(1.01, 64.0));
      auto* inner = command.add_option("--inner", args->inner_iterations, "TV u/w alternations per beta")
                        ->check(CLI::Range(1, 100));
      command.add_flag("--bregman,!--no-bregman", args->bregman, "ADMM multipliers in the TV solver (default on)");
      auto* beta_start = command.add_option("--beta-start", args->beta_start, "First beta")->check(CLI::PositiveNumber);
      auto* beta_max = command.add_option("--beta-max", args->beta_max, "Last beta")->check(CLI::PositiveNumber);
      command.add_flag("--fast", args->fast, "The fast TV schedule of `crfcal deblur --fast` (8 u-steps at beta 128)")
          ->excludes(inner)
          ->excludes(beta_start)
          ->excludes(beta_max);
      command.add_option("--phi-error", args->phi_error, "RMSE of the perturbed phi of the 'phi off' columns")
          ->check(CLI::Range(0.001, 0.2));
      command.add_flag("--estimated-phi", args->estimated_phi,
                       "Also deblur with the phi crfcal estimates from each simulated pair (one pair calibration per "
                       "case: slow)");
      command.add_flag("--pair,!--no-pair", args->pair,
                       "Also deblur with a simulated sharp shot of the pair (residual deconvolution; default on)");
      command.add_option("--pair-ratio", args->pair_ratio, "Underexposure r of the simulated sharp shot")
          ->check(CLI::Range(1.0, 64.0));
      command.add_option("--blurred-iso", args->blurred_iso, "ISO of the blurred shot (the sharp shot: ISO x r)")
          ->check(CLI::PositiveNumber);
      command.add_option("--noise-camera", args->noise_camera, "Camera of the sharp shot's noise (darktable profiles)");
      command.add_option("--noise-profiles", args->noise_profiles, "darktable noiseprofiles.json");
      command.add_option("--denoise-strength", args->denoise_strength, "NL-means h of the sharp shot, x its noise sigma")
          ->check(CLI::Range(0.0, 10.0));
      command.add_option("--residual-lambda", args->residual_lambda, "TV lambda of the residual (default: --lambda)")
          ->check(CLI::NonNegativeNumber);
      command.add_option("--real", args->real,
                         "Only the real triplets of DIR (noisy_N, blurred_N, g_truth_N.jpg), deblurred with --reports' "
                         "calibrations and scored against g_truth_N");
      command.add_option("--reports", args->reports,
                         "--real: directory of the triplets' calibrations, N/report.json (crfcal calibrate -o DIR/N)");
      command.add_flag("--double", args->double_precision, "CV_64F DFTs (the reference) instead of CV_32F");
      command.add_option("--json", args->json, "Write every case to this JSON file (atomic)");
      command.add_flag("--force", args->force, kForceHelp);
      return [args] { return runDeblurBench(*args); };
    });

}  // namespace
}  // namespace crfcal::app
