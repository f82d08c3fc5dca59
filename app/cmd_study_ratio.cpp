// crfcal study ratio: EXIF vs fitted exposure ratios (brackets, phone pairs) and what a wrong r does to phi.
#include "study_common.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "command.hpp"
#include "crfcal/blur_model.hpp"
#include "crfcal/colour_mixing.hpp"
#include "crfcal/crf_fitter.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/exposure_fit.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/plot.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_model.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/simulation.hpp"
#include "progress.hpp"

namespace crfcal::app::study {
namespace fs = std::filesystem;
namespace {

// ================================================================================================== ratio
struct FrameInfo {
  fs::path path;
  io::ExifCsvRow exif;
};

std::vector<FrameInfo> bracketFrames(const fs::path& dir) {
  std::vector<FrameInfo> frames;
  for (const auto& row : io::readExifCsv(dir / "exif.csv")) frames.push_back({dir / row.file, row});
  std::sort(frames.begin(), frames.end(),
            [](const FrameInfo& a, const FrameInfo& b) { return a.exif.exposure_time < b.exif.exposure_time; });
  return frames;
}

ResponseCurve debevecCurve(const fs::path& npy) {
  const cv::Mat d = io::readNpy(npy);
  if (d.rows != 256 || d.cols < 2) throw Error("expected a (256, 3) response", npy.string());
  std::vector<double> phi(256);
  const double lo = d.at<double>(0, 1), hi = d.at<double>(255, 1);
  double run = 0;
  for (int i = 0; i < 256; ++i) {
    run = std::max(run, (d.at<double>(i, 1) - lo) / (hi - lo));
    phi[static_cast<size_t>(i)] = std::min(run, 1.0);
  }
  phi[0] = 0;
  phi[255] = 1;
  return ResponseCurve::fromSamples(phi);
}

// What the ratio study gathers from the measured sets before the synthetic sweep.
struct RatioMeasurements {
  std::vector<double> deviations_bracket, deviations_phone, heldout_nominal, heldout_fitted;
  ResponseModel nikon_curve = GammaModel{2.2};
};

// One bracket frame per step.
struct Bracket {
  std::vector<FrameInfo> frames;
  std::vector<cv::Mat> images;
  std::vector<double> times;
};

// Held-out: fit on the left half of the frames, predict each frame from the previous one on the right half — with the
// EXIF (nominal) exposures vs with the fitted ones (each with its own φ).
void bracketHeldOut(const std::string& set, const Bracket& bracket, const BracketFitOptions& bo, StudyTable& table,
                    RatioMeasurements& m) {
  const auto& images = bracket.images;
  const cv::Rect left(0, 0, images[0].cols / 2, images[0].rows), right(images[0].cols / 2, 0,
                                                                       images[0].cols - images[0].cols / 2, images[0].rows);
  BracketFitOptions nominal_options = bo, fitted_options = bo;
  nominal_options.fixed_exposures = true;
  nominal_options.region = fitted_options.region = left;
  const auto held_nominal = bracketPredictionRmse(images, fitBracket(images, bracket.times, nominal_options), right);
  const auto held_fitted = bracketPredictionRmse(images, fitBracket(images, bracket.times, fitted_options), right);
  m.heldout_nominal.push_back(255 * held_nominal.back());
  m.heldout_fitted.push_back(255 * held_fitted.back());
  table.rows.push_back({set, "held-out (right half; fit on the left half)", "all steps", "EXIF exposures",
                        "fitted exposures", "RMSE " + fmt(255 * held_nominal.back(), 2) + " -> " +
                                                fmt(255 * held_fitted.back(), 2) + " (8-bit)",
                        "frame j+1 predicted from frame j: psi(s_j phi(z_j))"});
  table.extra["heldout_prediction_rmse_8bit"][set] = {{"exif", held_nominal}, {"fitted", held_fitted}};
}

// The step ratios of the Debevec fixture curve, for comparison with the joint fit.
void debevecRatioRows(const std::string& set, const fs::path& npy, const Bracket& bracket, StudyTable& table) {
  const auto& frames = bracket.frames;
  const ResponseCurve curve = debevecCurve(npy);
  for (size_t j = 0; j + 1 < frames.size(); ++j) {
    const auto est = estimateExposureRatio(bracket.images[j], bracket.images[j + 1], curve);
    const double nominal = bracket.times[j + 1] / bracket.times[j];
    table.rows.push_back({set, frames[j].exif.file + " -> " + frames[j + 1].exif.file,
                          frames[j].exif.exposure_text + " -> " + frames[j + 1].exif.exposure_text,
                          fmt(nominal, 4), fmt(est.ratio, 4), pct(est.ratio / nominal - 1),
                          "median phi ratio, Debevec fixture phi (G)"});
  }
}

// One bracket: joint EMoR + exposure fit (span fixed to the nominal one), its held-out check and its step ratios.
void studyBracket(const std::string& set, double scale, const fs::path& dir, StudyTable& table, RatioMeasurements& m) {
  Bracket bracket;
  bracket.frames = bracketFrames(dir);
  const auto& frames = bracket.frames;
  for (const auto& f : frames) {
    bracket.images.push_back(greenUnit(f.path, scale));
    bracket.times.push_back(f.exif.exposure_time);
  }
  const auto& times = bracket.times;
  BracketFitOptions bo;
  const BracketFitResult fit = fitBracket(bracket.images, times, bo);
  bracketHeldOut(set, bracket, bo, table, m);
  if (set == "nikon_e995_window") m.nikon_curve = fit.model;
  for (size_t j = 0; j + 1 < frames.size(); ++j) {
    const double nominal = times[j + 1] / times[j];
    const double fitted = fit.step_ratio[j];
    m.deviations_bracket.push_back(std::abs(fitted / nominal - 1));
    table.rows.push_back({set, frames[j].exif.file + " -> " + frames[j + 1].exif.file,
                          frames[j].exif.exposure_text + " -> " + frames[j + 1].exif.exposure_text, fmt(nominal, 4),
                          fmt(fitted, 4), pct(fitted / nominal - 1), "joint EMoR(4)+exposures, span fixed"});
  }
  table.extra["bracket_fits"][set] = {{"step_ratio", fit.step_ratio}, {"rms_log_residual", fit.rms_residual},
                                      {"pairs", fit.pairs_used}, {"emor", fit.model.coefficients}};
  if (set == "canon5d2_frobisher" && fs::exists(dir / "colour_hdri_Debevec1997_crfs.npy"))
    debevecRatioRows(set, dir / "colour_hdri_Debevec1997_crfs.npy", bracket, table);
}

// Phone pairs: quantile matching with the EMoR mean curve (the phone's curve is unknown).
void studyPhonePairs(const fs::path& pairs, StudyTable& table, RatioMeasurements& m) {
  std::map<std::string, io::ExifCsvRow> exif;
  for (const auto& row : io::readExifCsv(pairs / "exif.csv")) exif[row.file] = row;
  const ResponseCurve g0(EmorModel{{0.0}});
  for (int n = 1; n <= 9; ++n) {
    const std::string id = std::to_string(n);
    const std::vector<std::pair<std::string, std::string>> combos{
        {"noisy_" + id + ".jpg", "blurred_" + id + ".jpg"},
        {"noisy_" + id + ".jpg", "g_truth_" + id + ".jpg"},
        {"g_truth_" + id + ".jpg", "blurred_" + id + ".jpg"}};
    for (const auto& [a, b] : combos) {
      if (!exif.count(a) || !exif.count(b) || !fs::exists(pairs / a) || !fs::exists(pairs / b)) continue;
      const auto& ea = exif[a];
      const auto& eb = exif[b];
      const double nominal = (eb.iso * eb.exposure_time) / (ea.iso * ea.exposure_time);
      ExposureRatioOptions ro;
      ro.registered = false;
      const auto est = estimateExposureRatio(greenUnit(pairs / a), greenUnit(pairs / b), g0, ro);
      m.deviations_phone.push_back(std::abs(std::log(est.ratio / nominal)));
      table.rows.push_back({"vivo_x6s", a + " -> " + b,
                            "ISO" + fmt(ea.iso, 0) + " " + ea.exposure_text + " -> ISO" + fmt(eb.iso, 0) + " " +
                                eb.exposure_text,
                            fmt(nominal, 4), fmt(est.ratio, 4), pct(est.ratio / nominal - 1),
                            "quantile matching, EMoR mean phi"});
    }
  }
}

// The effect of a wrong r on phi: per eps, the phi RMSE of every case with r fixed and with the Eq. 25 update.
struct WrongRatioSweep {
  std::vector<double> eps{-0.20, -0.10, -0.03, 0.0, 0.03, 0.10, 0.20};
  double true_r = 2.0;
  std::vector<std::vector<double>> rmse_fixed, rmse_eq25, r_eq25;
};

// Synthetic: simulatePair with a known curve and r, fitted with r = r_true (1 + eps) fixed or updated.
WrongRatioSweep runWrongRatioSweep(int images, const ResponseModel& nikon_curve, Progress& progress) {
  WrongRatioSweep sweep;
  const auto& eps = sweep.eps;
  const double true_r = sweep.true_r;
  const std::vector<std::pair<std::string, ResponseModel>> curves{{"gamma2.2", GammaModel{2.2}},
                                                                   {"nikon_e995_fit", nikon_curve}};
  sweep.rmse_fixed.resize(eps.size());
  sweep.rmse_eq25.resize(eps.size());
  sweep.r_eq25.resize(eps.size());
  int done = 0;
  const int total = static_cast<int>(eps.size() * curves.size()) * images;
  for (int im = 1; im <= images; ++im) {
    const cv::Mat image = io::readGrayUnit(io::samplesDirectory() / "levin09" / ("im" + std::to_string(im) + ".png"));
    const cv::Mat kernel = io::kernelFromSpec("levin:" + std::to_string(im));
    for (const auto& [cname, cmodel] : curves) {
      SimulationOptions so;
      so.ratio = true_r;
      so.noise_variance = 1e-4;
      so.seed = static_cast<std::uint64_t>(im);
      // keep r·Ĩ below 1 mostly: scale the latent irradiance to [0, 0.45]
      const SimulationResult pair = simulatePair(image * 0.45, cmodel, kernel, so);
      const auto truth = sampleInverse(cmodel, kCurveSamples);
      for (size_t e = 0; e < eps.size(); ++e) {
        for (int mode = 0; mode < 2; ++mode) {
          CrfFitOptions fo;
          fo.nominal_ratio = true_r * (1 + eps[e]);
          fo.fit_ratio = mode == 1;
          const CrfFitResult fit = fitInverseCrf(pair.sharp, pair.blurred, kernel, fo);
          const double err = curveRmse(fit.inverse_crf, truth);
          (mode ? sweep.rmse_eq25 : sweep.rmse_fixed)[e].push_back(err);
          if (mode) sweep.r_eq25[e].push_back(fit.ratio);
        }
        ++done;
        progress.update(double(done) / total, std::to_string(done) + "/" + std::to_string(total));
      }
    }
  }
  return sweep;
}

// One detail row per eps, and the two plotted curves.
void sweepRows(const WrongRatioSweep& sweep, StudyTable& table, io::PlotSeries& fixed_series,
               io::PlotSeries& eq25_series) {
  const auto& eps = sweep.eps;
  fixed_series.label = "r fixed at r(1+eps)";
  eq25_series.label = "Eq. 25 r update from r(1+eps)";
  fixed_series.color = io::seriesColor(0);
  eq25_series.color = io::seriesColor(1);
  for (size_t e = 0; e < eps.size(); ++e) {
    const double mf = meanOf(sweep.rmse_fixed[e]), m25 = meanOf(sweep.rmse_eq25[e]);
    table.rows.push_back({"synthetic", "eps " + pct(eps[e]),
                          "r_true 2 (" + std::to_string(sweep.rmse_fixed[e].size()) + " cases)",
                          fmt(sweep.true_r * (1 + eps[e]), 3), fmt(meanOf(sweep.r_eq25[e]), 4),
                          "phi RMSE fixed " + fmt(mf, 4) + " / Eq.25 " + fmt(m25, 4), "fitInverseCrf (default options)"});
    fixed_series.x.push_back(100 * eps[e]);
    fixed_series.y.push_back(mf);
    eq25_series.x.push_back(100 * eps[e]);
    eq25_series.y.push_back(m25);
  }
}

void ratioSummary(const RatioMeasurements& m, const WrongRatioSweep& sweep, StudyTable& table) {
  const auto& rmse_fixed = sweep.rmse_fixed;
  const double at0 = meanOf(rmse_fixed[3]);
  const double at3 = 0.5 * (meanOf(rmse_fixed[2]) + meanOf(rmse_fixed[4]));
  const double at10 = 0.5 * (meanOf(rmse_fixed[1]) + meanOf(rmse_fixed[5]));
  const double at20 = 0.5 * (meanOf(rmse_fixed[0]) + meanOf(rmse_fixed[6]));
  double eq25_worst = 0;
  for (const auto& v : sweep.rmse_eq25) eq25_worst = std::max(eq25_worst, meanOf(v));
  SummaryRow s;
  s.assumption = "exact exposure ratio r (Eq. 4) from EXIF (footnote 4)";
  s.misfit = "brackets: mean |fitted/nominal - 1| = " +
             (m.deviations_bracket.empty() ? std::string("n/a") : pct(meanOf(m.deviations_bracket))) +
             " per step; phone pairs: mean |log(fitted/nominal)| = " +
             (m.deviations_phone.empty() ? std::string("n/a") : fmt(meanOf(m.deviations_phone), 2));
  s.cause = "nominal shutter speeds are rounded (1/60 for 1/64, 1/125 for 1/128: 1-EV steps are exact powers of 2), "
            "nominal ISO, and phones re-meter / tone-map each shot";
  s.extended = "r fitted from the images (joint EMoR + per-frame exposure, span fixed) or Eq. 25 r update in the fitter";
  std::string held;
  for (size_t i = 0; i < m.heldout_nominal.size(); ++i)
    held += (i ? ", " : "") + fmt(m.heldout_nominal[i], 2) + " -> " + fmt(m.heldout_fitted[i], 2);
  s.gain = "held-out prediction RMSE of each bracket frame from the previous one (8-bit; EXIF -> fitted exposures): " +
           held + "; phi RMSE with r fixed wrong by 0/3/10/20%: " + fmt(at0, 4) + "/" + fmt(at3, 4) + "/" +
           fmt(at10, 4) + "/" + fmt(at20, 4) + "; with Eq. 25 update: worst " + fmt(eq25_worst, 4);
  table.summary.push_back(s);
  table.extra["sweep"] = {{"eps", sweep.eps}, {"true_ratio", sweep.true_r}};
  for (size_t e = 0; e < sweep.eps.size(); ++e) {
    table.extra["sweep"]["rmse_fixed"].push_back(rmse_fixed[e]);
    table.extra["sweep"]["rmse_eq25"].push_back(sweep.rmse_eq25[e]);
    table.extra["sweep"]["ratio_eq25"].push_back(sweep.r_eq25[e]);
  }
}

}  // namespace

int runRatio(const StudyArgs& args) {
  const fs::path root = requireData(args, "brackets");
  io::OutputDirectory out(args.output, {"study ratio", {root}, args.force});  // refused or unwritable: fails now
  Progress progress(args.quiet);
  StudyTable table;
  table.study = "ratio";
  table.header = {"set", "pair", "exif", "nominal_ratio", "fitted_ratio", "deviation", "method"};
  RatioMeasurements measured;
  for (const auto& [set, scale] : std::vector<std::pair<std::string, double>>{
           {"nikon_e995_window", 0.25}, {"canon_s3is_stlouisarch", 0.125}, {"canon5d2_frobisher", 1.0}}) {
    const fs::path dir = root / "brackets" / set;
    if (!fs::is_directory(dir)) continue;
    progress.stage("bracket " + set);
    studyBracket(set, scale, dir, table, measured);
    progress.done();
  }
  const fs::path pairs = root / "pairs" / "vivo_x6s";
  if (fs::is_directory(pairs)) {
    progress.stage("vivo pairs");
    studyPhonePairs(pairs, table, measured);
    progress.done();
  }
  progress.stage("wrong-r sweep");
  const WrongRatioSweep sweep = runWrongRatioSweep(args.images, measured.nikon_curve, progress);
  progress.done();
  io::PlotSeries fixed_series, eq25_series;
  sweepRows(sweep, table, fixed_series, eq25_series);
  ratioSummary(measured, sweep, table);
  emit(table, out);
  io::PlotOptions plot;
  plot.title = "phi RMSE vs error of the exposure ratio r (synthetic, r = 2)";
  plot.x_label = "eps = r_used / r_true - 1 (%)";
  plot.y_label = "phi RMSE";
  plot.y_min = 0;
  io::writePlot(out.file("ratio_sweep.png"), {fixed_series, eq25_series}, plot);
  out.commit();
  std::printf("wrote %s/{table.csv, details.csv, table.json, ratio_sweep.png}\n", args.output.c_str());
  return kExitOk;
}

}  // namespace crfcal::app::study
