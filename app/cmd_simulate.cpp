// crfcal simulate: a synthetic sharp/blurred pair with a known response, kernel and exposure ratio (Sec. 5).
#include <cstdio>

#include <nlohmann/json.hpp>

#include "command.hpp"
#include "option_checks.hpp"
#include "crfcal/blur_model.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/simulation.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {

struct SimulateArgs {
  std::string image;
  std::string crf = "gamma:2.2";
  std::string kernel = "levin:1";
  std::string output;
  std::string input_domain = "irradiance";
  SimulationOptions options;
  bool quiet = false;
  bool force = false;  // write into an output directory holding other files (never deletes them)
};

int runSimulate(const SimulateArgs& args) {
  Progress progress(args.quiet);
  progress.stage("simulate");
  io::OutputDirectory out(args.output,
                          {"simulate", {args.image, io::specInput(args.crf), io::specInput(args.kernel)}, args.force});
  const cv::Mat image = io::readImage(args.image);
  const ResponseModel model = io::parseResponseSpec(args.crf);
  const cv::Mat kernel = io::kernelFromSpec(args.kernel);
  SimulationOptions options = args.options;
  options.image_is_irradiance = args.input_domain == "irradiance";
  const SimulationResult pair = simulatePair(image, model, kernel, options);

  io::writeUnitImage(out.file("sharp.png"), pair.sharp, options.bits);
  io::writeUnitImage(out.file("blurred.png"), pair.blurred, options.bits);
  io::writeKernelPng(out.file("kernel.png"), kernel);
  io::writeKernelText(out.file("kernel.txt"), kernel);

  nlohmann::json truth;
  truth["inverse_crf"] = sampleInverse(model, kCurveSamples);
  truth["inverse_crf_x"] = "x = i/1023, i = 0..1023";
  truth["model"] = io::modelToJson(model);
  truth["crf_spec"] = args.crf;
  std::vector<std::vector<double>> rows;
  for (int y = 0; y < kernel.rows; ++y) rows.emplace_back(kernel.ptr<double>(y), kernel.ptr<double>(y) + kernel.cols);
  truth["kernel"] = rows;
  truth["kernel_spec"] = args.kernel;
  truth["kernel_size"] = {kernel.cols, kernel.rows};
  truth["exposure_ratio"] = options.ratio;
  truth["noise_variance"] = options.noise_variance;
  truth["bits"] = options.bits;
  truth["seed"] = options.seed;
  truth["image"] = args.image;
  truth["input_domain"] = args.input_domain;
  truth["clipped_pixels"] = pair.clipped_pixels;
  truth["size"] = {pair.sharp.cols, pair.sharp.rows};
  io::writeTextFile(out.file("truth.json"), truth.dump(2) + "\n");
  out.commit();
  progress.done();
  std::printf("wrote %s/{sharp.png, blurred.png, kernel.png, kernel.txt, truth.json}\n", args.output.c_str());
  if (pair.clipped_pixels > 0)
    std::printf("note: %d blurred pixels saturated (r * (phi(I) (x) K) > 1)\n", pair.clipped_pixels);
  return kExitOk;
}

const CommandRegistration registration(
    10, "simulate", "Make a synthetic sharp/blurred pair with a known CRF, kernel and exposure ratio (seed Sec. 5)",
    [](CLI::App& command) {
      auto args = std::make_shared<SimulateArgs>();
      command.add_option("--image", args->image, "Latent image (any format OpenCV reads; colour is converted to grey)")
          ->required()
          ->check(CLI::ExistingFile);
      command.add_option("--crf", args->crf,
                         "Inverse response phi: gamma:G | ggcm:a0,a1,... | emor:c1,c2,... | table:FILE");
      command.add_option("--kernel", args->kernel, "Blur kernel: levin:1..8 | levin:N@S (scaled by S) | box:L | FILE (text matrix or image)");
      command.add_option("--ratio", args->options.ratio, "Exposure ratio r = dt_B/dt_I (Eq. 4), 0.001 .. 1000")
          ->check(exposureRatioOption(false));
      command.add_option("--noise-var", args->options.noise_variance,
                         "Variance of Gaussian noise added to the sharp image, intensities in [0,1] (Sec. 5)")
          ->check(CLI::Range(0.0, 1.0));
      command.add_option("--bits", args->options.bits, "Bit depth of the written images")->check(CLI::IsMember({8, 16}));
      command.add_option("--seed", args->options.seed, "Noise seed");
      command.add_option("--input-domain", args->input_domain,
                         "irradiance: the image is the latent irradiance (Sec. 5); intensity: it is already I")
          ->check(CLI::IsMember({"irradiance", "intensity"}));
      command.add_option("-o,--output", args->output, "Output directory (created or replaced atomically)")->required();
      command.add_flag("--force", args->force, kForceHelp);
      command.add_flag("-q,--quiet", args->quiet, "No progress output");
      return [args] { return runSimulate(*args); };
    });

}  // namespace
}  // namespace crfcal::app
