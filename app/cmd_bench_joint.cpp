// crfcal bench joint: several semi-real pairs of ONE camera (one measured curve) with different photos, kernels and
// exposures, so that their covered ranges differ, each calibrated alone (the calibrate pipeline) and then jointly
// (joint_calibration.hpp). Per curve: the joint φ_G and each single φ_G against the truth, over [0, 1], over the
// union of the pairs' covered ranges, and there in shape (after the best common scale: φ → bφ leaves Eq. 4
// unchanged); the joint band's coverage of the truth.
// The pairs are those of `bench pairs` in its sharp-normal regime (handheld_simulation.hpp), 4:2:0 JPEG with EXIF.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <memory>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "bench_command.hpp"
#include "option_checks.hpp"
#include "crfcal/curve_band.hpp"
#include "crfcal/io/curve_prior_io.hpp"
#include "crfcal/curve_comparison.hpp"
#include "crfcal/error.hpp"
#include "crfcal/handheld_simulation.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/exif.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/joint_calibration.hpp"
#include "crfcal/pair_calibration.hpp"
#include "bench_real_regime.hpp"
#include "progress.hpp"

namespace crfcal::app {
namespace {
namespace fs = std::filesystem;

struct JointBenchArgs {
  std::string data;  // ../shared/data (or CRFCAL_SHARED_DATA): the photos
  std::vector<std::string> images;
  std::vector<std::string> crfs;
  int pairs = 3;
  int max_side = 600;
  int band_replicates = 8;  // of the joint fit (the single pairs' bands are not computed: not compared here)
  // Fraction of the photo's tonal range kept (about its middle grey) before it is re-exposed: a low-contrast scene,
  // so that each pair covers only part of [0, 1] and the pairs' exposures move their ranges apart. 1: the photo as
  // it is (the wide-range scenes of bench pairs cover 0-0.9 at any exposure).
  double contrast = 0.35;
  std::string joint_ratio = "pair";  // the r each pair holds in the joint fit: pair (its single-pair r) or exif
  bool band_fixed_ratio = false;     // the joint band's replicates hold r (no draws from its uncertainty)
  int joint_ratio_rounds = JointCalibrationOptions{}.ratio_rounds;  // rounds moving each r to its r at the joint φ
  // An additive irradiance offset (fraction of full scale) in the blurred shot of pair `offset_pair` (1-based) of
  // every curve: a flare or black level of one shot, which that pair alone absorbs into φ + c / (r − 1) and the
  // joint fit cannot (JointPairSummary::joint_misfit). 0: none.
  double offset = 0;
  int offset_pair = 1;
  bool joint_offsets = JointCalibrationOptions{}.pair_offsets;  // each pair's offset fitted in the rounds
  // The real regime (as `bench pairs --ratio R`, R > 2): every pair at r = R, its blurred shot normally exposed at
  // the noise camera's lowest ISO (or blurred_iso) and its sharp shot underexposed by R at R× that ISO, each with
  // the camera's measured noise. 0: the sharp-normal pairs at r = 2, 2, 1 (the default).
  double ratio = 0;
  std::string noise_camera = "LGE Nexus 5";
  std::string noise_profiles;  // darktable noiseprofiles.json (empty: --data's, else the bundled excerpt)
  double blurred_iso = 0;
  // The joint band above the data (CurveBandOptions::above_data_prior): "learned" (the prior learned from the bundled
  // camera curves without the case's camera, as `calibrate` uses it with all of them) or "bounds" (exponent bounds).
  std::string band_above = "learned";
  std::string output;
  bool force = false;
};

// The same photos and curves as `bench pairs` (its defaults).
const char* kPhotos[] = {"brackets/nikon_e995_window/HDRI_Sample_Scene_Window_-_05.jpg",
                         "brackets/canon5d2_frobisher/IMG_2601.jpg",
                         "brackets/canon_s3is_stlouisarch/StLouisArchMultExpEV+1.51.jpeg"};
const char* kCurves[] = {"NikonD70", "CanonPowerShotG9", "SonyDSLR-A100"};
const char* kKernels[] = {"levin:1", "levin:3", "levin:8", "levin:2", "levin:5", "levin:6"};

// Pair p of n: its mean irradiance spread in log from dark (0.04) to bright (0.5), so that the covered ranges
// differ; r = 2 for the darker pairs (the blurred shot reaches higher), 1 for the brighter (it would clip).
double pairExposure(int p, int n) { return n == 1 ? 0.2 : 0.04 * std::pow(0.5 / 0.04, double(p) / (n - 1)); }
double pairRatio(int p, int n) { return pairExposure(p, n) < 0.25 ? 2.0 : 1.0; }

// The pair's true r: the real regime's for every pair, else pairRatio.
double pairRatio(const JointBenchArgs& args, int p) { return args.ratio > 0 ? args.ratio : pairRatio(p, args.pairs); }

struct Scores {
  ChannelComparison union_range;  // against the truth over the union's range
  std::pair<double, double> covered{0, 1};
};

Scores score(const std::vector<double>& phi, const std::vector<double>& truth, std::pair<double, double> union_range,
             std::pair<double, double> own) {
  Scores s;
  s.union_range = compareCurves(truth, phi, union_range, union_range);
  s.covered = own;
  return s;
}

std::string row(const std::string& curve, const std::string& fit, const Scores& s, const std::string& extra) {
  char line[300];
  std::snprintf(line, sizeof line, "| %s | %s | %.2f-%.2f | %.4f | %.4f | %.4f | %s |\n", curve.c_str(), fit.c_str(),
                s.covered.first, s.covered.second, s.union_range.rmse, s.union_range.rmse_covered,
                s.union_range.rmse_covered_aligned, extra.c_str());
  return line;
}

struct Totals {
  int curves = 0;
  double joint_full = 0, joint_union = 0, joint_shape = 0;
  double single_full = 0, single_union = 0, single_shape = 0;  // mean over the pairs
  double best_full = 0, best_union = 0, best_shape = 0;        // the best single pair of each curve
  BandScore band;
  int band_curves = 0;
  std::vector<double> largest_misfit;  // per curve: the largest of its pairs' misfits
};

class JointRun {
 public:
  JointRun(const JointBenchArgs& a, io::OutputDirectory& o, std::optional<io::CameraNoiseProfile> camera)
      : args(a), out(o), noise_camera(std::move(camera)) {}

  void runCurve(const std::string& crf, const std::vector<cv::Mat>& photos) {
    const std::string name = fs::path(crf.substr(crf.rfind(':') + 1)).stem().string();
    progress.stage(name);
    const ResponseModel truth_model = io::parseResponseSpec(crf);
    const std::vector<double> truth = sampleInverse(truth_model);
    std::vector<PairCalibrationResult> results;
    nlohmann::json pairs_json = nlohmann::json::array();
    for (int p = 0; p < args.pairs; ++p) {
      const fs::path dir = out.file(name + "_pair" + std::to_string(p + 1));
      const std::string kernel_spec = kKernels[p % std::size(kKernels)];
      results.push_back(calibrateCase(photos[p % photos.size()], truth_model, kernel_spec, p, dir));
      pairs_json.push_back({{"kernel", kernel_spec}, {"exposure", pairExposure(p, args.pairs)},
                            {"ratio", pairRatio(args, p)}, {"ratio_fitted", results.back().fits.at("G").ratio},
                            {"blurred_offset", p + 1 == args.offset_pair ? args.offset : 0.0},
                            {"covered_G", results.back().covered_range.at("G")},
                            {"inverse_crf_G", results.back().fits.at("G").inverse_crf}});
    }
    JointCalibrationOptions options;
    options.band.replicates = args.band_replicates;
    options.ratio_source = args.joint_ratio == "exif" ? JointCalibrationOptions::RatioSource::nominal
                                                      : JointCalibrationOptions::RatioSource::pair_fit;
    options.band_varies_ratio = !args.band_fixed_ratio;
    options.ratio_rounds = args.joint_ratio_rounds;
    options.pair_offsets = args.joint_offsets;
    // leave one camera out: the truth's camera is not among the prior's training curves
    if (args.band_above == "learned") options.band.above_data_prior = io::learnPriorFromCameraCurves({name});
    const JointCalibrationResult joint = calibrateJointly(results, options);
    const auto union_range = joint.covered_range.at("G");
    const Scores j = score(joint.fits.at("G").inverse_crf, truth, union_range, union_range);
    std::string band_text = "-";
    if (joint.bands.count("G")) {
      const BandScore b = scoreBand(joint.bands.at("G"), joint.fits.at("G").inverse_crf, truth);
      accumulate(b);
      char text[120];
      std::snprintf(text, sizeof text, "band: truth inside %.0f %% (shape %.0f %%), above %.0f %%",
                    100.0 * b.inside_hits / std::max(1, b.inside), 100.0 * b.shape_hits / std::max(1, b.inside),
                    100.0 * b.above_hits / std::max(1, b.above));
      band_text = text;
    }
    band_text += std::string(band_text == "-" ? "" : "; ") + "verdict " + toString(joint.verdicts.at("G").level);
    table << row(name, "joint", j, band_text);
    double best_full = 1e9, best_union = 1e9, best_shape = 1e9;
    for (int p = 0; p < args.pairs; ++p) {
      const Scores s = score(results[p].fits.at("G").inverse_crf, truth, union_range, results[p].covered_range.at("G"));
      const JointPairSummary& in_joint = joint.pairs[p];
      const auto misfit = in_joint.joint_misfit.find("G");
      char extra[240];
      std::snprintf(extra, sizeof extra,
                    "%s, exposure %.2f, r %.0f (fitted %.3f; joint fit at %.3f; at the joint phi %.3f), misfit %.2fx",
                    kKernels[p % std::size(kKernels)], pairExposure(p, args.pairs), pairRatio(args, p),
                    results[p].fits.at("G").ratio, in_joint.ratio.at("G"), in_joint.ratio_at_joint_phi.at("G"),
                    misfit == in_joint.joint_misfit.end() ? std::nan("") : misfit->second);
      pairs_json[p]["ratio_at_joint_phi"] = in_joint.ratio_at_joint_phi.at("G");
      pairs_json[p]["ratio_joint_fit"] = in_joint.ratio.at("G");
      if (misfit != in_joint.joint_misfit.end()) pairs_json[p]["joint_misfit"] = misfit->second;
      if (const auto offset = in_joint.offset.find("G"); offset != in_joint.offset.end()) {
        pairs_json[p]["offset"] = offset->second;
        const std::size_t used = std::strlen(extra);
        std::snprintf(extra + used, sizeof extra - used, ", offset %+.4f", offset->second);
      }
      table << row(name, "pair " + std::to_string(p + 1), s, extra);
      totals.single_full += s.union_range.rmse / args.pairs;
      totals.single_union += s.union_range.rmse_covered / args.pairs;
      totals.single_shape += s.union_range.rmse_covered_aligned / args.pairs;
      best_full = std::min(best_full, s.union_range.rmse);
      best_union = std::min(best_union, s.union_range.rmse_covered);
      best_shape = std::min(best_shape, s.union_range.rmse_covered_aligned);
    }
    double largest = -1;  // -1: none measured (no pair alone fitted to a finite energy)
    for (const JointPairSummary& pair : joint.pairs)
      if (const auto m = pair.joint_misfit.find("G"); m != pair.joint_misfit.end())
        largest = std::max(largest, m->second);
    totals.largest_misfit.push_back(largest);
    ++totals.curves;
    totals.joint_full += j.union_range.rmse, totals.joint_union += j.union_range.rmse_covered;
    totals.joint_shape += j.union_range.rmse_covered_aligned;
    totals.best_full += best_full, totals.best_union += best_union, totals.best_shape += best_shape;
    results_json.push_back({{"curve", crf}, {"pairs", pairs_json}, {"joint_inverse_crf_G", joint.fits.at("G").inverse_crf},
                            {"union_G", union_range}, {"joint_rmse_G", j.union_range.rmse},
                            {"joint_rmse_G_union", j.union_range.rmse_covered},
                            {"joint_shape_rmse_G_union", j.union_range.rmse_covered_aligned},
                            {"joint_verdict_G", toString(joint.verdicts.at("G").level)},
                            {"joint_verdict_reasons_G", joint.verdicts.at("G").reasons},
                            {"summary", joint.summary()}});
    progress.done(row(name, "joint", j, band_text));
  }

  std::string finish() {
    const double n = std::max(1, totals.curves);
    char line[600];
    std::snprintf(line, sizeof line,
                  "\nMean over %d curves, phi_G against the truth (RMSE over [0, 1] / over the union of the pairs' "
                  "covered ranges / there in shape):\n\n| fit | [0, 1] | union | union, shape |\n|---|---|---|---|\n"
                  "| joint | %.4f | %.4f | %.4f |\n| single pairs (mean) | %.4f | %.4f | %.4f |\n"
                  "| best single pair of each curve | %.4f | %.4f | %.4f |\n",
                  totals.curves, totals.joint_full / n, totals.joint_union / n, totals.joint_shape / n,
                  totals.single_full / n, totals.single_union / n, totals.single_shape / n, totals.best_full / n,
                  totals.best_union / n, totals.best_shape / n);
    std::string text = table.str() + line;
    std::string misfits;
    for (const double m : totals.largest_misfit) {
      char value[32];
      if (m < 0) std::snprintf(value, sizeof value, "%s-", misfits.empty() ? "" : " / ");
      else std::snprintf(value, sizeof value, "%s%.2f", misfits.empty() ? "" : " / ", m);
      misfits += value;
    }
    std::snprintf(line, sizeof line,
                  "\nPairs' misfit (the joint phi's energy on a pair's rows over that of a phi fitted to the pair "
                  "alone at the same r): largest per curve %s\n",
                  misfits.c_str());
    text += line;
    if (totals.band_curves > 0) {
      const BandScore& b = totals.band;
      std::snprintf(line, sizeof line,
                    "\nJoint band (pooled over the curves): truth inside the absolute band %.1f %% inside the union, "
                    "%.1f %% above, %.1f %% below; shape band inside %.1f %%\n",
                    100.0 * b.inside_hits / std::max(1, b.inside), 100.0 * b.above_hits / std::max(1, b.above),
                    100.0 * b.below_hits / std::max(1, b.below), 100.0 * b.shape_hits / std::max(1, b.inside));
      text += line;
    }
    return text;
  }

  nlohmann::json results_json = nlohmann::json::array();

 private:
  void accumulate(const BandScore& b) {
    BandScore& t = totals.band;
    t.inside += b.inside, t.inside_hits += b.inside_hits, t.above += b.above, t.above_hits += b.above_hits;
    t.below += b.below, t.below_hits += b.below_hits, t.shape_hits += b.shape_hits;
    ++totals.band_curves;
  }

  // One pair written as `bench pairs` writes it (JPEG + EXIF), read back and calibrated alone.
  PairCalibrationResult calibrateCase(const cv::Mat& photo, const ResponseModel& truth, const std::string& kernel_spec,
                                      int p, const fs::path& dir) {
    HandheldPairOptions ho;
    ho.ratio = pairRatio(args, p);
    ho.exposure = pairExposure(p, args.pairs);
    std::optional<RealExposure> exposure;
    if (noise_camera) {
      exposure = realExposure(*noise_camera, args.blurred_iso, ho.ratio);
      ho.normally_exposed = HandheldPairOptions::NormallyExposed::Blurred;
      ho.sharp_noise = exposure->noise_sharp;
      ho.blurred_noise = exposure->noise_blurred;
    }
    const double angle = (p + 1) * 2.399963;  // a different handheld motion per pair (golden angle)
    ho.shift_x = 4.3 * std::cos(angle);
    ho.shift_y = 4.3 * std::sin(angle);
    ho.rotation_deg = p % 2 ? 0.4 : -0.4;
    ho.seed = static_cast<std::uint64_t>(p + 1);
    if (p + 1 == args.offset_pair) ho.blurred_offset = args.offset;
    cv::Mat scene;
    photo.convertTo(scene, -1, args.contrast, 127.5 * (1 - args.contrast));  // its range about mid grey
    const HandheldPair pair = makeHandheldPair(scene, truth, io::kernelFromSpec(kernel_spec), ho);
    fs::create_directories(dir);
    io::writeJpeg(dir / "sharp.jpg", pair.sharp, 95);
    io::writeJpeg(dir / "blurred.jpg", pair.blurred, 95);
    ExifExposure es, eb;
    es.make = eb.make = "crfcal";
    es.model = eb.model = "semi-real handheld";
    es.iso = 800;
    es.exposure_time = 0.01;
    es.f_number = eb.f_number = 4.0;
    eb.iso = 100;
    eb.exposure_time = ho.ratio * 1.04 * 800 * 0.01 / 100;  // EXIF 4 % off the truth, as bench pairs
    if (exposure) setRealExif(es, eb, *exposure, ho.ratio, 0.04);
    io::writeExif(dir / "sharp.jpg", es);
    io::writeExif(dir / "blurred.jpg", eb);
    const io::LoadedPair loaded = io::loadPair(dir / "sharp.jpg", dir / "blurred.jpg");
    PairCalibrationOptions options;
    options.rgb = false;
    options.fit.nominal_ratio = loaded.exif_ratio->ratio();
    options.band.replicates = 0;
    options.keep_fit_inputs = true;
    return calibratePair(loaded.sharp.image, loaded.blurred.image, options);
  }

  const JointBenchArgs& args;
  io::OutputDirectory& out;
  std::optional<io::CameraNoiseProfile> noise_camera;  // the real regime's (--ratio)
  Progress progress{false};
  std::ostringstream table;
  Totals totals;
};

int runJointBench(const JointBenchArgs& args) {
  if (args.ratio > 0 && args.ratio <= 2) {
    char given[32];
    std::snprintf(given, sizeof given, "%g", args.ratio);
    throw Error(std::string("--ratio ") + given + ": the real regime is for r > 2 (0: the default pairs)",
                ErrorSubject::options);
  }
  if (args.offset != 0 && args.offset_pair > args.pairs)
    throw Error("--offset-pair " + std::to_string(args.offset_pair) + " names no pair (--pairs " +
                std::to_string(args.pairs) + ")", ErrorSubject::options);
  std::vector<std::string> images = args.images, crfs = args.crfs;
  if (images.empty())
    for (const char* p : kPhotos) {
      const fs::path path = io::defaultSharedData(args.data) / p;
      if (!fs::exists(path)) throw Error("default photo not found (give --image or --data / CRFCAL_SHARED_DATA)", path.string());
      images.push_back(path.string());
    }
  if (crfs.empty())
    for (const char* c : kCurves)
      crfs.push_back("table:" + (io::samplesDirectory() / "camera_curves" / (std::string(c) + ".csv")).string());
  std::vector<fs::path> inputs(images.begin(), images.end());
  for (const auto& spec : crfs) inputs.push_back(io::specInput(spec));
  io::OutputDirectory out(args.output, {"bench joint", inputs, args.force});
  std::vector<cv::Mat> photos;
  for (const auto& path : images) {
    cv::Mat photo = io::readImage(path);
    if (photo.depth() != CV_8U) photo.convertTo(photo, CV_8U, 255.0 / 65535.0);
    const double s = std::min(1.0, double(args.max_side) / std::max(photo.cols, photo.rows));
    if (s < 1) cv::resize(photo, photo, cv::Size(), s, s, cv::INTER_AREA);
    photos.push_back(photo);
  }
  std::optional<io::CameraNoiseProfile> noise_camera;
  if (args.ratio > 0)
    noise_camera = io::readCameraNoiseProfile(
        args.noise_profiles.empty() ? io::defaultNoiseProfiles(args.data) : fs::path(args.noise_profiles),
        args.noise_camera);
  JointRun run(args, out, noise_camera);
  std::ostringstream header;
  header << "Joint fit of " << args.pairs << " semi-real pairs per camera curve (photos, kernels and exposures "
         << "differ per pair); phi_G against the truth.";
  if (noise_camera) {
    const RealExposure e = realExposure(*noise_camera, args.blurred_iso, args.ratio);
    header << " Real regime: every pair at r = " << args.ratio << ", noise of " << noise_camera->camera() << ", ISO "
           << e.iso_sharp << " / " << e.iso_blurred << " (sharp / blurred).";
  }
  if (args.offset != 0)
    header << " Pair " << args.offset_pair << "'s blurred shot has an offset " << args.offset << ".";
  header << "\n\n| curve | fit | covered G | RMSE [0, 1] | RMSE over the "
         << "union | shape RMSE over the union | notes |\n|---|---|---|---|---|---|---|\n";
  for (const auto& crf : crfs) run.runCurve(crf, photos);
  const std::string text = header.str() + run.finish();
  io::writeTextFile(out.file("results.md"), text);
  io::writeTextFile(out.file("results.json"), run.results_json.dump(1) + "\n");
  out.commit();
  std::printf("%s", text.c_str());
  std::printf("wrote %s/{results.md, results.json, <curve>_pair*/}\n", args.output.c_str());
  return kExitOk;
}

const BenchRegistration registration(
    45, "joint",
    "Several semi-real pairs of one camera curve (different photos, kernels, exposures) calibrated alone and "
    "jointly (calibrate --pair ...): phi_G against the truth over the union of their covered ranges",
    [](CLI::App& command) {
      auto args = std::make_shared<JointBenchArgs>();
      command.add_option("--pairs", args->pairs, "Pairs per camera curve")->capture_default_str()->check(CLI::Range(2, 6));
      command.add_option("--image", args->images, "Photo(s) to make pairs from (default: three photos of --data)")
          ->check(CLI::ExistingFile);
      command.add_option("--data", args->data, "The shared data directory (default: $CRFCAL_SHARED_DATA or ../shared/data)");
      command.add_option("--crf", args->crfs, "True inverse response(s) phi (spec; default: three measured cameras)");
      command.add_option("--max-side", args->max_side, "Downscale the photos to this longest side")
          ->capture_default_str()
          ->check(CLI::Range(128, 4096));
      command.add_option("--contrast", args->contrast,
                         "Fraction of each photo's tonal range kept before it is re-exposed (1: as it is)")
          ->capture_default_str()
          ->check(CLI::Range(0.05, 1.0));
      command.add_option("--joint-ratio", args->joint_ratio,
                         "The r each pair holds in the joint fit: pair (its final single-pair r) or exif (its EXIF r)")
          ->capture_default_str()
          ->check(CLI::IsMember({"pair", "exif"}));
      command.add_option("--joint-ratio-rounds", args->joint_ratio_rounds,
                         "Rounds moving each pair's r from that start to the least-squares r of its rows at the joint "
                         "phi, then refitting phi (0: r held)")
          ->capture_default_str()
          ->check(CLI::Range(0, 20));
      command.add_flag("--joint-offsets", args->joint_offsets,
                       "Fit each pair's additive irradiance offset (a flare or black level of one shot) in the rounds, "
                       "beside its r");
      command.add_option("--ratio", args->ratio,
                         "The real regime: every pair at this r (> 2), the blurred shot normally exposed at the noise "
                         "camera's lowest ISO, the sharp one underexposed by r at r x that ISO, each with the camera's "
                         "measured noise (0: the sharp-normal pairs at r = 2, 2, 1)")
          ->capture_default_str()
          ->check(CLI::Range(0.0, 16.0));
      command.add_option("--noise-camera", args->noise_camera,
                         "--ratio: camera whose darktable noise profile the shots get, \"maker model\"")
          ->capture_default_str();
      command.add_option("--noise-profiles", args->noise_profiles,
                         "--ratio: darktable noiseprofiles.json (default: --data's noise_profiles/noiseprofiles.json, "
                         "else the bundled excerpt samples/noise_profiles/)")
          ->check(CLI::ExistingFile);
      command.add_option("--blurred-iso", args->blurred_iso,
                         "--ratio: ISO of the blurred shot (0: the noise camera's lowest profiled ISO)")
          ->capture_default_str()
          ->check(CLI::NonNegativeNumber);
      command.add_option("--offset", args->offset,
                         "An additive irradiance offset (fraction of full scale) in the blurred shot of one pair of "
                         "each curve (--offset-pair): a flare or black level of that shot alone, which the joint fit "
                         "shows as that pair's misfit")
          ->capture_default_str()
          ->check(CLI::Range(-0.5, 0.5));
      command.add_option("--offset-pair", args->offset_pair, "The pair (1-based) whose blurred shot gets --offset")
          ->capture_default_str()
          ->check(CLI::Range(1, 6));
      command.add_flag("--band-fixed-ratio", args->band_fixed_ratio,
                       "The joint band's replicates hold each pair's r (ablation: no draws from its uncertainty)");
      command.add_option("--band-replicates", args->band_replicates, "Half-sample refits of the joint band (even; 0: none)")
          ->capture_default_str()
          ->check(bandReplicates());
      command.add_option("--band-above", args->band_above,
                         "The joint band above the covered range: the quantiles of the prior learned from the bundled "
                         "camera curves without the truth's camera (learned) or the exponent bounds (bounds)")
          ->capture_default_str()
          ->check(CLI::IsMember({"bounds", "learned"}));
      command.add_option("-o,--output", args->output, "Output directory")->required();
      command.add_flag("--force", args->force, kForceHelp);
      return [args] { return runJointBench(*args); };
    });

}  // namespace
}  // namespace crfcal::app
