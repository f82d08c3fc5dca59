// crfcal bench pairs: semi-real handheld pairs with known truth (real photo, measured curve, real kernel,
// handheld misregistration, camera-like noise, JPEG, EXIF ratio) run through the whole calibrate pipeline.
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "bench_command.hpp"
#include "crfcal/error.hpp"
#include "crfcal/handheld_simulation.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/pair_calibration.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct PairsArgs {
  std::vector<std::string> images;
  std::vector<std::string> crfs{"emor:0", "emor:1.0,0.3", "emor:-1.0,0.2"};
  std::vector<std::string> kernels{"levin:1", "levin:3", "levin:8"};
  std::string output;
  double ratio = 1.0;
  double exif_error = 0.04;  // EXIF ratio = truth × (1 + this): camera hardware imprecision (Sec. 4)
  double shift = 4.3;
  double rotation = 0.4;
  int quality = 95;
  int max_side = 800;
  int kernel_size = 35;
  std::string channels = "g";
  bool pairs_only = false;
};

double cornerError(const cv::Mat& H, const cv::Mat& truth, cv::Size size) {
  std::vector<cv::Point2d> corners{{0, 0}, {size.width - 1.0, 0}, {0, size.height - 1.0}, {size.width - 1.0, size.height - 1.0}};
  std::vector<cv::Point2d> a, b;
  cv::perspectiveTransform(corners, a, H);
  cv::perspectiveTransform(corners, b, truth);
  double worst = 0;
  for (size_t i = 0; i < a.size(); ++i) worst = std::max(worst, cv::norm(a[i] - b[i]));
  return worst;
}

int runPairs(const PairsArgs& args) {
  if (args.images.empty()) throw InvalidInput("bench pairs: give at least one --image");
  Progress progress;
  io::OutputDirectory out(args.output);
  nlohmann::json results = nlohmann::json::array();
  std::ostringstream table;
  table << "| case | image | crf | kernel | phi_G RMSE | r fitted/true | kernel shape err | reg. corner err px | time s |\n"
        << "|---|---|---|---|---|---|---|---|---|\n";
  int index = 0;
  double sum_rmse = 0, sum_r = 0;
  int done = 0;
  for (const auto& image_path : args.images) {
    cv::Mat photo = io::readImage(image_path);
    if (photo.depth() != CV_8U) photo.convertTo(photo, CV_8U, 255.0 / 65535.0);
    const double s = std::min(1.0, static_cast<double>(args.max_side) / std::max(photo.cols, photo.rows));
    if (s < 1) cv::resize(photo, photo, cv::Size(), s, s, cv::INTER_AREA);
    for (const auto& crf : args.crfs) {
      for (const auto& kernel_spec : args.kernels) {
        ++index;
        const std::string name = "case" + std::to_string(index);
        progress.stage(name);
        const ResponseModel truth = io::parseResponseSpec(crf);
        const cv::Mat kernel = io::kernelFromSpec(kernel_spec);
        HandheldPairOptions ho;
        ho.ratio = args.ratio;
        ho.shift_x = args.shift;
        ho.shift_y = -0.6 * args.shift;
        ho.rotation_deg = args.rotation;
        ho.seed = static_cast<std::uint64_t>(index);
        const HandheldPair pair = makeHandheldPair(photo, truth, kernel, ho);
        const fs::path dir = out.file(name);
        fs::create_directories(dir);
        const std::vector<int> jpeg{cv::IMWRITE_JPEG_QUALITY, args.quality};
        cv::imwrite((dir / "sharp.jpg").string(), pair.sharp, jpeg);
        cv::imwrite((dir / "blurred.jpg").string(), pair.blurred, jpeg);
        ExifExposure es, eb;
        es.make = eb.make = "crfcal";
        es.model = eb.model = "semi-real handheld";
        es.iso = 800;
        es.exposure_time = 0.01;
        es.f_number = eb.f_number = 4.0;
        eb.iso = 100;
        eb.exposure_time = args.ratio * (1 + args.exif_error) * 800 * 0.01 / 100;
        io::writeExif(dir / "sharp.jpg", es);
        io::writeExif(dir / "blurred.jpg", eb);
        nlohmann::json truth_json = {{"inverse_crf", sampleInverse(truth)}, {"crf_spec", crf}, {"kernel_spec", kernel_spec},
                                     {"exposure_ratio", args.ratio}, {"exif_ratio", *eb.exposure_time * 100 / 8.0},
                                     {"homography", std::vector<double>(pair.homography.begin<double>(), pair.homography.end<double>())},
                                     {"image", image_path}};
        io::writeTextFile(dir / "truth.json", truth_json.dump(1) + "\n");
        if (args.pairs_only) {
          progress.done();
          continue;
        }
        const auto t0 = std::chrono::steady_clock::now();
        nlohmann::json row = {{"case", name}, {"image", fs::path(image_path).filename().string()}, {"crf", crf}, {"kernel", kernel_spec}};
        try {
          const io::LoadedPair loaded = io::loadPair(dir / "sharp.jpg", dir / "blurred.jpg");
          PairCalibrationOptions options;
          options.kernel.kernel_size = args.kernel_size;
          options.rgb = args.channels == "rgb";
          options.fit.initial_ratio = loaded.exif_ratio->ratio();
          const PairCalibrationResult r = calibratePair(loaded.sharp.image, loaded.blurred.image, options);
          const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
          const double rmse = curveRmse(r.fits.at("G").inverse_crf, sampleInverse(truth));
          const double rr = r.fits.at("G").ratio / args.ratio;
          const double kerr = kernelShapeError(r.kernel.kernel, kernel);
          const double cerr = cornerError(r.registration.homography, pair.homography, photo.size());
          row.update({{"phi_rmse_G", rmse}, {"ratio_fitted_over_true", rr}, {"kernel_shape_error", kerr},
                      {"registration_corner_error_px", cerr}, {"seconds", seconds}, {"swapped", loaded.swapped}});
          char line[300];
          std::snprintf(line, sizeof line, "| %s | %s | %s | %s | %.4f | %.4f | %.3f | %.2f | %.1f |\n", name.c_str(),
                        fs::path(image_path).filename().string().c_str(), crf.c_str(), kernel_spec.c_str(), rmse, rr,
                        kerr, cerr, seconds);
          table << line;
          sum_rmse += rmse;
          sum_r += std::abs(rr - 1);
          ++done;
          progress.done(line);
        } catch (const Error& e) {
          row["error"] = e.what();
          table << "| " << name << " | failed: " << e.what() << " |||||||\n";
          progress.done(std::string("FAILED: ") + e.what());
        }
        results.push_back(row);
      }
    }
  }
  if (done > 0) {
    char line[200];
    std::snprintf(line, sizeof line, "\nmean phi_G RMSE %.4f, mean |r_fitted/r_true - 1| %.4f over %d cases\n",
                  sum_rmse / done, sum_r / done, done);
    table << line;
  }
  io::writeTextFile(out.file("results.json"), results.dump(1) + "\n");
  io::writeTextFile(out.file("results.md"), table.str());
  out.commit();
  std::printf("%s", table.str().c_str());
  std::printf("wrote %s/{results.md, results.json, case*/}\n", args.output.c_str());
  return kExitOk;
}

const BenchRegistration registration(
    40, "pairs",
    "Semi-real handheld pairs (real photo, measured curve, real kernel, shift+rotation, noise, JPEG, EXIF) "
    "through the calibrate pipeline: phi RMSE, ratio, kernel and registration errors",
    [](CLI::App& command) {
      auto args = std::make_shared<PairsArgs>();
      command.add_option("--image", args->images, "Real photo(s) to make pairs from")->required()->check(CLI::ExistingFile);
      command.add_option("--crf", args->crfs, "True inverse response(s) phi (spec)");
      command.add_option("--kernel", args->kernels, "True kernel(s): levin:N | box:L | FILE");
      command.add_option("--ratio", args->ratio, "True exposure ratio r")->check(CLI::PositiveNumber);
      command.add_option("--exif-error", args->exif_error, "Relative error of the EXIF ratio against the truth");
      command.add_option("--shift", args->shift, "Handheld shift (x; y = -0.6 x), pixels");
      command.add_option("--rotation", args->rotation, "Handheld rotation, degrees");
      command.add_option("--quality", args->quality, "JPEG quality")->check(CLI::Range(50, 100));
      command.add_option("--max-side", args->max_side, "Downscale the photo to this longest side");
      command.add_option("--kernel-size", args->kernel_size, "Kernel size limit for estimation (odd)");
      command.add_option("--channels", args->channels, "g or rgb")->check(CLI::IsMember({"g", "rgb"}));
      command.add_flag("--pairs-only", args->pairs_only, "Only write the pairs (no calibration)");
      command.add_option("-o,--output", args->output, "Output directory")->required();
      return [args] { return runPairs(*args); };
    });

}  // namespace
}  // namespace crfcal::app
