#include "crfcal/io/bracket_report.hpp"

#include <cmath>
#include <cstdio>
#include <map>

#include <opencv2/imgproc.hpp>

#include "crfcal/io/band_report.hpp"
#include "crfcal/io/figures.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/io/response_io.hpp"

namespace crfcal::io {
namespace {

constexpr const char* kBracketBandMethod =
    "half-sample refits of the scene points, K and exposures held (shape) + local-exponent bounds beyond the covered "
    "range (scale); scaled_fit_band.hpp";

nlohmann::json optionalNumber(const std::optional<double>& v) { return v ? nlohmann::json(*v) : nlohmann::json(nullptr); }

nlohmann::json frameJson(const BracketFrameResult& f, const ExifExposure* exif) {
  nlohmann::json j;
  j["image"] = f.name;
  if (exif)
    j["exif"] = {{"iso", optionalNumber(exif->iso)},
                 {"exposure_time", optionalNumber(exif->exposure_time)},
                 {"f_number", optionalNumber(exif->f_number)},
                 {"camera", exif->camera()}};
  j["nominal_exposure"] = f.nominal_exposure > 0 ? nlohmann::json(f.nominal_exposure) : nlohmann::json(nullptr);
  j["start_exposure"] = f.start_exposure;
  j["fitted_exposure"] = f.fitted_exposure;
  j["reference"] = f.reference;
  j["registration"] = {{"method", f.registration.method},
                       {"ecc_correlation", f.registration.ecc_correlation},
                       {"shift", {f.registration.shift().x, f.registration.shift().y}},
                       {"rotation_deg", f.registration.rotationDegrees()}};
  j["scene_correlation"] = std::isfinite(f.scene_correlation) ? nlohmann::json(f.scene_correlation) : nlohmann::json(nullptr);
  return j;
}

nlohmann::json channelJson(const BracketChannelResult& c) {
  nlohmann::json ch;
  ch["emor"] = modelToJson(c.fit.model);
  ch["terms"] = c.fit.terms;
  ch["cv_rmse"] = nlohmann::json::object();
  for (const auto& [k, e] : c.fit.cv_rmse) ch["cv_rmse"][std::to_string(k)] = e;
  ch["rmse"] = c.fit.rmse;
  ch["points"] = c.points;
  ch["observations"] = c.fit.observations;
  ch["ggcm_rmse_vs_emor"] = c.ggcm_rmse;
  ch["ggcm_valid"] = c.ggcm_valid;
  return ch;
}

cv::Scalar channelColour(const std::string& c) {
  return c == "R" ? cv::Scalar(40, 40, 220) : c == "G" ? cv::Scalar(40, 160, 40) : cv::Scalar(220, 80, 40);
}

std::string number(const char* format, double v) {
  char buffer[48];
  std::snprintf(buffer, sizeof buffer, format, v);
  return buffer;
}

}  // namespace

CalibrationReport bracketReport(const BracketCalibrationResult& result, const std::vector<ExifExposure>& exif) {
  CalibrationReport report;
  report.command = "bracket";
  report.warnings = result.warnings;
  nlohmann::json channels = nlohmann::json::object();
  std::map<std::string, CurveBand> bands;
  for (const auto& c : result.channels) {
    const std::string name = channelName(c.channel);
    addScaledFitChannel(report, name, c.fit, c.ggcm);
    channels[name] = channelJson(c);
    if (!c.band.empty()) bands[name] = c.band;
  }
  if (!bands.empty()) report.extra["inverse_crf_band"] = curveBandsJson(bands, kBracketBandMethod);
  nlohmann::json frames = nlohmann::json::array();
  for (std::size_t j = 0; j < result.frames.size(); ++j)
    frames.push_back(frameJson(result.frames[j], j < exif.size() ? &exif[j] : nullptr));
  report.extra["bracket"] = {{"frames", frames},
                             {"exposure_source", result.exposure_source},
                             {"points", result.points},
                             {"channels", channels},
                             {"inverse_crf_model", "emor (models: its GGCM conversion, seed Eq. 19)"}};
  return report;
}

void writeBracketFigures(const std::filesystem::path& curve_png, const std::filesystem::path& points_png,
                         const BracketCalibrationResult& result, const cv::Mat& reference_image,
                         const std::string& camera) {
  std::vector<double> x(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) x[static_cast<std::size_t>(i)] = double(i) / (kCurveSamples - 1);
  std::vector<PlotSeries> series{{x, x, cv::Scalar(150, 150, 150), "identity", 1, false, true}};
  PlotOptions plot;
  for (const auto& c : result.channels) {
    const std::string name = channelName(c.channel);
    const auto [lo, hi] = c.fit.covered_range;
    auto piece = [&](double a, double b, const std::string& label, int thickness) {
      PlotSeries s{{}, {}, channelColour(name), label, thickness};
      for (std::size_t i = 0; i < x.size(); ++i)
        if (x[i] >= a - 0.5 / kCurveSamples && x[i] <= b + 0.5 / kCurveSamples) s.x.push_back(x[i]), s.y.push_back(c.fit.inverse[i]);
      series.push_back(s);
    };
    piece(0, lo, "", 1);
    piece(hi, 1, "", 1);
    piece(lo, hi, "phi " + name + " (EMoR K=" + std::to_string(c.fit.terms) + ", " + std::to_string(c.points) + " points)", 2);
    if (c.band.lower.size() == x.size())
      plot.bands.push_back({x, c.band.lower, c.band.upper, channelColour(name),
                            number("%.0f", 100 * c.band.level) + " % band " + name + " (shaded)"});
    plot.x_ranges.push_back({lo, hi, channelColour(name),
                             "data " + name + ": x " + number("%.2f", lo) + " - " + number("%.2f", hi)});
  }
  series.push_back({{}, {}, cv::Scalar(90, 90, 90), "thin: beyond the data (extrapolated)", 1});
  plot.title = "inverse response phi from a " + std::to_string(result.frames.size()) + "-frame bracket (" + camera + ")";
  plot.x_label = "intensity x (pixel value / max)";
  plot.y_label = "irradiance phi(x)";
  plot.size = {720, 580};
  plot.x_min = plot.y_min = 0;
  plot.x_max = plot.y_max = 1;
  writePlot(curve_png, series, plot);

  cv::Mat mask = cv::Mat::zeros(reference_image.size(), CV_8U);
  for (const cv::Point& p : result.point_positions) cv::circle(mask, p, std::max(2, reference_image.cols / 300), cv::Scalar(255), -1);
  FigureText text{"Scene points sampled for the bracket fit (flat areas, spread over the brightness range)",
                  {std::to_string(result.points) + " points; each one's value is the local mean of each channel in every "
                                                     "frame, used where neither near 0 nor clipped"}};
  writeMaskFigure(points_png, mask, reference_image, text, "sampled scene point", "reference frame (dimmed)");
}

}  // namespace crfcal::io
