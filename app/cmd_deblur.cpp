// crfcal deblur: non-blind deconvolution with a known kernel and the camera's response (the seed's Sec. 3.2):
// deblurring in irradiance (φ(B), deconvolve, ψ) avoids the ringing that deblurring intensities shows around
// high-contrast edges (Eq. 18). Both domains are written so that the difference can be seen.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "command.hpp"
#include "crfcal/deconvolution.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/output_guard.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/report.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct DeblurArgs {
  std::string blurred;
  std::string kernel;
  std::string crf;
  std::string from;
  std::string domain = "irradiance";
  std::string method = "tv";
  double lambda = DeconvolutionOptions{}.lambda;
  double wiener_nsr = DeconvolutionOptions{}.wiener_nsr;
  double saturation = DeconvolutionOptions{}.saturation;
  std::string output;
  bool force = false;  // write into an output directory holding other files (never deletes them)
};

bool endsWith(const std::string& text, const std::string& suffix) {
  return text.size() >= suffix.size() && text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// One φ per image channel (OpenCV order B, G, R; grey: G). A report (or "table:REPORT.json") gives each channel its
// own curve, falling back to G for channels it lacks; any other spec is one curve for all channels.
std::vector<ResponseCurve> curvesFor(const std::string& spec, int channels) {
  std::string path = spec.rfind("table:", 0) == 0 ? spec.substr(6) : spec;
  if (!endsWith(path, ".json")) return {ResponseCurve(io::parseResponseSpec(spec))};
  const io::CalibrationReport report = io::readReport(path);
  const std::vector<std::string> names = channels == 1 ? std::vector<std::string>{"G"}
                                                       : std::vector<std::string>{"B", "G", "R"};
  std::vector<ResponseCurve> curves;
  for (const std::string& name : names) {
    auto found = report.inverse_crf.find(name);
    if (found == report.inverse_crf.end()) found = report.inverse_crf.find("G");
    if (found == report.inverse_crf.end()) throw Error("no inverse_crf for channel " + name + " or G", path);
    try {
      curves.push_back(ResponseCurve::fromSamples(found->second));
    } catch (const InvalidInput& e) {
      throw Error("inverse_crf " + found->first + ": " + e.reason(), path);
    }
  }
  return curves;
}

// The kernel a calibration report points to: "kernel": {"text": "kernel.txt"} beside report.json.
cv::Mat kernelOfReport(const fs::path& report_path) {
  const io::CalibrationReport report = io::readReport(report_path);
  const auto entry = report.extra.find("kernel");
  if (entry == report.extra.end() || !entry->is_object())
    throw Error("the report records no kernel (give --kernel)", report_path.string());
  const std::string text = entry->value("text", std::string("kernel.txt"));
  return io::readKernel(report_path.parent_path() / text);
}

cv::Mat toUnit(const cv::Mat& image) {
  cv::Mat colour = image;
  if (image.channels() == 4) cv::cvtColor(image, colour, cv::COLOR_BGRA2BGR);
  if (colour.channels() != 1 && colour.channels() != 3)
    throw InvalidInput("images to deblur must be grey or colour");
  const double scale = colour.depth() == CV_16U ? 1.0 / 65535 : colour.depth() == CV_8U ? 1.0 / 255 : 1.0;
  cv::Mat unit;
  colour.convertTo(unit, CV_MAKETYPE(CV_64F, colour.channels()), scale);
  return unit;
}

// blurred | intensity-domain | irradiance-domain, 8-bit, a caption above each panel.
cv::Mat sideBySide(const cv::Mat& blurred, const cv::Mat& intensity, const cv::Mat& irradiance) {
  const int caption = 28;
  std::vector<cv::Mat> panels;
  const std::pair<const cv::Mat*, const char*> items[] = {
      {&blurred, "blurred"}, {&intensity, "intensity domain"}, {&irradiance, "irradiance domain"}};
  for (const auto& [image, label] : items) {
    cv::Mat bgr, eight;
    cv::Mat clamped = cv::min(cv::max(*image, 0.0), 1.0);
    clamped.convertTo(eight, CV_MAKETYPE(CV_8U, clamped.channels()), 255.0);
    if (eight.channels() == 1) cv::cvtColor(eight, bgr, cv::COLOR_GRAY2BGR);
    else bgr = eight;
    cv::Mat panel(bgr.rows + caption, bgr.cols, CV_8UC3, cv::Scalar(255, 255, 255));
    bgr.copyTo(panel(cv::Rect(0, caption, bgr.cols, bgr.rows)));
    cv::putText(panel, label, {6, caption - 8}, cv::FONT_HERSHEY_SIMPLEX, 0.6, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
    panels.push_back(panel);
    panels.push_back(cv::Mat(panel.rows, 4, CV_8UC3, cv::Scalar(255, 255, 255)));
  }
  panels.pop_back();
  cv::Mat joined;
  cv::hconcat(panels, joined);
  return joined;
}

int runDeblur(const DeblurArgs& args) {
  DeconvolutionOptions options;
  options.method = parseDeconvolutionMethod(args.method);
  options.domain = parseDeconvolutionDomain(args.domain);
  options.lambda = args.lambda;
  options.wiener_nsr = args.wiener_nsr;
  options.saturation = args.saturation;
  options.check();
  if (args.kernel.empty() && args.from.empty()) throw InvalidInput("give --kernel or --from REPORT.json");
  if (args.crf.empty() && args.from.empty()) throw InvalidInput("give --crf or --from REPORT.json");

  // Decided before the computation: a refused or unwritable output directory fails at once.
  std::vector<std::filesystem::path> inputs{args.blurred};
  for (const auto* spec : {&args.kernel, &args.crf}) if (!spec->empty()) inputs.push_back(io::specInput(*spec));
  if (!args.from.empty()) {
    inputs.push_back(args.from);
    inputs.push_back(std::filesystem::path(args.from).parent_path() / "kernel.txt");
  }
  io::OutputDirectory out(args.output, {"deblur", inputs, args.force});

  const cv::Mat blurred = toUnit(io::readImage(args.blurred));
  const cv::Mat kernel = !args.kernel.empty() ? io::kernelFromSpec(args.kernel) : kernelOfReport(args.from);
  const std::vector<ResponseCurve> curves = curvesFor(args.crf.empty() ? args.from : args.crf, blurred.channels());

  const DeconvolutionResult chosen = deconvolve(blurred, kernel, curves, options);
  DeconvolutionOptions other_options = options;
  other_options.domain = options.domain == DeconvolutionDomain::Irradiance ? DeconvolutionDomain::Intensity
                                                                           : DeconvolutionDomain::Irradiance;
  const DeconvolutionResult other = deconvolve(blurred, kernel, curves, other_options);
  const bool irradiance_chosen = options.domain == DeconvolutionDomain::Irradiance;
  const cv::Mat& intensity_result = irradiance_chosen ? other.deblurred : chosen.deblurred;
  const cv::Mat& irradiance_result = irradiance_chosen ? chosen.deblurred : other.deblurred;

  io::writeUnitImage(out.file("deblurred.png"), chosen.deblurred, 16);
  io::writeUnitImage(out.file("deblurred_other_domain.png"), other.deblurred, 16);
  io::writeImage(out.file("side_by_side.png"), sideBySide(blurred, intensity_result, irradiance_result));
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
      command.add_option("--domain", args->domain,
                         "Domain of deblurred.png: irradiance (phi(B), deconvolve, psi) or intensity (B directly); "
                         "deblurred_other_domain.png holds the other")
          ->check(CLI::IsMember({"irradiance", "intensity"}));
      command.add_option("--method", args->method, "tv (FTVd total variation) or wiener")
          ->check(CLI::IsMember({"tv", "wiener"}));
      command.add_option("--lambda", args->lambda, "TV data weight (larger: sharper, noisier)")
          ->check(CLI::PositiveNumber);
      command.add_option("--wiener-nsr", args->wiener_nsr, "Wiener noise-to-signal ratio")->check(CLI::PositiveNumber);
      command.add_option("--saturation", args->saturation,
                         "Pixels at or above this level (0..1) are saturated and left out of the TV data term")
          ->check(CLI::Range(0.01, 1.0));
      command.add_option("-o,--output", args->output, "Output directory (see --force)")->required();
      command.add_flag("--force", args->force, kForceHelp);
      return [args] { return runDeblur(*args); };
    });

}  // namespace
}  // namespace crfcal::app
