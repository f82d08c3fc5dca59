// crfcal study channels: one pointwise curve per channel vs a 3x3 mix before the curves (Middlebury RAW -> JPEG, held out).
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

// One Middlebury camera, cross-validated over its two scenes.
struct CameraResult {
  std::vector<double> train, heldout;  // per kind
  std::array<double, 4> wb{};          // colour patches of the test scene: pw, pw+greyWB, mixclip, mixclip+greyWB
  int n1 = 0, n2 = 0;
  nlohmann::json mix;
};

std::vector<ColourSample> greyOrColourPatches(const std::vector<ColourSample>& v, bool grey) {
  std::vector<ColourSample> out;
  for (const auto& x : v)
    if ((x.patch >= 18) == grey) out.push_back(x);
  return out;
}

// White balance per scene: re-fit only diag gains on the test scene's 6 grey patches, test on its 18 colour ones.
void whiteBalanceRmse(const std::vector<ColourFitResult>& f1, const std::vector<ColourFitResult>& f2,
                      const std::vector<ColourSample>& s1, const std::vector<ColourSample>& s2, CameraResult& r) {
  const auto g1 = greyOrColourPatches(s1, true), c1 = greyOrColourPatches(s1, false),
             g2 = greyOrColourPatches(s2, true), c2 = greyOrColourPatches(s2, false);
  for (int which = 0; which < 2; ++which) {
    const size_t k = which == 0 ? 0 : 2;
    const double plain = std::sqrt((c2.size() * std::pow(colourRmse(f1[k].model, c2), 2) +
                                    c1.size() * std::pow(colourRmse(f2[k].model, c1), 2)) /
                                   double(c1.size() + c2.size()));
    double adapted = plain;
    if (g1.size() >= 2 && g2.size() >= 2) {
      const double e12 = colourRmse(adaptWhiteBalance(f1[k].model, g2), c2);
      const double e21 = colourRmse(adaptWhiteBalance(f2[k].model, g1), c1);
      adapted = std::sqrt((c2.size() * e12 * e12 + c1.size() * e21 * e21) / double(c1.size() + c2.size()));
    }
    r.wb[static_cast<size_t>(2 * which)] = plain;
    r.wb[static_cast<size_t>(2 * which + 1)] = adapted;
  }
}

CameraResult crossValidateCamera(const io::MiddleburyCamera& cam, size_t nk, const ColourFitOptions& fit_options) {
  std::vector<ColourSample> s1, s2;
  for (const auto& s : cam.samples) (s.group == 1 ? s1 : s2).push_back(s);
  CameraResult r;
  r.n1 = static_cast<int>(s1.size());
  r.n2 = static_cast<int>(s2.size());
  r.train.assign(nk, 0);
  r.heldout.assign(nk, 0);
  const auto f1 = fitColourModels(s1, fit_options);  // train i1, test i2
  const auto f2 = fitColourModels(s2, fit_options);  // train i2, test i1
  for (size_t k = 0; k < nk; ++k) {
    const double e12 = colourRmse(f1[k].model, s2), e21 = colourRmse(f2[k].model, s1);
    r.heldout[k] = std::sqrt((r.n2 * e12 * e12 + r.n1 * e21 * e21) / (r.n1 + r.n2));
    r.train[k] = std::sqrt((r.n1 * f1[k].train_rmse * f1[k].train_rmse + r.n2 * f2[k].train_rmse * f2[k].train_rmse) /
                           (r.n1 + r.n2));
  }
  whiteBalanceRmse(f1, f2, s1, s2, r);
  const auto& m = f1[2].model.mix;  // mix_clip, trained on i1
  r.mix = nlohmann::json::array();
  for (int a = 0; a < 3; ++a) r.mix.push_back({m(a, 0), m(a, 1), m(a, 2)});
  return r;
}

// Means over the cameras (8-bit units) and how many cameras each extension helps.
struct ChannelsMeans {
  std::array<double, 4> wb{};
  std::vector<double> held, train;
  int mix_better = 0, best_better = 0, wb_better = 0;
};

const std::array<std::string, 4> kWhiteBalanceColumns{"colour_pointwise", "colour_pointwise+greyWB",
                                                      "colour_mix3x3+clip", "colour_mix3x3+clip+greyWB"};

// One detail row per camera and the MEAN row; the held-out RMSE per camera into `series`.
ChannelsMeans channelsDetails(const std::vector<io::MiddleburyCamera>& cameras, const std::vector<CameraResult>& results,
                              const std::vector<ColourModelKind>& kinds, StudyTable& table,
                              std::vector<io::PlotSeries>& series) {
  const size_t nk = kinds.size();
  table.header = {"camera", "n_i1", "n_i2"};
  for (auto k : kinds) table.header.push_back(std::string("heldout_") + toString(k));
  for (auto k : kinds) table.header.push_back(std::string("train_") + toString(k));
  for (const auto& n : kWhiteBalanceColumns) table.header.push_back(n);
  ChannelsMeans mean;
  mean.held.assign(nk, 0);
  mean.train.assign(nk, 0);
  series.assign(nk, io::PlotSeries{});
  for (size_t k = 0; k < nk; ++k) {
    series[k].label = toString(kinds[k]);
    series[k].color = io::seriesColor(static_cast<int>(k));
  }
  for (size_t i = 0; i < cameras.size(); ++i) {
    const auto& r = results[i];
    std::vector<std::string> row{cameras[i].name, std::to_string(r.n1), std::to_string(r.n2)};
    for (size_t k = 0; k < nk; ++k) {
      row.push_back(fmt(255 * r.heldout[k], 2));
      mean.held[k] += 255 * r.heldout[k] / double(cameras.size());
      series[k].x.push_back(double(i + 1));
      series[k].y.push_back(255 * r.heldout[k]);
    }
    for (size_t k = 0; k < nk; ++k) {
      row.push_back(fmt(255 * r.train[k], 2));
      mean.train[k] += 255 * r.train[k] / double(cameras.size());
    }
    for (size_t w = 0; w < 4; ++w) {
      row.push_back(fmt(255 * r.wb[w], 2));
      mean.wb[w] += 255 * r.wb[w] / double(cameras.size());
    }
    if (r.heldout[2] < r.heldout[0]) ++mean.mix_better;
    if (r.wb[3] < r.wb[2]) ++mean.wb_better;
    if (*std::min_element(r.heldout.begin() + 1, r.heldout.end()) < r.heldout[0]) ++mean.best_better;
    table.rows.push_back(row);
    table.extra["mix_clip_matrix_fit_on_i1"][cameras[i].name] = r.mix;
  }
  std::vector<std::string> mean_row{"MEAN", "", ""};
  for (size_t k = 0; k < nk; ++k) mean_row.push_back(fmt(mean.held[k], 2));
  for (size_t k = 0; k < nk; ++k) mean_row.push_back(fmt(mean.train[k], 2));
  for (size_t w = 0; w < 4; ++w) mean_row.push_back(fmt(mean.wb[w], 2));
  table.rows.push_back(mean_row);
  return mean;
}

void channelsSummary(const ChannelsMeans& mean, size_t cameras, const std::vector<ColourModelKind>& kinds,
                     StudyTable& table) {
  const auto& mean_held = mean.held;
  const auto& mean_train = mean.train;
  const auto& mean_wb = mean.wb;
  const size_t best = static_cast<size_t>(std::min_element(mean_held.begin(), mean_held.end()) - mean_held.begin());
  SummaryRow s;
  s.assumption = "one pointwise curve per channel: jpeg_c = f_c(s_c * raw_c) (seed Sec. 3, per-channel psi)";
  s.misfit = "pointwise model: held-out RMSE " + fmt(mean_held[0], 2) + " (8-bit JPEG units, mean of " +
             std::to_string(cameras) + " Middlebury cameras, fit on one scene, tested on the other)";
  s.cause = "the camera mixes channels before its tone curve (white balance + 3x3 colour-correction matrix) and "
            "clips the mixed values to the output gamut";
  s.extended = std::string("jpeg_c = f_c(clip01((M raw)_c)) [mix3x3+clip]; also mix3x3 without clip ") + fmt(mean_held[1], 2) +
               ", +post 3x3 after the curve " + fmt(mean_held[3], 2);
  s.gain = "held-out RMSE " + fmt(mean_held[0], 2) + " -> " + fmt(mean_held[2], 2) + " (" +
           pct(mean_held[2] / mean_held[0] - 1) + "), better on " + std::to_string(mean.mix_better) + "/" +
           std::to_string(cameras) + " cameras; best model " + toString(kinds[best]) + " " +
           fmt(mean_held[best], 2);
  table.summary.push_back(s);
  SummaryRow s2;
  s2.assumption = "one fixed curve set per camera, independent of the scene (the held-out gap: train " +
                  fmt(mean_train[2], 2) + " vs held-out " + fmt(mean_held[2], 2) + " for mix3x3+clip)";
  s2.misfit = "18 colour patches of the other scene: pointwise " + fmt(mean_wb[0], 2) + ", mix3x3+clip " +
              fmt(mean_wb[2], 2);
  s2.cause = "hypothesis: the two scenes are lit differently and the rendering white-balances each shot "
             "(per-scene diagonal gains before the colour matrix)";
  s2.extended = "same model, only the 3 white-balance gains re-fitted on the 6 grey patches of the test scene "
                "(as a camera's grey-world/grey-card WB does), tested on its 18 colour patches";
  s2.gain = "pointwise " + fmt(mean_wb[0], 2) + " -> " + fmt(mean_wb[1], 2) + "; mix3x3+clip " + fmt(mean_wb[2], 2) +
            " -> " + fmt(mean_wb[3], 2) + " (" + pct(mean_wb[3] / mean_wb[2] - 1) + "), better on " +
            std::to_string(mean.wb_better) + "/" + std::to_string(cameras) +
            " cameras: per-scene WB explains part of the gap only for some cameras (not confirmed overall)";
  table.summary.push_back(s2);
  table.extra["mean_colour_patch_rmse_8bit"] = {{"names", kWhiteBalanceColumns}, {"values", mean_wb}};
  table.extra["mean_heldout_rmse_8bit"] = mean_held;
  table.extra["mean_train_rmse_8bit"] = mean_train;
  table.extra["models"] = {"pointwise", "mix3x3", "mix3x3+clip", "mix3x3+clip+post"};
}

// Issue 20: the chroma row. The bundled demo pair (semi-real, OpenCV JPEG 4:2:0, one true curve for all channels):
// R, B and G calibrated with the pointwise model and with the chroma model; the error against the known truth,
// which no fit sees, is the held-out measure.
void chromaSummary(StudyTable& table, Progress& progress) {
  progress.stage("chroma: demo pair, pointwise vs chroma model");
  const fs::path dir = io::samplesDirectory() / "pairs";
  const io::LoadedPair pair = io::loadPair(dir / "sharp.jpg", dir / "blurred.jpg");
  std::ifstream in(dir / "truth.json");
  const std::vector<double> truth = nlohmann::json::parse(in).at("inverse_crf").get<std::vector<double>>();
  std::map<std::string, double> rmse[2];
  int excluded_b = 0;
  for (int modelled = 0; modelled < 2; ++modelled) {
    PairCalibrationOptions options;
    options.fit.nominal_ratio = pair.exif_ratio ? pair.exif_ratio->ratio() : 1.0;
    options.effects.enabled = false;
    if (modelled) options.sharp_chroma = {pair.sharp.chroma_block_h, pair.sharp.chroma_block_v};
    const PairCalibrationResult r = calibratePair(pair.sharp.image, pair.blurred.image, options);
    for (const auto& [name, fit] : r.fits) rmse[modelled][name] = curveRmse(fit.inverse_crf, truth);
    if (modelled && r.fits.count("B")) excluded_b = r.fits.at("B").pixels.unmodelled;
  }
  progress.done();
  SummaryRow s;
  s.assumption = "the decoded sharp shot is psi(E) per pixel and channel (Eq. 4 pointwise, per-channel phi)";
  s.misfit = "demo pair (JPEG " + pair.sharp.chroma_subsampling + "), phi RMSE vs the known truth R/G/B " +
             fmt(rmse[0]["R"], 4) + " / " + fmt(rmse[0]["G"], 4) + " / " + fmt(rmse[0]["B"], 4);
  s.cause = "JPEG chroma subsampling of the sharp shot: R = Y + 1.402 Cr, B = Y + 1.772 Cb with Cb, Cr averaged over "
            "2x2 blocks after the tone curve; the blurred shot's chroma is smooth (measured: only the sharp shot's "
            "4:2:0 matters)";
  s.extended = "R and B fitted only where the kernel-weighted bound of the lost chroma detail (from the stored "
               "block averages) is <= 4 levels (" + std::to_string(excluded_b) + " B pixels excluded), kept per channel "
               "where that fit lies above the pointwise one (the sign of the bias it removes); G unchanged";
  s.gain = "phi RMSE vs truth (not used by the fit) R " + fmt(rmse[0]["R"], 4) + " -> " + fmt(rmse[1]["R"], 4) +
           ", B " + fmt(rmse[0]["B"], 4) + " -> " + fmt(rmse[1]["B"], 4) + ", G " + fmt(rmse[0]["G"], 4) + " -> " +
           fmt(rmse[1]["G"], 4);
  table.summary.push_back(s);
  table.extra["chroma_demo_phi_rmse"] = {{"pointwise", rmse[0]}, {"chroma_model", rmse[1]}};
}

}  // namespace

int runChannels(const StudyArgs& args) {
  const fs::path root = requireData(args, "middlebury");
  io::OutputDirectory out(args.output, {"study channels", {root}, args.force});  // refused or unwritable: fails now
  Progress progress(args.quiet);
  progress.stage("read middlebury charts");
  const auto cameras = io::readMiddleburyPatches(root / "middlebury");
  progress.done(std::to_string(cameras.size()) + " cameras");
  const auto kinds = allColourModelKinds();
  ColourFitOptions fit_options;
  fit_options.knots = args.knots;
  std::vector<CameraResult> results(cameras.size());
  progress.stage("fit 4 models x 2 folds per camera");
  cv::parallel_for_(cv::Range(0, static_cast<int>(cameras.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i)
      results[static_cast<size_t>(i)] = crossValidateCamera(cameras[static_cast<size_t>(i)], kinds.size(), fit_options);
  });
  progress.done();

  StudyTable table;
  table.study = "channels";
  std::vector<io::PlotSeries> series;
  const ChannelsMeans mean = channelsDetails(cameras, results, kinds, table, series);
  channelsSummary(mean, cameras.size(), kinds, table);
  chromaSummary(table, progress);

  emit(table, out);
  io::PlotOptions plot;
  plot.title = "RAW->JPEG held-out RMSE per camera (cross-validated over the 2 scenes)";
  plot.x_label = "camera (row of details.csv)";
  plot.y_label = "held-out RMSE (8-bit)";
  plot.y_min = 0;
  io::writePlot(out.file("heldout_rmse.png"), series, plot);
  out.commit();
  std::printf("wrote %s/{table.csv, details.csv, table.json, heldout_rmse.png}\n", args.output.c_str());
  return kExitOk;
}

}  // namespace crfcal::app::study
