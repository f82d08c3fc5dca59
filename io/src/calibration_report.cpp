#include "crfcal/io/calibration_report.hpp"

#include <cmath>
#include <vector>

#include "crfcal/io/band_report.hpp"
#include "crfcal/io/kernel_io.hpp"

namespace crfcal::io {
namespace {

using nlohmann::json;

std::vector<double> matrixValues(const cv::Mat& m) { return std::vector<double>(m.begin<double>(), m.end<double>()); }

json effectsJson(const EffectReport& effects) {
  json out = json::array();
  for (const auto& e : effects.entries)
    out.push_back({{"name", e.name}, {"detected", e.detected}, {"tested", e.tested}, {"statistic", e.statistic},
                   {"threshold", e.threshold}, {"gain", e.gain}, {"gain_threshold", e.gain_threshold},
                   {"parameters", e.parameters}, {"detail", e.detail},
                   // attribution: the evidence against the competing explanation that came closest (effects.hpp)
                   {"runner_up", e.runner_up}, {"runner_up_gain", e.runner_up_gain},
                   {"evidence_gain", e.evidence_gain}, {"evidence_z", e.evidence_z},
                   {"explained_by", e.explained_by}});
  return out;
}

// Warnings about the inputs, after the calibration's own: a swapped pair, linear data, chroma subsampling.
void addInputWarnings(const PairCalibrationResult& result, const LoadedPair& pair, std::vector<std::string>& warnings) {
  if (pair.swapped) warnings.push_back("the first image is the blurred one (" + pair.blurred_reason + "); swapped");
  if (pair.sharp.linear)
    warnings.push_back("RAW pair: the data are linear (phi should be the identity; the fit checks it)");
  // One warning naming every chroma-subsampled shot (only when R and B are fitted: G is carried by luma).
  std::vector<std::string> subsampled;
  for (const auto* shot : {&pair.sharp, &pair.blurred})
    if (shot->chroma_subsampled) subsampled.push_back(shot->path.string() + " (" + shot->chroma_subsampling + ")");
  // With the chroma model (issue 20) R and B avoid the sharp shot's chroma detail; the blurred shot's subsampling
  // alone does not matter (its blur removed the detail), so then no warning.
  const bool modelled = !result.chroma_model_channels.empty();
  if (!subsampled.empty() && result.fits.size() > 1 && !modelled) {
    std::string files = subsampled.front();
    if (subsampled.size() > 1) files += " and " + subsampled.back();
    warnings.push_back(files + ": JPEG chroma subsampled: R and B are rebuilt from chroma averaged across "
                       "edges after the tone curve, so their curves are less reliable than G's (see "
                       "docs/RESULTS.md#chroma)");
  }
}

json inputJson(const LoadedPair& pair) {
  json input = {{"sharp", pair.sharp.path.string()},
                {"blurred", pair.blurred.path.string()},
                {"format", pair.sharp.format},
                {"chroma_subsampling",
                 {{"sharp", pair.sharp.chroma_subsampling}, {"blurred", pair.blurred.chroma_subsampling}}},
                {"linear", pair.sharp.linear},
                {"blurred_reason", pair.blurred_reason},
                {"camera", pair.sharp.exposure.camera()},
                {"size", {pair.blurred.image.cols, pair.blurred.image.rows}}};
  if (pair.sharp.linear) input["raw_levels"] = {{"black", pair.sharp.black_level}, {"white", pair.sharp.white_level}};
  return input;
}

// The exposure ratio r = Δt_B/Δt_I (footnote 4) beyond report.hpp's "exposure_ratio": the EXIF factors, how r was
// used, what the fit made of it per channel.
void addExposureRatio(const PairCalibrationResult& result, const CalibrationReportContext& context, json& extra) {
  const LoadedPair& pair = context.pair;
  if (pair.exif_ratio)
    extra["exposure_ratio_factors"] = {{"iso", pair.exif_ratio->iso},
                                       {"time", pair.exif_ratio->time},
                                       {"aperture", pair.exif_ratio->aperture},
                                       {"aperture_known", pair.exif_ratio->aperture_known},
                                       {"sharp", pair.sharp.exposure.summary()},
                                       {"blurred", pair.blurred.exposure.summary()}};
  extra["exposure_ratio_mode"] = context.ratio_fixed_by_option        ? "fixed (--fix-ratio)"
                                 : result.ratio_fixed_by_small_blur ? "fixed (blur too small to determine r)"
                                 : result.ratio_from_evidence       ? "combined (images and nominal ratio)"
                                                                    : "fitted";
  // The images' r combined with the nominal ratio (ratio_evidence.hpp): both sources with their σ in log r.
  if (const RatioEvidence& e = result.ratio_evidence; e.combined)
    extra["exposure_ratio_evidence"] = {{"ratio", e.ratio},
                                        {"log_sigma", e.log_sigma},
                                        {"images_ratio", e.images_ratio},
                                        {"images_log_sigma", e.images_log_sigma},
                                        {"images_resampled_log_sigma", e.resampled_log_sigma},
                                        {"images_noise_bias_log", e.noise_bias_log},
                                        {"images_replicate_ratios", e.replicate_ratios},
                                        {"nominal_ratio", e.nominal_ratio},
                                        {"nominal_log_sigma", e.nominal_log_sigma},
                                        {"images_weight", e.images_weight},
                                        {"difference_sigmas", e.conflict_sigmas},
                                        {"conflict", e.conflict},
                                        {"brightness_interval", {e.brightness_low, e.brightness_high}},
                                        {"decision", toString(e.decision)},
                                        {"refitted", result.ratio_from_evidence},
                                        {"not_adopted_reason", e.not_adopted_reason}};
  extra["exposure_ratio_per_channel"] = json::object();
  extra["ambiguity_rise"] = json::object();  // CrfFitResult::ambiguity_rise per channel
  for (const auto& [name, fit] : result.fits) {
    extra["exposure_ratio_per_channel"][name] = fit.ratio;
    extra["ambiguity_rise"][name] = fit.ambiguity_rise;
  }
  // the prior on log r (CrfFitOptions::ratio_prior_sigma) and what the images alone say, per channel
  if (!context.ratio_fixed_by_option && context.ratio_prior_sigma > 0) {
    extra["exposure_ratio_prior"] = {
        {"centre", context.nominal_ratio}, {"log_sigma", context.ratio_prior_sigma}, {"images_only", json::object()}};
    for (const auto& [name, fit] : result.fits)
      if (fit.ratio_images_only > 0) extra["exposure_ratio_prior"]["images_only"][name] = fit.ratio_images_only;
  }
}

json kernelJson(const PairCalibrationResult& result) {
  const cv::Mat& K = result.kernel.kernel;
  json kernel = {{"size", {K.cols, K.rows}}, {"file", "kernel.png"}, {"text", "kernel.txt"},
                 {"estimated", result.kernel_estimated}};
  if (!result.kernel_estimated) return kernel;
  kernel["centroid"] = {result.kernel.centroid.x, result.kernel.centroid.y};
  kernel["blur_rms_radius_px"] = result.blur_radius;
  // the sharp shot's black share when the estimate needed its black areas admitted (0: it did not)
  kernel["sharp_black_admitted"] = result.kernel_sharp_black_admitted;
  // the size the estimate grew to when it reached its limit (0: it did not)
  kernel["grown_to"] = result.kernel_grown_to;
  kernel["equations"] = result.kernel.equations;
  kernel["border_mass"] = result.kernel.border_mass;
  kernel["relative_residual"] = result.kernel.relative_residual;
  kernel["tiles"] = result.tiles.size();
  if (result.tile_kernels.size() > 1) {
    kernel["tile_disagreement"] = {{"mean_relative", result.disagreement.mean_relative},
                                   {"max_relative", result.disagreement.max_relative},
                                   {"centroid_spread_px", result.disagreement.centroid_spread},
                                   {"varies", result.disagreement.varies()}};
    json tile_kernels = json::array();
    for (const TileKernel& t : result.tile_kernels) {
      const cv::Rect& rect = result.tiles.at(static_cast<std::size_t>(t.tile)).rect;
      const cv::Point2d centre = result.tileCentreInBlurred(t);
      tile_kernels.push_back({{"tile", t.tile},
                              {"region_in_sharp", {rect.x, rect.y, rect.width, rect.height}},
                              {"centre_in_blurred", {centre.x, centre.y}},
                              {"size", {t.kernel.cols, t.kernel.rows}},
                              {"text", tileKernelFileName(t.tile)}});
    }
    kernel["tile_kernels"] = tile_kernels;
  }
  return kernel;
}

json registrationJson(const RegistrationResult& registration) {
  return {{"method", registration.method},
          {"homography", matrixValues(registration.homography)},
          {"ecc_correlation", registration.ecc_correlation},
          {"overlap", registration.overlap_fraction},
          {"inliers", registration.inliers},
          {"shift_px", {registration.shift().x, registration.shift().y}},
          {"rotation_deg", registration.rotationDegrees()}};
}

// The kernel ↔ φ rounds, the fit window and each channel's fit (model, choice, energy).
void addFitDetails(const PairCalibrationResult& result, json& extra) {
  extra["rounds"] = json::array();
  for (const auto& r : result.rounds)
    extra["rounds"].push_back({{"round", r.round},
                               {"kernel_change", r.kernel_change},
                               {"phi_change_rmse", r.phi_change},
                               {"ratio", r.ratio},
                               {"kernel_residual", r.kernel_residual}});
  extra["fit_window"] = {result.fit_window.x, result.fit_window.y, result.fit_window.width, result.fit_window.height};
  extra["fit"] = json::object();
  for (const auto& [name, fit] : result.fits)
    extra["fit"][name] = {{"model", describe(fit.model)}, {"chosen", fit.chosen},   {"reason", fit.choice_reason},
                          {"energy", fit.energy},         {"iterations", fit.iterations},
                          {"noise_sigma", fit.noise_sigma}};
  if (!result.base_fits.empty()) {
    extra["phi_base_model"] = json::object();
    for (const auto& [name, fit] : result.base_fits) extra["phi_base_model"][name] = fit.inverse_crf;
  }
}

json rawTruthJson(const RawTruthReport& truth) {
  const RawTruthResult& r = truth.result;
  json out = {{"file", truth.file.path.string()},
              {"format", truth.file.format},
              {"camera_raw", truth.file.linear},
              {"shot", truth.blurred_shot ? "blurred" : "sharp"},
              {"shot_file", truth.shot_file},
              {"shot_reason", truth.shot_reason},
              {"inverse_crf", r.inverse()},
              {"covered_range", json::object()},
              {"channels", json::object()},
              {"overlap_pixels", r.overlap_pixels},
              {"flat_pixels", r.flat_pixels},
              {"warnings", r.warnings}};
  if (truth.file.linear) out["raw_levels"] = {{"black", truth.file.black_level}, {"white", truth.file.white_level}};
  for (const auto& [name, range] : r.covered()) out["covered_range"][name] = {range.first, range.second};
  for (const auto& c : r.channels) {
    json cv = json::array();
    for (const auto& [k, e] : c.fit.cv_rmse) cv.push_back({k, e});
    out["channels"][c.channel] = {
        {"model", describe(c.fit.model)},
        {"terms", c.fit.terms},
        {"cv_rmse", cv},
        {"colour_mix", c.mix},
        {"bin_rmse", c.fit.rmse},
        {"pixel_rmse", c.pixel_rmse},
        {"explained_variance", c.explained},
        {"effective_exponent", std::isfinite(c.effective_gamma) ? json(c.effective_gamma) : json(nullptr)},
        {"pixels", c.pixels},
        {"censored_pixels", c.censored_pixels},
        {"bins", c.bins}};
  }
  out["registration"] = {{"method", r.registration.method},
                         {"rotation_deg", r.rotation_degrees},
                         {"linear_scale", r.linear_scale},
                         {"ecc_correlation", r.registration.ecc_correlation},
                         {"working_size", {r.working_size.width, r.working_size.height}},
                         {"matrix", matrixValues(r.registration.homography)}};
  if (truth.comparison) out["comparison"] = curveComparisonJson(*truth.comparison);
  return out;
}

// The band of φ per channel (issue 19; band_report.hpp). Its covered range is report.json's "covered_range".
void addCurveBands(const PairCalibrationResult& result, json& extra) {
  if (result.bands.empty()) return;
  extra["inverse_crf_band"] = curveBandsJson(result.bands);
}

// The verdict per channel (channel_verdict.hpp): "verdict", "verdict_reasons" and the flat regions' brightness
// ratio it compared r with.
void addVerdict(const PairCalibrationResult& result, json& extra) {
  extra["verdict"] = json::object();
  extra["verdict_reasons"] = json::object();
  for (const auto& [name, verdict] : result.verdicts) {
    extra["verdict"][name] = toString(verdict.level);
    extra["verdict_reasons"][name] = verdict.reasons;
  }
  extra["brightness_ratio"] = result.brightness_ratio;
}

}  // namespace

void writeTileKernels(const std::filesystem::path& directory, const PairCalibrationResult& result) {
  if (result.tile_kernels.size() < 2) return;  // as kernelJson lists them
  for (const TileKernel& t : result.tile_kernels) writeKernelText(directory / tileKernelFileName(t.tile), t.kernel);
}

json curveComparisonJson(const CurveComparison& comparison) {
  json out = json::object();
  for (const auto& c : comparison.channels)
    out[c.channel] = {{"rmse", c.rmse},
                      {"max_error", c.max_error},
                      {"covered", {c.covered.first, c.covered.second}},
                      {"covered_source", c.covered_source},
                      {"rmse_covered", c.rmse_covered},
                      {"max_error_covered", c.max_error_covered},
                      {"scale_covered", c.scale_covered},
                      {"rmse_covered_aligned", c.rmse_covered_aligned}};
  out["worst_rmse"] = comparison.worst_rmse;
  out["worst_rmse_covered"] = comparison.worst_rmse_covered;
  out["worst_rmse_covered_aligned"] = comparison.worst_rmse_covered_aligned;
  return out;
}

CalibrationReport curveFitsReport(const std::map<std::string, CrfFitResult>& fits) {
  CalibrationReport report;
  report.command = "calibrate";
  for (const auto& [name, fit] : fits) {
    report.inverse_crf[name] = fit.inverse_crf;
    report.models[name] = fit.model;
    report.pixels_used[name] = fit.pixels.used;
  }
  return report;
}

CalibrationReport calibrationReport(const PairCalibrationResult& result, const CalibrationReportContext& context) {
  CalibrationReport report = curveFitsReport(result.fits);
  report.timings = result.timings;
  report.nominal_ratio = context.nominal_ratio;
  report.nominal_ratio_source = context.nominal_ratio_source;
  report.fitted_ratio = result.fits.at("G").ratio;
  report.covered_range = result.covered_range;
  report.warnings = result.warnings;
  report.effects = effectsJson(result.effects);
  for (const auto& name : result.effects.detected()) report.warnings.push_back("effect detected: " + name);
  addInputWarnings(result, context.pair, report.warnings);

  json& extra = report.extra;
  extra["input"] = inputJson(context.pair);
  // issue 20: channels fitted only where the sharp shot's subsampled chroma is flat, and the pixels that left out
  extra["input"]["chroma_model_channels"] = result.chroma_model_channels;
  for (const auto& name : result.chroma_model_channels)
    extra["input"]["chroma_excluded_pixels"][name] = result.fits.at(name).pixels.unmodelled;
  // the choice between the chroma model's fit and the pointwise one: the former's best scale against the latter
  for (const auto& [name, scale] : result.chroma_model_scale) extra["input"]["chroma_model_scale"][name] = scale;
  addExposureRatio(result, context, extra);
  extra["kernel"] = kernelJson(result);
  extra["registration"] = registrationJson(result.registration);
  if (result.effects.refit_tried) {  // the refit guard (effects.hpp): whose φ is reported and why
    extra["effects_refit"] = {{"adopted", result.effects.refit_adopted},
                              {"failed", result.effects.refit_failed},
                              {"rejected_reason", result.effects.refit_rejected_reason}};
    if (!result.effects.refit_failed) {  // a failed refit was never judged on the held-back pixels
      extra["effects_refit"]["heldout_error_base_fit"] = result.effects.heldout_error_base_fit;
      extra["effects_refit"]["heldout_error_refit"] = result.effects.heldout_error_refit;
      extra["effects_refit"]["heldout_error_base_fit_selected_model"] =
          result.effects.heldout_error_base_fit_selected_model;
    }
    if (!result.effects.refit_adopted)
      report.warnings.push_back(std::string("effects: the extended model's refit ") +
                                (result.effects.refit_failed ? "failed" : "was rejected") + " (" +
                                result.effects.refit_rejected_reason + "); the base fit's phi is reported");
  }
  addFitDetails(result, extra);
  addCurveBands(result, extra);
  addVerdict(result, extra);
  if (context.raw_truth) {
    if (context.raw_truth->compared_on_full_range_only)
      report.warnings.push_back("raw truth: the pair and the RAW truth cover disjoint intensity ranges; compared "
                                "over [0,1] only");
    extra["raw_truth"] = rawTruthJson(*context.raw_truth);
    for (const auto& w : context.raw_truth->result.warnings) report.warnings.push_back("raw truth: " + w);
  }
  return report;
}

}  // namespace crfcal::io
