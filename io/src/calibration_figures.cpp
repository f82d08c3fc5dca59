#include "crfcal/io/calibration_figures.hpp"

#include <cstdio>

#include <opencv2/core.hpp>

#include "crfcal/io/figures.hpp"
#include "crfcal/io/plot.hpp"

namespace crfcal::io {
namespace {

std::string number(const char* format, double v) {
  char buffer[48];
  std::snprintf(buffer, sizeof buffer, format, v);
  return buffer;
}

cv::Scalar channelColour(const std::string& c) {
  return c == "R" ? cv::Scalar(40, 40, 220) : c == "G" ? cv::Scalar(40, 160, 40) : cv::Scalar(220, 80, 40);
}

// The legend entry of a channel's curve: "phi G - verdict: weak" (channel_verdict.hpp; reasons in report.json).
std::string curveLabel(const PairCalibrationResult& result, const std::string& c) {
  const auto verdict = result.verdicts.find(c);
  return "phi " + c + (verdict == result.verdicts.end() ? "" : std::string(" - verdict: ") + toString(verdict->second.level));
}

// φ per channel: a thick line over the intensities the data cover, a thin one where it is extrapolated, the
// covered ranges as bars along the bottom, the pointwise band shaded (curve_band.hpp); the RAW truth dashed.
void writeCurveFigure(const std::filesystem::path& path, const CalibrationFigureInputs& in) {
  std::vector<double> x(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) x[i] = static_cast<double>(i) / (kCurveSamples - 1);
  std::vector<PlotSeries> series{{x, x, cv::Scalar(150, 150, 150), "identity", 1, false, true}};
  PlotOptions plot;
  bool extrapolated = false;
  for (const char* c : {"R", "G", "B"}) {
    if (!in.result.fits.count(c)) continue;
    const std::vector<double>& phi = in.result.fits.at(c).inverse_crf;
    const auto band = in.result.bands.find(c);
    if (band != in.result.bands.end() && band->second.lower.size() == x.size())
      plot.bands.push_back({x, band->second.lower, band->second.upper, channelColour(c),
                            number("%.0f", 100 * band->second.level) + " % band " + c + " (shaded)"});
    const auto covered = in.result.covered_range.find(c);
    if (covered == in.result.covered_range.end()) {
      series.push_back({x, phi, channelColour(c), curveLabel(in.result, c)});
    } else {
      const auto [lo, hi] = covered->second;
      // three pieces sharing their end samples so that they join: below, inside, above the covered range
      auto piece = [&](double a, double b, const std::string& label, int thickness) {
        PlotSeries s{{}, {}, channelColour(c), label, thickness};
        for (size_t i = 0; i < phi.size(); ++i)
          if (x[i] >= a - 0.5 / kCurveSamples && x[i] <= b + 0.5 / kCurveSamples) s.x.push_back(x[i]), s.y.push_back(phi[i]);
        series.push_back(s);
      };
      piece(0, lo, "", 1);
      piece(hi, 1, "", 1);
      piece(lo, hi, curveLabel(in.result, c), 2);
      plot.x_ranges.push_back({lo, hi, channelColour(c),
                               std::string("data ") + c + " (bar under the axis): x " + number("%.2f", lo) + " - " + number("%.2f", hi)});
      extrapolated = extrapolated || lo > 0 || hi < 1;
    }
    if (in.raw_truth && in.raw_truth->count(c))
      series.push_back({x, in.raw_truth->at(c), channelColour(c), std::string("RAW truth ") + c, 1, false, true});
  }
  if (extrapolated) series.push_back({{}, {}, cv::Scalar(90, 90, 90), "thin: beyond the data (extrapolated)", 1});
  plot.title = "inverse response phi (" + in.pair.sharp.exposure.camera() + ")";
  plot.x_label = "intensity x (pixel value / max)";
  plot.size = {720, 580};
  plot.y_label = "irradiance phi(x)";
  plot.x_min = plot.y_min = 0;
  plot.x_max = plot.y_max = 1;
  writePlot(path, series, plot);
}

void writeGammaFigure(const std::filesystem::path& path, const CalibrationFigureInputs& in) {
  const double r = in.result.fits.count("G") ? in.result.fits.at("G").ratio : 1;
  std::string why = "red: the blurred shot is brighter, blue: darker. With a convex phi, Gamma >= 0 at edges "
                    "(Sec. 3.1, Theorem 1)";
  why += r > 1.05 ? "; the exposure ratio r = " + number("%.3g", r) +
                        " > 1 makes B brighter everywhere: a mostly red map is expected (the fit of phi explains it)"
                  : "; the exposure ratio r = " + number("%.3g", r) + ": Gamma concentrates at edges";
  FigureText text{"Blur inconsistency Gamma = B - I*K on G (blurred shot minus sharp shot blurred by the kernel)",
                  {why}};
  writeSignedMapFigure(path, in.result.gamma_map, text, {"Gamma, in intensity", "(1 = full scale)"});
}

void writeKernelFigure(const std::filesystem::path& path, const CalibrationFigureInputs& in) {
  FigureText text{in.result.kernel_estimated ? "Blur kernel K estimated from the pair" : "Blur kernel K (given)", {}};
  if (in.result.kernel_estimated)
    text.notes.push_back("RMS radius " + number("%.2f", in.result.blur_radius) + " px about its centroid (" +
                         number("%+.2f", in.result.kernel.centroid.x) + ", " +
                         number("%+.2f", in.result.kernel.centroid.y) + ") px");
  io::writeKernelFigure(path, in.result.kernel.kernel, text);
}

// The sharp shot as the fitter saw it: turned like calibratePair turned it, cropped to the fit window.
cv::Mat sharpInFitWindow(const CalibrationFigureInputs& in) {
  cv::Mat sharp = in.pair.sharp.image;
  if (in.result.sharp_rotation_deg != 0)
    cv::rotate(sharp, sharp, in.result.sharp_rotation_deg < 0 ? cv::ROTATE_90_CLOCKWISE : cv::ROTATE_90_COUNTERCLOCKWISE);
  const cv::Rect window = in.result.fit_window & cv::Rect(0, 0, sharp.cols, sharp.rows);
  if (window != in.result.fit_window || window.size() != in.result.weights.size()) return {};
  return sharp(window);
}

void writeWeightsFigure(const std::filesystem::path& path, const CalibrationFigureInputs& in) {
  const cv::Mat weights = in.result.weights.empty() ? cv::Mat::zeros(1, 1, CV_8U) : in.result.weights;
  FigureText text{"Pixels used by the fit of phi on G", {}};
  std::string unused = "not used: flat (W = 0), saturated, kernel leaves the image, or over the pixel budget";
  if (in.result.fits.count("G")) {
    const CrfPixelAccounting& p = in.result.fits.at("G").pixels;
    text.notes.push_back(std::to_string(p.used) + " of " + std::to_string(p.total) + " pixels used (" +
                         number("%.1f", 100.0 * p.used / std::max(1, p.total)) + " %); not used: " +
                         std::to_string(p.low_weight) + " flat, " + std::to_string(p.saturated) + " saturated, " +
                         std::to_string(p.border) + " at the border, " + std::to_string(p.subsampled) +
                         " over the pixel budget");
  }
  text.notes.push_back("backdrop: the sharp shot in the fit window, brightness stretched and dimmed");
  writeMaskFigure(path, weights, sharpInFitWindow(in), text, "used by the G fit (weight W > 0, Eq. 23/24)", unused);
}

}  // namespace

void writeCalibrationCurveFigure(const std::filesystem::path& path, const CalibrationFigureInputs& inputs) {
  writeCurveFigure(path, inputs);
}

void writeCalibrationFigures(const std::filesystem::path& directory, const CalibrationFigureInputs& inputs) {
  writeCurveFigure(directory / "curve.png", inputs);
  writeGammaFigure(directory / "gamma_map.png", inputs);
  writeKernelFigure(directory / "kernel.png", inputs);
  writeWeightsFigure(directory / "weights.png", inputs);
}

}  // namespace crfcal::io
