// crfcal deblur: non-blind deconvolution with a known kernel and the camera's response (the seed's Sec. 3.2):
// deblurring in irradiance (φ(B), deconvolve, ψ) avoids the ringing that deblurring intensities shows around
// high-contrast edges (Eq. 18). Both domains are written so that the difference can be seen.
#include <cstdio>
#include <exception>
#include <filesystem>
#include <cmath>
#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "command.hpp"
#include "deblur_inputs.hpp"
#include "progress.hpp"
#include "crfcal/deconvolution.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/output_guard.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/registration.hpp"
#include "crfcal/residual_deconvolution.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

// Runs the image writes of one result side by side (each PNG's deflate is single-threaded: at 12 MP the three writes
// took ~4 s one after the other) and rethrows the first failure once all have finished, so that nothing is left
// running when the output directory is abandoned.
void writeConcurrently(const std::vector<std::function<void()>>& writes) {
  std::vector<std::future<void>> running;
  for (const auto& write : writes) running.push_back(std::async(std::launch::async, write));
  std::exception_ptr first_failure;
  for (auto& job : running) {
    try {
      job.get();
    } catch (...) {
      if (!first_failure) first_failure = std::current_exception();
    }
  }
  if (first_failure) std::rethrow_exception(first_failure);
}

struct DeblurArgs {
  std::string blurred;
  std::string kernel;
  std::string crf;
  std::string from;
  std::string kernels = "auto";  // with --from: the report's per-tile kernels (auto: when they vary), or one
  std::string domain = "irradiance";
  std::string method = "tv";
  double lambda = DeconvolutionOptions{}.lambda;
  int iterations = DeconvolutionOptions{}.inner_iterations;  // TV u-steps (fewer: faster, softer)
  bool fast = false;  // the fast TV schedule (DeconvolutionOptions::withFastSchedule)
  double wiener_nsr = DeconvolutionOptions{}.wiener_nsr;
  double saturation = DeconvolutionOptions{}.saturation;
  std::string sharp;  // the pair's sharp shot: residual deconvolution (Yuan et al. 2007)
  double denoise_strength = ResidualDeconvolutionOptions{}.denoise_strength;
  double ratio = 0;   // r of the residual model (0: fitted)
  bool registered = false;  // --sharp: the shots are registered (identity), no registration
  std::string output;
  bool force = false;  // write into an output directory holding other files (never deletes them)
};

// --from without --kernel: the report's per-tile kernels when --kernels asks for them (auto: when the calibration
// found the blur varying across the frame); empty: the report's one kernel.
ReportTileKernels chosenTileKernels(const DeblurArgs& args) {
  if (args.from.empty() || !args.kernel.empty() || args.kernels == "one") return {};
  ReportTileKernels tiles = tileKernelsOfReport(args.from);
  if (args.kernels == "tiles" && tiles.kernels.size() < 2)
    throw Error("the report lists no per-tile kernels (--kernels tiles; images up to 1200 px are one tile)", args.from);
  if (args.kernels == "auto" && !tiles.varies) return {};
  return tiles;
}

// --sharp: residual deconvolution with the pair's sharp shot (irradiance) is deblurred.png; the blind results of
// both domains are kept beside it.
int writeWithSharp(const DeblurArgs& args, io::OutputDirectory& out, const cv::Mat& blurred, const cv::Mat& sharp,
                   const cv::Mat& kernel, const std::vector<ResponseCurve>& curves, const DeconvolutionResult& chosen,
                   const DeconvolutionResult& other) {
  ResidualDeconvolutionOptions options;
  options.deconvolution = chosen.options;
  options.deconvolution.domain = DeconvolutionDomain::Irradiance;
  options.denoise_strength = args.denoise_strength;
  options.ratio = args.ratio;
  // The report's registration is of the sharp shot as given; a transposed sharp shot (portrait vs landscape) is
  // turned by ±90° here, as calibrate does, and registered again.
  cv::Mat turned = sharp;
  cv::Mat homography = args.from.empty() || sharp.size() != blurred.size() ? cv::Mat() : homographyOfReport(args.from);
  std::string registration = "from " + args.from;
  if (args.registered) {
    if (sharp.size() != blurred.size())
      throw Error("--registered needs the sharp shot in the blurred image's orientation", args.sharp);
    homography = cv::Mat::eye(3, 3, CV_64F);
    registration = "none (--registered)";
  } else if (homography.empty()) {
    try {
      const RegistrationResult registered = registerTurning(sharp, blurred, turned);
      homography = registered.homography;
      registration = registered.summary();
    } catch (const InvalidInput& e) {
      throw Error(e.reason() + " (give --from REPORT.json or --registered)", args.sharp + ", " + args.blurred);
    }
  }
  ResidualDeconvolutionResult residual;
  try {
    residual = deconvolveResidual(blurred, turned, homography, kernel, curves, options);
  } catch (const InvalidInput& e) {
    if (e.subject() == ErrorSubject::sharp_image) throw Error(e.reason(), args.sharp);
    if (e.subject() == ErrorSubject::pair) throw Error(e.reason(), args.sharp + ", " + args.blurred);
    throw;
  }
  const bool irradiance_chosen = chosen.options.domain == DeconvolutionDomain::Irradiance;
  const DeconvolutionResult& blind = irradiance_chosen ? chosen : other;
  const DeconvolutionResult& intensity = irradiance_chosen ? other : chosen;
  writeConcurrently({
      [&] { io::writeUnitImage(out.file("deblurred.png"), residual.deblurred, 16); },
      [&] { io::writeUnitImage(out.file("deblurred_blind.png"), blind.deblurred, 16); },
      [&] { io::writeUnitImage(out.file("deblurred_other_domain.png"), intensity.deblurred, 16); },
      [&] { io::writeUnitImage(out.file("sharp_denoised.png"), residual.sharp_denoised, 16); },
      [&] {
        io::writeImage(out.file("side_by_side.png"),
                       sideBySide({{blurred, "blurred"}, {residual.sharp_denoised, "sharp shot, denoised"},
                                   {intensity.deblurred, "intensity domain"}, {blind.deblurred, "irradiance domain"},
                                   {residual.deblurred, "with the sharp shot"}}));
      }});
  const std::string text = residual.summary() + "\nregistration: " + registration + "\nblind, irradiance: " +
                           blind.summary() + "\nblind, intensity: " + intensity.summary() + "\n";
  io::writeTextFile(out.file("summary.txt"), text);
  out.commit();
  std::printf("%swrote %s/{deblurred,deblurred_blind,deblurred_other_domain,sharp_denoised,side_by_side}.png\n",
              text.c_str(), out.finalPath().string().c_str());
  return kExitOk;
}

int runDeblur(const DeblurArgs& args) {
  DeconvolutionOptions options;
  options.method = parseDeconvolutionMethod(args.method);
  options.domain = parseDeconvolutionDomain(args.domain);
  options.lambda = args.lambda;
  options.inner_iterations = args.iterations;
  options.wiener_nsr = args.wiener_nsr;
  options.saturation = args.saturation;
  if (args.fast) options = options.withFastSchedule();
  options.check();
  if (args.kernel.empty() && args.from.empty()) throw InvalidInput("give --kernel or --from REPORT.json");
  if (args.crf.empty() && args.from.empty()) throw InvalidInput("give --crf or --from REPORT.json");

  // Decided before the computation: a refused or unwritable output directory fails at once.
  std::vector<std::filesystem::path> inputs{args.blurred};
  if (!args.sharp.empty()) inputs.push_back(args.sharp);
  for (const auto* spec : {&args.kernel, &args.crf}) if (!spec->empty()) inputs.push_back(io::specInput(*spec));
  if (!args.from.empty()) {
    inputs.push_back(args.from);
    inputs.push_back(std::filesystem::path(args.from).parent_path() / "kernel.txt");
  }
  const ReportTileKernels tile_kernels = chosenTileKernels(args);
  inputs.insert(inputs.end(), tile_kernels.files.begin(), tile_kernels.files.end());
  io::OutputDirectory out(args.output, {"deblur", inputs, args.force});

  const cv::Mat blurred = toUnit(io::readImage(args.blurred));
  const cv::Mat kernel = !args.kernel.empty() ? io::kernelFromSpec(args.kernel) : kernelOfReport(args.from);
  const std::vector<ResponseCurve> curves = curvesFor(args.crf.empty() ? args.from : args.crf, blurred.channels());
  const cv::Mat sharp = args.sharp.empty() ? cv::Mat() : readSharpShot(args.sharp, blurred, args.blurred);

  Progress progress;
  const auto deconvolveShowing = [&](const DeconvolutionOptions& domain_options) {
    progress.stage(std::string("deblur, ") + toString(domain_options.domain) + " domain");
    DeconvolutionOptions shown = domain_options;
    shown.progress = [&progress](double fraction, const std::string& detail) { progress.update(fraction, detail); };
    DeconvolutionResult result = tile_kernels.kernels.size() > 1
                                     ? deconvolve(blurred, tile_kernels.kernels, curves, shown)
                                     : deconvolve(blurred, kernel, curves, shown);
    result.options.progress = nullptr;  // the options go on to the residual deconvolution (--sharp), not the line
    progress.done();
    return result;
  };
  const DeconvolutionResult chosen = deconvolveShowing(options);
  DeconvolutionOptions other_options = options;
  other_options.domain = options.domain == DeconvolutionDomain::Irradiance ? DeconvolutionDomain::Intensity
                                                                           : DeconvolutionDomain::Irradiance;
  const DeconvolutionResult other = deconvolveShowing(other_options);
  const bool irradiance_chosen = options.domain == DeconvolutionDomain::Irradiance;
  const cv::Mat& intensity_result = irradiance_chosen ? other.deblurred : chosen.deblurred;
  const cv::Mat& irradiance_result = irradiance_chosen ? chosen.deblurred : other.deblurred;

  if (!args.sharp.empty()) return writeWithSharp(args, out, blurred, sharp, kernel, curves, chosen, other);
  writeConcurrently({[&] { io::writeUnitImage(out.file("deblurred.png"), chosen.deblurred, 16); },
                     [&] { io::writeUnitImage(out.file("deblurred_other_domain.png"), other.deblurred, 16); },
                     [&] {
                       io::writeImage(out.file("side_by_side.png"),
                                      sideBySide({{blurred, "blurred"}, {intensity_result, "intensity domain"},
                                                  {irradiance_result, "irradiance domain"}}));
                     }});
  io::writeTextFile(out.file("summary.txt"), chosen.summary() + "\nother domain: " + other.summary() + "\n");
  out.commit();
  std::printf("%s\nother domain: %s\nwrote %s/{deblurred,deblurred_other_domain,side_by_side}.png\n",
              chosen.summary().c_str(), other.summary().c_str(), out.finalPath().string().c_str());
  return kExitOk;
}

const CommandRegistration registration(
    47, "deblur",
    "Deblur an image with a known kernel and the camera's response (deconvolve irradiance, Sec. 3.2)",
    [](CLI::App& command) {
      auto args = std::make_shared<DeblurArgs>();
      command.add_option("blurred", args->blurred, "The blurred image (8/16-bit, grey or colour)")->required();
      command.add_option("--kernel", args->kernel,
                         "Blur kernel: text matrix (rows = y), kernel image, levin:1..8 or box:L");
      command.add_option("--crf", args->crf,
                         "Inverse response phi: a report.json (per channel), table:FILE, gamma:2.2, ggcm:…, emor:…");
      command.add_option("--from", args->from,
                         "A calibration report.json: its phi and its kernel (kernel.txt beside it); --kernel and "
                         "--crf override");
      command.add_option("--kernels", args->kernels,
                         "With --from: auto (the report's per-tile kernels when the calibration found the blur varying "
                         "across the frame, each part of the image with the nearest), tiles (always when listed), one "
                         "(kernel.txt only)")
          ->check(CLI::IsMember({"auto", "tiles", "one"}));
      command.add_option("--domain", args->domain,
                         "Domain of deblurred.png: irradiance (phi(B), deconvolve, psi) or intensity (B directly); "
                         "deblurred_other_domain.png holds the other")
          ->check(CLI::IsMember({"irradiance", "intensity"}));
      command.add_option("--method", args->method, "tv (FTVd total variation) or wiener")
          ->check(CLI::IsMember({"tv", "wiener"}));
      command.add_option("--lambda", args->lambda, "TV data weight (larger: sharper, noisier)")
          ->check(CLI::PositiveNumber);
      auto* iterations = command.add_option("--iterations", args->iterations,
                                            "TV u-steps (default 25; 8 take about a third of the time for 0.9 dB less "
                                            "on the Levin set)")
                             ->check(CLI::Range(1, 500));
      command.add_flag("--fast", args->fast,
                       "Fast TV schedule: 8 u-steps at beta 128 (about a third of the time; 0.8 dB less on the Levin "
                       "set, the irradiance domain still +3.2 dB ahead of the intensity domain)")
          ->excludes(iterations);
      command.add_option("--wiener-nsr", args->wiener_nsr, "Wiener noise-to-signal ratio")->check(CLI::PositiveNumber);
      command.add_option("--saturation", args->saturation,
                         "Pixels at or above this level (0..1) are saturated and left out of the TV data term")
          ->check(CLI::Range(0.01, 1.0));
      command.add_option("--sharp", args->sharp,
                         "The pair's sharp (short, noisy) shot: deblurred.png becomes residual deconvolution against "
                         "it (Yuan et al. 2007, irradiance); registered by --from's report or else registered here");
      command.add_option("--denoise-strength", args->denoise_strength,
                         "--sharp: NL-means strength h of the sharp shot, in units of its estimated noise sigma")
          ->check(CLI::Range(0.0, 10.0));
      command.add_option("--ratio", args->ratio,
                         "--sharp: exposure ratio r of the blurred to the sharp shot (default: fitted per channel)")
          ->check(CLI::NonNegativeNumber);
      command.add_flag("--registered", args->registered,
                       "--sharp: the two shots are already registered (no registration, the report's ignored)");
      command.add_option("-o,--output", args->output, "Output directory (see --force)")->required();
      command.add_flag("--force", args->force, kForceHelp);
      return [args] { return runDeblur(*args); };
    });

}  // namespace
}  // namespace crfcal::app
