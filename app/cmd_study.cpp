// crfcal study channels|noise|ratio: what the seed's simulation gets wrong on measured data (issue 6).
// Each study prints one table — simulation assumption → measured misfit → named cause → extended model → measured
// gain (held-out) — plus a detail table, and writes table.csv, details.csv, table.json and PNG plot(s) atomically.
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

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct StudyArgs {
  std::string data;
  std::string output;
  bool quiet = false;
  bool force = false;  // write into an output directory holding other files (never deletes them)
  int knots = 12;      // channels
  int cases = 16;      // noise benchmark cases
  int images = 2;      // ratio sweep images
};

std::string fmt(double v, int precision = 3) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*f", precision, v);
  return buf;
}
std::string pct(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%+.1f%%", 100 * v);
  return buf;
}

struct SummaryRow {
  std::string assumption, misfit, cause, extended, gain;
};

struct StudyTable {
  std::string study;
  std::vector<SummaryRow> summary;
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  nlohmann::json extra = nlohmann::json::object();
};

std::string csvEscape(const std::string& s) {
  if (s.find_first_of(",\"\n") == std::string::npos) return s;
  std::string out = "\"";
  for (char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

void printTable(const std::vector<std::string>& header, const std::vector<std::vector<std::string>>& rows) {
  std::vector<size_t> width(header.size());
  for (size_t i = 0; i < header.size(); ++i) width[i] = header[i].size();
  for (const auto& r : rows)
    for (size_t i = 0; i < r.size() && i < width.size(); ++i) width[i] = std::max(width[i], r[i].size());
  auto line = [&](const std::vector<std::string>& r) {
    for (size_t i = 0; i < header.size(); ++i)
      std::printf("%-*s%s", static_cast<int>(width[i]), i < r.size() ? r[i].c_str() : "", i + 1 < header.size() ? "  " : "\n");
  };
  line(header);
  for (const auto& r : rows) line(r);
}

void emit(const StudyTable& table, io::OutputDirectory& out) {
  std::printf("\n== study %s: assumption -> misfit -> cause -> extended model -> gain\n", table.study.c_str());
  for (const auto& s : table.summary) {
    std::printf("  assumption: %s\n  misfit:     %s\n  cause:      %s\n  extended:   %s\n  gain:       %s\n\n",
                s.assumption.c_str(), s.misfit.c_str(), s.cause.c_str(), s.extended.c_str(), s.gain.c_str());
  }
  std::printf("-- details\n");
  printTable(table.header, table.rows);
  std::ostringstream csv;
  csv << "assumption,measured_misfit,named_cause,extended_model,measured_gain\n";
  for (const auto& s : table.summary)
    csv << csvEscape(s.assumption) << ',' << csvEscape(s.misfit) << ',' << csvEscape(s.cause) << ','
        << csvEscape(s.extended) << ',' << csvEscape(s.gain) << '\n';
  io::writeTextFile(out.file("table.csv"), csv.str());
  std::ostringstream det;
  for (size_t i = 0; i < table.header.size(); ++i) det << (i ? "," : "") << csvEscape(table.header[i]);
  det << '\n';
  for (const auto& r : table.rows) {
    for (size_t i = 0; i < r.size(); ++i) det << (i ? "," : "") << csvEscape(r[i]);
    det << '\n';
  }
  io::writeTextFile(out.file("details.csv"), det.str());
  nlohmann::json j;
  j["study"] = table.study;
  j["summary"] = nlohmann::json::array();
  for (const auto& s : table.summary)
    j["summary"].push_back({{"assumption", s.assumption}, {"measured_misfit", s.misfit}, {"named_cause", s.cause},
                            {"extended_model", s.extended}, {"measured_gain", s.gain}});
  j["details"] = {{"header", table.header}, {"rows", table.rows}};
  j["extra"] = table.extra;
  io::writeTextFile(out.file("table.json"), j.dump(2) + "\n");
}

fs::path requireData(const StudyArgs& args, const std::string& sub) {
  const fs::path root = io::defaultSharedData(args.data);
  if (!fs::is_directory(root))
    throw Error("shared data directory not found (give --data DIR or set CRFCAL_SHARED_DATA)", root.string());
  const fs::path dir = root / sub;
  if (!fs::is_directory(dir)) throw Error("dataset folder missing", dir.string());
  return root;
}

cv::Mat greenUnit(const fs::path& path, double scale = 1.0) {
  const cv::Mat image = io::readColorImage(path);
  cv::Mat g;
  cv::extractChannel(image, g, 1);
  if (scale != 1.0) cv::resize(g, g, cv::Size(), scale, scale, cv::INTER_AREA);
  cv::Mat out;
  g.convertTo(out, CV_64F, 1.0 / 255);
  return out;
}

// ================================================================================================== channels
double meanOf(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? 0.0 : s / double(v.size());
}

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
               "block averages) is <= 4 levels (" + std::to_string(excluded_b) + " B pixels excluded); G unchanged";
  s.gain = "phi RMSE vs truth (not used by the fit) R " + fmt(rmse[0]["R"], 4) + " -> " + fmt(rmse[1]["R"], 4) +
           ", B " + fmt(rmse[0]["B"], 4) + " -> " + fmt(rmse[1]["B"], 4) + ", G " + fmt(rmse[0]["G"], 4) + " -> " +
           fmt(rmse[1]["G"], 4);
  table.summary.push_back(s);
  table.extra["chroma_demo_phi_rmse"] = {{"pointwise", rmse[0]}, {"chroma_model", rmse[1]}};
}

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

// ================================================================================================== noise
// darktable profiles pushed through a camera curve: one detail row and one plotted sigma_I(v) per profile. Returns the
// benchmark's noise (the 5D Mark II at ISO 3200, or a fallback close to a high-ISO profile).
PoissonGaussianNoise studyNoiseProfiles(const fs::path& root, const ResponseCurve& gamma22, StudyTable& table,
                                        std::vector<io::PlotSeries>& profile_series) {
  const auto profiles = io::readNoiseProfiles(root / "noise_profiles" / "noiseprofiles.json");
  PoissonGaussianNoise bench_noise{2.5e-4, 2e-6};  // fallback ≈ a high-ISO profile
  int colour = 0;
  for (const auto& [model, iso] : std::vector<std::pair<std::string, double>>{
           {"EOS 5D Mark II", 100}, {"EOS 5D Mark II", 3200}, {"EOS 5D Mark II", 12800}, {"PowerShot G9", 1600},
           {"D200", 1600}}) {
    const auto p = io::findNoiseProfile(profiles, model, iso);
    if (!p) continue;
    // darktable's fits can give b < 0 (an artefact of fitting near the black level): taken as 0 (shot noise only).
    const PoissonGaussianNoise n{p->a[1], std::max(p->b[1], 0.0)};
    if (model == "EOS 5D Mark II" && p->iso == 3200) bench_noise = n;
    const double s10 = intensityNoiseSigma(gamma22, n, 0.1), s50 = intensityNoiseSigma(gamma22, n, 0.5),
                 s90 = intensityNoiseSigma(gamma22, n, 0.9);
    table.rows.push_back({p->name, "G: a=" + fmt(n.a * 1e6, 2) + "e-6 b=" + fmt(p->b[1] * 1e6, 3) + "e-6" +
                                       (p->b[1] < 0 ? " (b<0 taken as 0)" : ""),
                          "sigma_I(0.1)=" + fmt(255 * s10, 2), "sigma_I(0.5)=" + fmt(255 * s50, 2),
                          "sigma_I(0.9)=" + fmt(255 * s90, 2), "dark/bright=" + fmt(s10 / s90, 2)});
    io::PlotSeries s;
    s.label = p->name + " (through gamma 2.2)";
    s.color = io::seriesColor(colour++);
    for (int i = 1; i < 100; ++i) {
      s.x.push_back(i / 100.0);
      s.y.push_back(255 * intensityNoiseSigma(gamma22, n, i / 100.0));
    }
    profile_series.push_back(s);
  }
  return bench_noise;
}

// The real JPEGs whose noise is measured: the vivo pairs' short exposures and two Nikon bracket frames.
std::vector<std::pair<std::string, fs::path>> realNoiseImages(const fs::path& root) {
  std::vector<std::pair<std::string, fs::path>> real;
  for (int i = 1; i <= 9; ++i) {
    const fs::path p = root / "pairs" / "vivo_x6s" / ("noisy_" + std::to_string(i) + ".jpg");
    if (fs::exists(p)) real.emplace_back("vivo noisy_" + std::to_string(i) + " (ISO 3200)", p);
  }
  for (int i = 1; i <= 9; ++i) {
    const fs::path p = root / "pairs" / "vivo_x6s" / ("g_truth_" + std::to_string(i) + ".jpg");
    if (fs::exists(p)) real.emplace_back("vivo g_truth_" + std::to_string(i) + " (ISO 3180)", p);
  }
  for (const auto* f : {"HDRI_Sample_Scene_Window_-_06.jpg", "HDRI_Sample_Scene_Window_-_08.jpg"}) {
    const fs::path p = root / "brackets" / "nikon_e995_window" / f;
    if (fs::exists(p)) real.emplace_back(std::string("Nikon E995 ") + f + " (ISO 100)", p);
  }
  return real;
}

// Log-sigma misfit of each noise model, one entry per measured image.
struct NoiseMisfits {
  std::vector<double> constant, intensity_affine, through_curve;
};

// The measured bins (markers) and the through-curve fit (line) of one image.
void addMeasuredSeries(const std::string& name, const std::vector<NoiseLevelBin>& bins, const ResponseCurve& g0,
                       const PoissonGaussianNoise& through, std::vector<io::PlotSeries>& measured_series) {
  io::PlotSeries s;
  s.label = name;
  s.markers = true;
  s.color = io::seriesColor(static_cast<int>(measured_series.size()));
  for (const auto& b : bins) {
    s.x.push_back(b.intensity);
    s.y.push_back(255 * b.sigma);
  }
  measured_series.push_back(s);
  io::PlotSeries c = s;
  c.markers = false;
  c.label = "";
  c.x.clear();
  c.y.clear();
  for (int i = 2; i < 99; ++i) {
    c.x.push_back(i / 100.0);
    c.y.push_back(255 * intensityNoiseSigma(g0, through, i / 100.0));
  }
  measured_series.push_back(c);
}

// Measured: sigma vs intensity of one real JPEG against the three noise models. Skips images with < 3 bins.
void measureImageNoise(const std::string& name, const fs::path& path, const ResponseCurve& g0, StudyTable& table,
                       NoiseMisfits& misfits, std::vector<io::PlotSeries>& measured_series) {
  const cv::Mat g = greenUnit(path);
  NoiseLevelOptions no;
  no.bins = 10;
  no.min_samples = 150;
  const auto bins = measureNoiseLevels(g, no);
  if (bins.size() < 3) return;
  // (a) homoscedastic: the best constant in the log domain
  double logsum = 0;
  for (const auto& b : bins) logsum += std::log(std::max(b.sigma, 1e-9));
  const double sconst = std::exp(logsum / double(bins.size()));
  std::vector<double> model_const(bins.size(), sconst), model_lin, model_curve;
  // (b) signal-dependent in the intensity domain (no curve)
  std::vector<double> xs, ss;
  for (const auto& b : bins) {
    xs.push_back(b.intensity);
    ss.push_back(b.sigma);
  }
  const PoissonGaussianNoise lin = fitPoissonGaussian(xs, ss);
  // (c) signal-dependent in irradiance, pushed through the curve (EMoR mean curve: the camera's is unknown)
  const PoissonGaussianNoise through = fitPoissonGaussianThroughCurve(bins, g0);
  for (const auto& b : bins) {
    model_lin.push_back(std::sqrt(lin.variance(b.intensity)));
    model_curve.push_back(intensityNoiseSigma(g0, through, b.intensity));
  }
  const double m1 = logSigmaMisfit(bins, model_const), m2 = logSigmaMisfit(bins, model_lin),
               m3 = logSigmaMisfit(bins, model_curve);
  misfits.constant.push_back(m1);
  misfits.intensity_affine.push_back(m2);
  misfits.through_curve.push_back(m3);
  std::ostringstream shape;
  shape << "sigma(8-bit) at v=";
  for (size_t i = 0; i < bins.size(); i += std::max<size_t>(1, bins.size() / 4))
    shape << fmt(bins[i].intensity, 2) << ":" << fmt(255 * bins[i].sigma, 2) << " ";
  table.rows.push_back({name, shape.str(), "log-misfit const=" + fmt(m1, 3), "a*v+b (intensity)=" + fmt(m2, 3),
                        "psi'(phi)*sqrt(a*phi+b)=" + fmt(m3, 3),
                        "fitted a=" + fmt(through.a * 1e4, 3) + "e-4 b=" + fmt(through.b * 1e6, 3) + "e-6"});
  addMeasuredSeries(name, bins, g0, through, measured_series);
}

// One case of the synthetic benchmark with signal-dependent noise in the irradiance domain.
struct NoiseCase {
  int image, kernel;
  std::string curve;
  double noise_scale;
};

std::vector<NoiseCase> noiseCases(int count) {
  std::vector<NoiseCase> cases;
  for (double scale : {8.0, 32.0})
    for (const char* curve : {"gamma:2.2", "emor:0"})
      for (int image : {1, 2})
        for (int kernel : {1, 4}) cases.push_back({image, kernel, curve, scale});
  if (static_cast<int>(cases.size()) > count) cases.resize(static_cast<size_t>(count));
  return cases;
}

const std::vector<std::string> kNoiseVariants{"crfcal default (no noise handling)",
                                              "homoscedastic sigma (debias, one sigma estimated: the seed's model)",
                                              "signal-dependent sigma(v) (debias, Poisson-Gaussian through the curve)",
                                              "denoise"};

// The phi RMSE of each variant of kNoiseVariants on one case, appended to err[variant].
void runNoiseCase(const NoiseCase& c, const PoissonGaussianNoise& bench_noise, std::uint64_t seed,
                  std::vector<std::vector<double>>& err) {
  const ResponseModel model = parseResponseSpec(c.curve);
  const ResponseCurve curve(model);
  const cv::Mat image = io::readGrayUnit(io::samplesDirectory() / "levin09" / ("im" + std::to_string(c.image) + ".png"));
  const cv::Mat kernel = io::kernelFromSpec("levin:" + std::to_string(c.kernel));
  RealisticSimulationOptions so;
  so.sharp_noise = {bench_noise.a * c.noise_scale, bench_noise.b * c.noise_scale * c.noise_scale};
  so.blurred_noise = {bench_noise.a / 32, bench_noise.b / 32};  // the long, low-ISO exposure
  so.seed = seed;
  const SimulationResult pair = simulatePairPoissonGaussian(image, model, kernel, so);
  const auto truth = sampleInverse(model);
  err.resize(kNoiseVariants.size());
  CrfFitOptions base;
  const CrfFitResult def = fitInverseCrf(pair.sharp, pair.blurred, kernel, base);
  err[0].push_back(curveRmse(def.inverse_crf, truth));
  CrfFitOptions homo = base;
  homo.experimental.noise = NoiseHandling::debias;
  homo.noise_sigma = -1;  // estimated from I (one σ)
  err[1].push_back(curveRmse(fitInverseCrf(pair.sharp, pair.blurred, kernel, homo).inverse_crf, truth));
  // σ(v) from the sensor model pushed through the first-pass fitted curve, on the fitter's level grid.
  const ResponseCurve fitted = ResponseCurve::fromSamples(def.inverse_crf);
  const int levels = std::max(naturalLevels(pair.sharp), naturalLevels(pair.blurred));  // the fitter's grid
  CrfFitOptions per_level = base;
  per_level.experimental.noise = NoiseHandling::debias;
  per_level.noise_sigma_per_level.resize(static_cast<size_t>(levels));
  for (int v = 0; v < levels; ++v)
    per_level.noise_sigma_per_level[static_cast<size_t>(v)] =
        std::min(0.5, intensityNoiseSigma(fitted, so.sharp_noise, static_cast<double>(v) / (levels - 1)));
  err[2].push_back(curveRmse(fitInverseCrf(pair.sharp, pair.blurred, kernel, per_level).inverse_crf, truth));
  CrfFitOptions den = base;
  den.experimental.noise = NoiseHandling::denoise;
  err[3].push_back(curveRmse(fitInverseCrf(pair.sharp, pair.blurred, kernel, den).inverse_crf, truth));
}

// One detail row per noise scale; returns scale → mean phi RMSE per variant.
std::map<double, std::vector<double>> noiseBenchmarkRows(const std::map<double, std::vector<std::vector<double>>>& errors,
                                                         StudyTable& table) {
  std::map<double, std::vector<double>> mean_err;
  for (const auto& [scale, err] : errors) {
    std::vector<std::string> row{"benchmark", "noise = 5D II ISO3200 (G) x" + fmt(scale, 0) + ", " +
                                                  std::to_string(err[0].size()) + " cases: phi RMSE"};
    for (size_t v = 0; v < kNoiseVariants.size(); ++v) {
      mean_err[scale].push_back(meanOf(err[v]));
      row.push_back(kNoiseVariants[v] + "=" + fmt(meanOf(err[v]), 4));
    }
    table.rows.push_back(row);
    table.extra["benchmark"][fmt(scale, 0)] = {{"variants", kNoiseVariants}, {"errors", err}};
  }
  return mean_err;
}

void noiseSummary(const NoiseMisfits& misfits, const std::map<double, std::vector<double>>& mean_err,
                  StudyTable& table) {
  SummaryRow s;
  s.assumption = "homoscedastic Gaussian noise added to the intensities I (seed Sec. 5)";
  s.misfit = "RMS log(sigma_model/sigma_measured) over intensity bins of " + std::to_string(misfits.constant.size()) +
             " real JPEGs: constant sigma " + fmt(meanOf(misfits.constant), 3);
  s.cause = "sensor noise is Poisson-Gaussian in RAW (var = a x + b, darktable) and the camera curve rescales it by "
            "psi'(phi(v)): large in the darks, small near white (JPEG denoising flattens it further)";
  s.extended = "sigma_I(v) = psi'(phi(v)) sqrt(a phi(v) + b): misfit " + fmt(meanOf(misfits.through_curve), 3) +
               " (a v + b in intensity: " + fmt(meanOf(misfits.intensity_affine), 3) +
               "); simulator simulatePairPoissonGaussian; fitter: sigma(v) per level (noise_sigma_per_level) in the "
               "debiasing instead of one sigma";
  std::ostringstream gain;
  for (const auto& [scale, m] : mean_err)
    gain << "x" << fmt(scale, 0) << ": phi RMSE homoscedastic sigma " << fmt(m[1], 4) << " -> sigma(v) " << fmt(m[2], 4)
         << " (" << pct(m[2] / m[1] - 1) << "); crfcal default (no noise handling) " << fmt(m[0], 4) << ", denoise "
         << fmt(m[3], 4) << "; ";
  s.gain = gain.str();
  table.summary.push_back(s);
  table.extra["misfit"] = {{"constant", misfits.constant},
                           {"intensity_affine", misfits.intensity_affine},
                           {"through_curve", misfits.through_curve}};
}

int runNoise(const StudyArgs& args) {
  const fs::path root = requireData(args, "noise_profiles");
  io::OutputDirectory out(args.output, {"study noise", {root}, args.force});  // refused or unwritable: fails now
  Progress progress(args.quiet);
  StudyTable table;
  table.study = "noise";
  table.header = {"source", "what", "value_1", "value_2", "value_3", "value_4"};
  const ResponseCurve gamma22(GammaModel{2.2});
  const ResponseCurve g0(EmorModel{{0.0}});
  progress.stage("darktable profiles");
  std::vector<io::PlotSeries> profile_series;
  const PoissonGaussianNoise bench_noise = studyNoiseProfiles(root, gamma22, table, profile_series);
  progress.done();

  progress.stage("measure real noise");
  NoiseMisfits misfits;
  std::vector<io::PlotSeries> measured_series;
  for (const auto& [name, path] : realNoiseImages(root)) measureImageNoise(name, path, g0, table, misfits, measured_series);
  progress.done();

  progress.stage("benchmark (realistic noise)");
  const std::vector<NoiseCase> cases = noiseCases(args.cases);
  std::map<double, std::vector<std::vector<double>>> errors;  // scale → variant → errors
  int done = 0;
  for (const auto& c : cases) {
    runNoiseCase(c, bench_noise, static_cast<std::uint64_t>(done + 1), errors[c.noise_scale]);
    ++done;
    progress.update(double(done) / double(cases.size()), std::to_string(done) + "/" + std::to_string(cases.size()));
  }
  progress.done();
  noiseSummary(misfits, noiseBenchmarkRows(errors, table), table);

  emit(table, out);
  io::PlotOptions plot;
  plot.title = "darktable noise profiles through gamma 2.2: sigma_I(v)";
  plot.x_label = "intensity v";
  plot.y_label = "sigma_I (8-bit)";
  plot.y_min = 0;
  io::writePlot(out.file("profiles_sigma.png"), profile_series, plot);
  plot.title = "measured noise of real JPEGs (markers) and psi'(phi) sqrt(a phi + b) fits (lines)";
  io::writePlot(out.file("measured_sigma.png"), measured_series, plot);
  out.commit();
  std::printf("wrote %s/{table.csv, details.csv, table.json, profiles_sigma.png, measured_sigma.png}\n",
              args.output.c_str());
  return kExitOk;
}

void addCommon(CLI::App* sub, StudyArgs& args) {
  sub->add_option("--data", args.data, "Shared data directory (default $CRFCAL_SHARED_DATA or ../shared/data)");
  sub->add_option("-o,--output", args.output, "Output directory (created or replaced atomically)")->required();
  sub->add_flag("--force", args.force, kForceHelp);
  sub->add_flag("-q,--quiet", args.quiet, "No progress output");
}

const CommandRegistration registration(
    70, "study", "Studies on measured data: what the seed's simulation gets wrong (channels | noise | ratio)",
    [](CLI::App& command) {
      auto args = std::make_shared<StudyArgs>();
      auto which = std::make_shared<std::string>();
      command.require_subcommand(1);
      CLI::App* channels = command.add_subcommand(
          "channels", "Middlebury RAW->JPEG: pointwise per-channel curve vs 3x3 colour mix (+ gamut clip), held out");
      addCommon(channels, *args);
      channels->add_option("--knots", args->knots, "Segments of each monotone curve")->check(CLI::Range(2, 64));
      channels->callback([which] { *which = "channels"; });
      CLI::App* noise = command.add_subcommand(
          "noise", "Real noise vs the seed's homoscedastic model; realistic-noise benchmark of the fitter");
      addCommon(noise, *args);
      noise->add_option("--cases", args->cases, "Benchmark cases (at most 16)")->check(CLI::Range(1, 16));
      noise->callback([which] { *which = "noise"; });
      CLI::App* ratio = command.add_subcommand(
          "ratio", "EXIF vs fitted exposure ratios (brackets, phone pairs) and the effect of a wrong r on phi");
      addCommon(ratio, *args);
      ratio->add_option("--images", args->images, "Levin images in the wrong-r sweep")->check(CLI::Range(1, 4));
      ratio->callback([which] { *which = "ratio"; });
      return [args, which] {
        if (*which == "channels") return runChannels(*args);
        if (*which == "noise") return runNoise(*args);
        return runRatio(*args);
      };
    });

}  // namespace
}  // namespace crfcal::app
