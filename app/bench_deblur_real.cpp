#include "bench_deblur_real.hpp"

#include <cstdio>
#include <string>
#include <vector>

#include "command.hpp"
#include "crfcal/deconvolution.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/reference_comparison.hpp"
#include "crfcal/registration.hpp"
#include "deblur_inputs.hpp"

namespace crfcal::app {
namespace fs = std::filesystem;
namespace {

struct RealRow {
  int pair = 0;
  std::vector<double> ratio;
  double reference_overlap = 0;
  ReferenceScore blurred, intensity, irradiance, residual, sharp;
};

RealRow deblurTriplet(const fs::path& data, const fs::path& reports, int n, const ResidualDeconvolutionOptions& options) {
  const std::string suffix = "_" + std::to_string(n) + ".jpg";
  const std::string blurred_path = (data / ("blurred" + suffix)).string(), sharp_path = (data / ("noisy" + suffix)).string();
  const fs::path report = reports / std::to_string(n) / "report.json";
  const cv::Mat blurred = toUnit(io::readImage(blurred_path));
  const cv::Mat sharp = readSharpShot(sharp_path, blurred, blurred_path);
  const cv::Mat kernel = kernelOfReport(report);
  const std::vector<ResponseCurve> curves = curvesFor(report.string(), blurred.channels());

  DeconvolutionOptions blind = options.deconvolution;
  blind.domain = DeconvolutionDomain::Intensity;
  const cv::Mat intensity = deconvolve(blurred, kernel, curves, blind).deblurred;
  blind.domain = DeconvolutionDomain::Irradiance;
  const cv::Mat irradiance = deconvolve(blurred, kernel, curves, blind).deblurred;
  cv::Mat turned = sharp;
  cv::Mat homography = sharp.size() == blurred.size() ? homographyOfReport(report) : cv::Mat();
  if (homography.empty()) homography = registerTurning(sharp, blurred, turned).homography;
  const ResidualDeconvolutionResult residual = deconvolveResidual(blurred, turned, homography, kernel, curves, options);

  // The reference registered into the blurred frame and matched to the blurred shot's brightness (monotone).
  const cv::Mat reference_raw = io::readImage((data / ("g_truth" + suffix)).string());
  cv::Mat reference_turned;
  const RegistrationResult to_reference = registerTurning(reference_raw, blurred, reference_turned);
  const cv::Mat reference = toUnit(warpToBlurred(reference_turned, to_reference.homography, blurred.size()));
  const cv::Mat common = overlapMask(reference_turned.size(), to_reference.homography, blurred.size(), 16);
  const cv::Mat matched = matchBrightness(reference, blurred, common);

  RealRow row;
  row.pair = n;
  row.ratio = residual.ratio;
  row.reference_overlap = cv::countNonZero(common) / static_cast<double>(blurred.total());
  row.blurred = scoreAgainstReference(blurred, matched, common);
  row.intensity = scoreAgainstReference(intensity, matched, common);
  row.irradiance = scoreAgainstReference(irradiance, matched, common);
  row.residual = scoreAgainstReference(residual.deblurred, matched, common);
  row.sharp = scoreAgainstReference(residual.sharp_denoised, matched, common);
  return row;
}

}  // namespace

int runRealDeblurBench(const fs::path& data, const fs::path& reports, const ResidualDeconvolutionOptions& options) {
  std::vector<RealRow> rows;
  for (int n = 1; fs::exists(data / ("blurred_" + std::to_string(n) + ".jpg")); ++n)
    rows.push_back(deblurTriplet(data, reports, n, options));
  if (rows.empty()) throw Error("no blurred_1.jpg (triplets noisy_N / blurred_N / g_truth_N.jpg)", data.string());
  std::printf("real triplets of %s, each deblurred with its own calibration (%s/N/report.json); PSNR dB / SSIM "
              "against g_truth_N registered into the blurred frame (16 px inside the overlap) and brightness-matched "
              "to the blurred shot by a monotone (quantile) map per channel\n", data.string().c_str(),
              reports.string().c_str());
  std::printf("%4s %8s %8s | %15s | %15s | %15s | %15s | %15s\n", "pair", "r (G)", "overlap", "blurred",
              "TV intensity", "TV irradiance", "residual+sharp", "sharp denoised");
  RealRow mean;
  const auto cell = [](const ReferenceScore& s) { std::printf(" | %6.2f  %.4f", s.psnr, s.ssim); };
  const auto add = [](ReferenceScore& a, const ReferenceScore& b) { a.psnr += b.psnr, a.ssim += b.ssim; };
  for (const RealRow& row : rows) {
    std::printf("%4d %8.2f %7.1f%%", row.pair, row.ratio[row.ratio.size() / 2], 100 * row.reference_overlap);
    for (const ReferenceScore* s : {&row.blurred, &row.intensity, &row.irradiance, &row.residual, &row.sharp}) cell(*s);
    std::printf("\n");
    add(mean.blurred, row.blurred), add(mean.intensity, row.intensity), add(mean.irradiance, row.irradiance);
    add(mean.residual, row.residual), add(mean.sharp, row.sharp);
  }
  std::printf("%4s %8s %8s", "mean", "", "");
  for (ReferenceScore* s : {&mean.blurred, &mean.intensity, &mean.irradiance, &mean.residual, &mean.sharp}) {
    s->psnr /= rows.size(), s->ssim /= rows.size();
    cell(*s);
  }
  std::printf("\n");
  return kExitOk;
}

}  // namespace crfcal::app
