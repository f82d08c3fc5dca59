// crfcal study pairs: what the seed's simulation assumes that the real phone pairs (vivo X6S, ../shared/data/pairs)
// contradict, one row per candidate cause (issue 17, item 2): the exponent ambiguity, the sharp shot's noise
// reduction, a tone curve that differs between the shots, sharpening halos, 4:2:0 chroma, a multi-frame long shot,
// the sharp shot's noise reaching black under its noise estimate.
// Each cause is supported or ruled out by a number measured on every pair; where crfcal has an extended model or a
// decision rule its gain on the real pairs is measured here and its gain on the semi-real bench is quoted with the
// command that prints it (docs/RESULTS.md, "Studies on measured data").
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "command.hpp"
#include "crfcal/bracket_calibration.hpp"
#include "crfcal/curve_shape_spread.hpp"
#include "crfcal/edge_profile.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/exposure_fit.hpp"
#include "crfcal/io/atomic_output.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/image_io.hpp"
#include "crfcal/io/jpeg_info.hpp"
#include "crfcal/io/pair_input.hpp"
#include "crfcal/kernel_shape.hpp"
#include "crfcal/noise_estimation.hpp"
#include "crfcal/noise_law_comparison.hpp"
#include "crfcal/pair_calibration.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/shot_imitation.hpp"
#include "progress.hpp"
#include "study_common.hpp"

namespace crfcal::app::study {
namespace fs = std::filesystem;
namespace {

// Decision thresholds of the rows (each with its reason; none chosen on the phone pairs).
// r off by more than this factor: EXIF's 1/3-stop rounding is σ 0.13 in log r, 3σ ≈ log 1.5 (channel_verdict.hpp).
constexpr double kRatioFactor = 1.5;
// Edges of the sharp shot smoothed: wider than the imitation (g_truth made as dark and noisy as the sharp shot,
// shot_imitation.hpp) smoothed by a Gaussian of this σ. σ 0.7 px has RMS radius σ√2 ≈ 1 px, the pair pipeline's
// min_blur_radius: smoothing that large would be as large as the blur that the pipeline needs to fix r. The
// threshold is measured per pair (the width's sensitivity to σ depends on the scene's edges: on g_truth_1 σ 0.5 / 0.8
// / 1.2 px widen the 1.67 px median edge by 17 / 60 / 113 %).
constexpr double kSmoothingSigma = 0.7;
// Halo: the lobes of the sharp shot's median edge profile above the blurred shot's (the blur removes lobes) by 5 %
// of the step — a sign change that no non-negative kernel produces, large enough to move the moments of Eq. 22.
constexpr double kHaloExcess = 0.05;

struct Shot {
  fs::path path;
  io::ExifCsvRow exif;
  std::string chroma;  // JPEG sampling read from the file
};

// Everything measured on one phone pair (noisy_N, blurred_N, g_truth_N).
struct PairMeasurement {
  std::string id;
  Shot noisy, blurred, truth;
  double exif_ratio = 0;
  PairCalibrationResult images;    // r from the images alone (--ratio-evidence off)
  PairCalibrationResult evidence;  // r from all the evidence (the default)
  PairCalibrationResult chroma;    // the default + the chroma model (`--chroma-model auto`)
  PairCalibrationResult black_per_pixel;  // the default with the black end's rule before stop 37 (`--black-end per-pixel`)
  BracketCalibrationResult bracket;  // noisy + g_truth: blur-free reference
  std::map<std::string, std::vector<double>> bracket_curve;               // per channel "R", "G", "B"
  std::map<std::string, std::pair<double, double>> bracket_range;         // their covered ranges
  double brightness_ratio = 0;      // noisy → blurred, quantile matching through the EMoR mean g0
  double bracket_phi_ratio = 0;     // noisy → blurred, quantile matching through the bracket's φ_G
  double bracket_self_ratio = 0;    // noisy → g_truth through the same φ_G (in-sample: the bracket's own frames)
  NoiseLawComparison noise;         // noisy's σ(v) against g_truth's (same ISO)
  EdgeProfile edge_noisy, edge_truth, edge_blurred;
  EdgeProfile edge_control;         // g_truth imitating noisy: its histogram and noise, 8 bits (shot_imitation.hpp)
  EdgeProfile edge_control_smoothed;  // … smoothed by kSmoothingSigma: the width threshold of "smoothed"
  double bracket_phi_spread = 0, bracket_self_spread = 0;  // relative spread of the quantile ratios
  KernelShape kernel;
  std::optional<KernelShape> truth_kernel;  // the kernel g_truth → blurred (a brighter sharp shot; effects, evidence off)
  std::string truth_kernel_failure;         // why there is none (the pipeline's reason)
  double noise_sigma_full = 0, noise_sigma_half = 0;  // G of noisy: the noise estimate at full and at half resolution
  int black_pixels = 0;              // G of noisy at level 0
  double isolated_black_share = 0;   // … of those, the share whose 5×5 median is not black: noise that reached black
};

double imagesRatio(const PairCalibrationResult& r) {
  return r.ratio_fixed_by_small_blur ? r.ratio_images_small_blur : r.fits.at("G").ratio;
}

// The bracket's EXIF ratio g_truth / noisy (ISO·t/N²).
double bracketExifRatio(const PairMeasurement& p) {
  auto exposure = [](const io::ExifCsvRow& e) { return e.iso * e.exposure_time / std::pow(e.f_number > 0 ? e.f_number : 1.0, 2); };
  return exposure(p.truth.exif) / exposure(p.noisy.exif);
}

std::string join(const std::vector<PairMeasurement>& pairs, const std::function<std::string(const PairMeasurement&)>& f) {
  std::string s;
  for (const auto& p : pairs) s += (s.empty() ? "" : "; ") + p.id + ": " + f(p);
  return s;
}

PairCalibrationResult calibrate(const io::LoadedPair& loaded, double exif_ratio, bool evidence, bool chroma_model = false,
                                bool black_per_pixel = false) {
  PairCalibrationOptions options;
  options.fit.experimental.black_per_pixel_when_clean = black_per_pixel;
  options.fit.nominal_ratio = exif_ratio;
  options.band.replicates = 0;  // the band does not change the curves; the study does not need it
  options.ratio_evidence.enabled = evidence;
  options.sharp_stored_chroma = {loaded.sharp.chroma_block_h, loaded.sharp.chroma_block_v};
  if (chroma_model) options.sharp_chroma = options.sharp_stored_chroma;
  return calibratePair(loaded.sharp.image, loaded.blurred.image, options);
}

// The kernel with g_truth as the sharp shot (ISO 3180 at 1/14 s: 7x brighter than noisy, a little shake of its own):
// whether the blurred shot's kernel shape is the blurred shot's or an artefact of the dark sharp shot.
void measureTruthKernel(PairMeasurement& m) {
  const io::LoadedPair loaded = io::loadPair(m.truth.path, m.blurred.path, io::BlurredChoice::second);
  PairCalibrationOptions options;
  options.fit.nominal_ratio = loaded.exif_ratio ? loaded.exif_ratio->ratio() : 1.0;
  options.rgb = false;
  options.band.replicates = 0;
  options.effects.enabled = false;  // the kernel is estimated before the effects; r is not used here
  options.ratio_evidence.enabled = false;
  try {
    m.truth_kernel = describeKernelShape(calibratePair(loaded.sharp.image, loaded.blurred.image, options).kernel.kernel);
  } catch (const InvalidInput& e) {  // an outcome of the measurement (g_truth was shot at another moment), not an error
    m.truth_kernel_failure = e.reason();
  }
}

// The blur-free reference: the phone's two-frame bracket noisy + g_truth (same ISO), exposures ISO·t/N² from EXIF.
void measureBracket(PairMeasurement& m) {
  std::vector<BracketFrame> frames;
  for (const Shot* s : {&m.noisy, &m.truth}) {
    BracketFrame f;
    f.name = s->path.string();
    f.image = io::readImage(s->path);
    f.exposure = s->exif.iso * s->exif.exposure_time / std::pow(s->exif.f_number > 0 ? s->exif.f_number : 1.0, 2);
    frames.push_back(f);
  }
  m.bracket = calibrateBracket(frames);
  for (const auto& c : m.bracket.channels) {
    const std::string name = c.channel == 0 ? "B" : c.channel == 1 ? "G" : "R";  // BGR frames
    m.bracket_curve[name] = c.fit.inverse;
    m.bracket_range[name] = c.fit.covered_range;
  }
  if (!m.bracket_curve.count("G")) throw Error("the bracket gave no green curve", m.truth.path.string());
}

void measureImages(PairMeasurement& m) {
  const cv::Mat noisy = greenUnit(m.noisy.path), blurred = greenUnit(m.blurred.path), truth = greenUnit(m.truth.path);
  ExposureRatioOptions quantiles;
  quantiles.registered = false;
  m.brightness_ratio = estimateExposureRatio(noisy, blurred, ResponseCurve(EmorModel{{0.0}}), quantiles).ratio;
  const ResponseCurve bracket_curve = ResponseCurve::fromSamples(m.bracket_curve.at("G"));
  const ExposureRatioEstimate to_blurred = estimateExposureRatio(noisy, blurred, bracket_curve, quantiles);
  const ExposureRatioEstimate to_truth = estimateExposureRatio(noisy, truth, bracket_curve, quantiles);
  m.bracket_phi_ratio = to_blurred.ratio;
  m.bracket_phi_spread = to_blurred.spread;
  m.bracket_self_ratio = to_truth.ratio;
  m.bracket_self_spread = to_truth.spread;
  NoiseLawOptions law;
  m.noise = compareNoiseToLaw(noisy, noiseLawFromBins(measureNoiseLevels(truth, law.levels)), law);
  m.edge_noisy = measureEdgeProfile(noisy);
  const cv::Mat imitation = imitateShot(truth, noisy, measureNoiseLevels(noisy, law.levels));
  m.edge_control = measureEdgeProfile(imitation);
  cv::Mat smoothed;
  cv::GaussianBlur(imitation, smoothed, cv::Size(), kSmoothingSigma);
  m.edge_control_smoothed = measureEdgeProfile(smoothed);
  m.edge_truth = measureEdgeProfile(truth);
  m.edge_blurred = measureEdgeProfile(blurred);
  m.kernel = describeKernelShape(m.evidence.kernel.kernel);
  const cv::Mat black = noisy <= 0.5 / 255;
  cv::Mat noisy32, median;
  noisy.convertTo(noisy32, CV_32F);
  cv::medianBlur(noisy32, median, 5);
  m.black_pixels = cv::countNonZero(black);
  m.noise_sigma_full = estimateNoiseSigma(noisy).sigma;
  m.noise_sigma_half = estimateNoiseSigmaAtHalfResolution(noisy).sigma;
  m.isolated_black_share = m.black_pixels ? double(cv::countNonZero(black & (median > 0.5 / 255))) / m.black_pixels : 0;
}

PairMeasurement measurePair(const fs::path& dir, const std::string& id, const std::map<std::string, io::ExifCsvRow>& exif,
                            Progress& progress) {
  PairMeasurement m;
  m.id = id;
  auto shot = [&](const std::string& stem) {
    const std::string file = stem + "_" + id + ".jpg";
    if (!exif.count(file)) throw Error("no row in exif.csv", (dir / file).string());
    return Shot{dir / file, exif.at(file), io::readJpegInfo(dir / file).subsampling};
  };
  m.noisy = shot("noisy");
  m.blurred = shot("blurred");
  m.truth = shot("g_truth");
  const io::LoadedPair loaded = io::loadPair(m.noisy.path, m.blurred.path, io::BlurredChoice::second);
  if (!loaded.exif_ratio) throw Error(loaded.exif_problem, m.blurred.path.string());
  m.exif_ratio = loaded.exif_ratio->ratio();
  progress.update(0.1, "pair " + id + ": r from the images");
  m.images = calibrate(loaded, m.exif_ratio, false);
  progress.update(0.5, "pair " + id + ": r from the evidence");
  m.evidence = calibrate(loaded, m.exif_ratio, true);
  progress.update(0.7, "pair " + id + ": chroma model");
  m.chroma = calibrate(loaded, m.exif_ratio, true, true);
  progress.update(0.8, "pair " + id + ": black end per pixel");
  m.black_per_pixel = calibrate(loaded, m.exif_ratio, true, false, true);
  progress.update(0.85, "pair " + id + ": kernel g_truth -> blurred");
  measureTruthKernel(m);
  progress.update(0.9, "pair " + id + ": bracket, noise, edges");
  measureBracket(m);
  measureImages(m);
  return m;
}

// ---------------------------------------------------------------------------------------------------- rows
std::vector<double> greenOf(const PairCalibrationResult& r) { return r.fits.at("G").inverse_crf; }
std::pair<double, double> greenRange(const PairCalibrationResult& r) { return r.covered_range.at("G"); }

struct ShapeSpreads {
  std::pair<double, double> pairs_range, brackets_range;
  double pairs_images = 0, pairs_evidence = 0, brackets = 0;
  std::vector<double> vs_bracket_images, vs_bracket_evidence;
  std::vector<std::pair<double, double>> vs_bracket_range;
};

ShapeSpreads shapeSpreads(const std::vector<PairMeasurement>& pairs) {
  ShapeSpreads s;
  std::vector<std::vector<double>> images, evidence, brackets;
  std::vector<std::pair<double, double>> ranges, bracket_ranges;
  for (const auto& p : pairs) {
    images.push_back(greenOf(p.images));
    evidence.push_back(greenOf(p.evidence));
    brackets.push_back(p.bracket_curve.at("G"));
    ranges.push_back(greenRange(p.images));
    ranges.push_back(greenRange(p.evidence));
    bracket_ranges.push_back(p.bracket_range.at("G"));
    const auto common = commonRange({greenRange(p.images), greenRange(p.evidence), p.bracket_range.at("G")});
    s.vs_bracket_range.push_back(common);
    s.vs_bracket_images.push_back(curveShapeSpread({greenOf(p.images), p.bracket_curve.at("G")}, common));
    s.vs_bracket_evidence.push_back(curveShapeSpread({greenOf(p.evidence), p.bracket_curve.at("G")}, common));
  }
  if (pairs.size() >= 2) {
    s.pairs_range = commonRange(ranges);
    s.brackets_range = commonRange(bracket_ranges);
    s.pairs_images = curveShapeSpread(images, s.pairs_range);
    s.pairs_evidence = curveShapeSpread(evidence, s.pairs_range);
    s.brackets = curveShapeSpread(brackets, s.brackets_range);
  }
  return s;
}

// Shape spread of one channel of a pair calibration against the same channel of its bracket over the range both
// (and `also`) cover; NaN when a curve or a common range is missing.
double channelVsBracket(const PairMeasurement& p, const PairCalibrationResult& r, const PairCalibrationResult& also,
                        const std::string& channel) {
  if (!r.fits.count(channel) || !r.covered_range.count(channel) || !also.covered_range.count(channel) ||
      !p.bracket_curve.count(channel))
    return std::nan("");
  try {
    return curveShapeSpread({r.fits.at(channel).inverse_crf, p.bracket_curve.at(channel)},
                            commonRange({r.covered_range.at(channel), also.covered_range.at(channel), p.bracket_range.at(channel)}));
  } catch (const InvalidInput&) {
    return std::nan("");
  }
}

// "supported on 2 of 3", or "ruled out (0 of 3)" / "not supported (0 of 3)": a cause counts where the pair's
// measurement crosses the row's threshold.
std::string verdictOn(int count, std::size_t total, const std::string& otherwise) {
  return count > 0 ? "supported on " + std::to_string(count) + " of " + std::to_string(total)
                   : otherwise + " (0 of " + std::to_string(total) + ")";
}

std::string range(const std::pair<double, double>& r) { return fmt(r.first, 2) + "-" + fmt(r.second, 2); }

SummaryRow ambiguityRow(const std::vector<PairMeasurement>& pairs, const ShapeSpreads& s) {
  int supported = 0;
  for (const auto& p : pairs) {
    const double off_images = std::abs(std::log(imagesRatio(p.images) / p.exif_ratio));
    const double off_brightness = std::abs(std::log(p.brightness_ratio / p.exif_ratio));
    supported += off_images > std::log(kRatioFactor) && off_brightness <= std::log(kRatioFactor);
  }
  SummaryRow r;
  r.assumption = "the blur fixes the curve's exponent, so r is fitted from the images (Eq. 25)";
  r.misfit = "images' r vs EXIF (brightness ratio, g0): " + join(pairs, [](const PairMeasurement& p) {
               return fmt(imagesRatio(p.images), 2) + " vs " + fmt(p.exif_ratio, 3) + " (" + fmt(p.brightness_ratio, 2) +
                      "), blur RMS radius " + fmt(p.images.blur_radius, 2) + " px, ambiguity rise of phi_G at the images' / the evidence's r " +
                      fmt(p.images.fits.at("G").ambiguity_rise, 3) + " / " + fmt(p.evidence.fits.at("G").ambiguity_rise, 3);
             });
  r.cause = "exponent ambiguity phi^g, r^g (a little blur cannot fix the exponent): " +
            verdictOn(supported, pairs.size(), "not supported") + " pairs (images' r off EXIF by > " + fmt(kRatioFactor, 1) +
            "x while the brightness ratio is within it)";
  r.extended = "decision rule: r from all the pair's evidence (calib/ratio_evidence.hpp, the default; "
               "`--ratio-evidence off` is the images alone)";
  std::string vs;
  for (std::size_t i = 0; i < pairs.size(); ++i)
    vs += (i ? "; " : "") + pairs[i].id + ": " + fmt(s.vs_bracket_images[i], 3) + " -> " + fmt(s.vs_bracket_evidence[i], 3) +
          " (x " + range(s.vs_bracket_range[i]) + ")";
  r.gain = "G shape spread of the pairs over their common covered range x " + range(s.pairs_range) + ": " +
           fmt(s.pairs_images, 3) + " -> " + fmt(s.pairs_evidence, 3) + " (the brackets among themselves " +
           fmt(s.brackets, 3) + ", x " + range(s.brackets_range) + "); each pair vs its bracket: " + vs +
           ". Semi-real (`crfcal bench pairs --ratio 4|8`, RESULTS 'r from all the pair's evidence'): r error mean "
           "3.3 % -> 2.3 % (r 4), 11.5 % -> 4.5 % (r 8); shape <= 0.01 on 25 -> 27 / 21 -> 23 of 27; r = 1 identical";
  return r;
}

SummaryRow noiseRow(const std::vector<PairMeasurement>& pairs) {
  int reduced = 0, smoothed = 0;
  for (const auto& p : pairs) {
    reduced += p.noise.reduced;
    smoothed += p.edge_noisy.width > p.edge_control_smoothed.width;
  }
  SummaryRow r;
  r.assumption = "the sharp shot is the scene plus sensor noise (Sec. 5 adds noise to I and nothing else)";
  r.misfit = "sigma(v) of noisy / sigma(v) of g_truth (same ISO 3200, same gain: same noise at the same level if "
             "processed alike), median over levels: " +
             join(pairs, [](const PairMeasurement& p) {
               return fmt(p.noise.median_ratio, 2) + " (" + std::to_string(p.noise.ratio.size()) + " levels)";
             }) +
             "; median edge 10-90 % width [px] noisy / g_truth imitating noisy (its histogram, noise, 8 bits) / "
             "the imitation smoothed by a " + fmt(kSmoothingSigma, 1) + " px Gaussian / g_truth / blurred: " +
             join(pairs, [](const PairMeasurement& p) {
               return fmt(p.edge_noisy.width, 2) + " / " + fmt(p.edge_control.width, 2) + " / " +
                      fmt(p.edge_control_smoothed.width, 2) + " / " + fmt(p.edge_truth.width, 2) + " / " +
                      fmt(p.edge_blurred.width, 2);
             });
  r.cause = "noise reduction stronger in the short shot than in the reference: " +
            verdictOn(reduced, pairs.size(), "ruled out") + " (ratio < 0.7); the short shot's edges smoothed (NR or the JPEG "
            "quantisation of a dark frame; wider than the smoothed imitation): " +
            verdictOn(smoothed, pairs.size(), "ruled out") +
            ". NR common to both shots is not measurable here: no darktable profile of this phone, and the files are "
            "downscaled by an unknown factor, so no sensor law predicts their sigma";
  r.extended = reduced || smoothed ? "not modelled (the kernel between the shots then holds the smoothing as well as the "
                                     "shake)" : "none needed";
  r.gain = "-";
  return r;
}

SummaryRow toneRow(const std::vector<PairMeasurement>& pairs, const ShapeSpreads& s) {
  int inconsistent = 0;
  for (const auto& p : pairs) inconsistent += std::abs(std::log(p.bracket_phi_ratio / p.exif_ratio)) > std::log(kRatioFactor);
  SummaryRow r;
  r.assumption = "one curve psi for both shots (Eq. 4), whatever their ISO and exposure";
  r.misfit = "noisy -> blurred brightness ratio through the bracket's phi_G (noisy + g_truth, no blur) vs EXIF "
             "[in-sample control noisy -> g_truth vs its EXIF]: " + join(pairs, [](const PairMeasurement& p) {
               return fmt(p.bracket_phi_ratio, 2) + " vs " + fmt(p.exif_ratio, 3) + " (" +
                      pct(p.bracket_phi_ratio / p.exif_ratio - 1) + ", spread over levels " + fmt(p.bracket_phi_spread, 3) +
                      ") [" + fmt(p.bracket_self_ratio, 2) + " vs " + fmt(bracketExifRatio(p), 2) + ", spread " +
                      fmt(p.bracket_self_spread, 3) + "]";
             });
  r.cause = "a tone curve that differs between the ISO 3200 and the ISO 100 shot: " +
            verdictOn(inconsistent, pairs.size(), "not supported") + " (off EXIF by > " + fmt(kRatioFactor, 1) + "x)";
  r.extended = "none (a per-shot curve is not identifiable from one pair); the verdict's brightness check";
  std::string vs;
  for (std::size_t i = 0; i < pairs.size(); ++i) vs += (i ? " / " : "") + fmt(s.vs_bracket_evidence[i], 3);
  r.gain = "- (pair G vs its bracket in shape, r from the evidence: " + vs + ")";
  return r;
}

SummaryRow haloRow(const std::vector<PairMeasurement>& pairs) {
  int halos = 0;
  for (const auto& p : pairs) halos += p.edge_noisy.halo() - p.edge_blurred.halo() > kHaloExcess;
  SummaryRow r;
  r.assumption = "the sharp shot is psi of the irradiance per pixel; the blurred one psi of a non-negative blur of it";
  r.misfit = "lobe of the median edge profile (overshoot + undershoot) / 2, share of the step, noisy / g_truth / blurred: " +
             join(pairs, [](const PairMeasurement& p) {
               return fmt(p.edge_noisy.halo(), 3) + " / " + fmt(p.edge_truth.halo(), 3) + " / " + fmt(p.edge_blurred.halo(), 3);
             });
  r.cause = "sharpening halos in the sharp shot: " + verdictOn(halos, pairs.size(), "ruled out") + " (noisy's lobes above blurred's by > " +
            fmt(kHaloExcess, 2) + ")";
  r.extended = halos ? "not modelled" : "none needed";
  r.gain = "-";
  return r;
}

SummaryRow chromaRow(const std::vector<PairMeasurement>& pairs) {
  SummaryRow r;
  r.assumption = "the decoded sharp shot is psi(E) per pixel and channel";
  r.misfit = "sampling noisy / blurred / g_truth and the images' r R/G/B: " + join(pairs, [](const PairMeasurement& p) {
               std::string s = p.noisy.chroma + " / " + p.blurred.chroma + " / " + p.truth.chroma + ", r";
               for (const char* c : {"R", "G", "B"})
                 if (p.images.fits.count(c)) s += std::string(" ") + fmt(p.images.fits.at(c).ratio, 2);
               return s;
             });
  std::string gain;
  int better = 0, compared = 0;
  double before = 0, after = 0;
  for (const char* c : {"R", "B"}) {
    gain += std::string(gain.empty() ? "" : "; ") + c + " shape vs the bracket's " + c + ", pointwise -> chroma model: " +
            join(pairs, [c](const PairMeasurement& p) {
              return fmt(channelVsBracket(p, p.evidence, p.chroma, c), 3) + " -> " + fmt(channelVsBracket(p, p.chroma, p.evidence, c), 3);
            });
    for (const auto& p : pairs) {
      const double b = channelVsBracket(p, p.evidence, p.chroma, c), a = channelVsBracket(p, p.chroma, p.evidence, c);
      if (std::isnan(a) || std::isnan(b)) continue;
      ++compared;
      better += a < b;
      before += b;
      after += a;
    }
  }
  int subsampled = 0;
  for (const auto& p : pairs) subsampled += p.noisy.chroma == "4:2:0" || p.noisy.chroma == "4:2:2" || p.noisy.chroma == "4:1:1";
  const bool helps = compared > 0 && 2 * better > compared && after < before;
  r.cause = "R and B of a chroma-subsampled sharp shot lose 2x2 detail: subsampled in " + std::to_string(subsampled) +
            " of " + std::to_string(pairs.size()) + " sharp shots; as the cause of the R/B misfit " +
            (helps ? "supported" : "not supported") + ": modelling it brings R/B closer to the brackets on " +
            std::to_string(better) + " of " + std::to_string(compared) + " (mean " +
            fmt(compared ? before / compared : 0, 3) + " -> " + fmt(compared ? after / compared : 0, 3) + ")";
  r.extended = "`calibrate --chroma-model auto` (opt-in) and the verdict: pointwise R/B of a subsampled sharp shot are at most 'weak'";
  r.gain = "real pairs (no truth; the blur-free brackets noisy + g_truth, themselves 4:2:0): " + gain +
           ". Semi-real (RESULTS 'Chroma subsampling modelled'): demo pair B 0.133 -> 0.024, R 0.028 -> "
           "0.026; 27 `bench pairs` pairs B 0.0676 -> 0.0677, R 0.0202 -> 0.0290 (hence opt-in)";
  return r;
}

SummaryRow multiFrameRow(const std::vector<PairMeasurement>& pairs) {
  int confirmed = 0, unconfirmed = 0;  // two blobs from noisy, and from g_truth too / g_truth gave no kernel
  for (const auto& p : pairs) {
    if (!p.kernel.multimodal()) continue;
    if (!p.truth_kernel) ++unconfirmed;
    else confirmed += p.truth_kernel->multimodal();
  }
  SummaryRow r;
  r.assumption = "the long shot is one exposure blurred by one continuous camera path (Eq. 4, one K)";
  auto shape = [](const KernelShape& k) {
    return std::to_string(k.components) + " / " + fmt(k.largest_mass, 2) + " / " + fmt(k.rms_radius, 2) + " px / " +
           fmt(k.elongation, 2);
  };
  r.misfit = "kernel components / largest component's mass / RMS radius / elongation, noisy -> blurred "
             "[g_truth -> blurred]: " + join(pairs, [&](const PairMeasurement& p) {
               return shape(p.kernel) + " [" + (p.truth_kernel ? shape(*p.truth_kernel) : "none: " + p.truth_kernel_failure) + "]";
             });
  r.cause = "several stabilised frames (separate blobs, from both sharp shots): " +
            verdictOn(confirmed, pairs.size(), "not supported") + (unconfirmed ? ", unconfirmed on " + std::to_string(unconfirmed) +
                                                              " (two blobs from noisy, no kernel from g_truth)" : std::string()) +
            "; kernels of 1-2 px cannot show gaps between blobs at this resolution";
  r.extended = "none";
  r.gain = "-";
  return r;
}

// The noise estimate below one 8-bit level at full resolution and above it at half resolution, while at least this
// share of the sharp shot's black pixels lie outside black regions (their 5×5 median is not black): its noise reaches
// black where the full-resolution σ̂ says it does not.
constexpr double kIsolatedBlackShare = 0.10;

SummaryRow blackEndRow(const std::vector<PairMeasurement>& pairs) {
  int supported = 0;
  std::vector<std::vector<double>> per_pixel, median;
  std::vector<std::pair<double, double>> ranges;
  std::string vs;
  for (const auto& p : pairs) {
    supported += p.noise_sigma_full * 255 <= 1.0 && p.noise_sigma_half * 255 > 1.0 &&
                 p.isolated_black_share >= kIsolatedBlackShare;
    per_pixel.push_back(greenOf(p.black_per_pixel));
    median.push_back(greenOf(p.evidence));
    ranges.push_back(greenRange(p.black_per_pixel));
    ranges.push_back(greenRange(p.evidence));
    const auto common = commonRange({greenRange(p.black_per_pixel), greenRange(p.evidence), p.bracket_range.at("G")});
    vs += (vs.empty() ? "" : "; ") + p.id + ": " + fmt(curveShapeSpread({greenOf(p.black_per_pixel), p.bracket_curve.at("G")}, common), 3) +
          " -> " + fmt(curveShapeSpread({greenOf(p.evidence), p.bracket_curve.at("G")}, common), 3);
  }
  const auto common = commonRange(ranges);
  SummaryRow r;
  r.assumption = "the noise estimate of the sharp shot tells whether its noise reaches black (below one level, every "
                 "black pixel is taken as clipped signal and its kernel support dropped)";
  r.misfit = "G noise estimate of noisy at full / half resolution [levels], its black pixels, the share of them outside "
             "black regions (5x5 median not black): " + join(pairs, [](const PairMeasurement& p) {
               return fmt(p.noise_sigma_full * 255, 2) + " / " + fmt(p.noise_sigma_half * 255, 2) + ", " +
                      std::to_string(p.black_pixels) + ", " + fmt(100 * p.isolated_black_share, 1) + " %";
             });
  r.cause = "noise that reaches black under a noise estimate that a JPEG's quantisation lowered (the dark side of the "
            "edges dropped): " + verdictOn(supported, pairs.size(), "not supported") + " (estimate <= 1 level at full resolution, "
            "> 1 at half, and >= " + fmt(100 * kIsolatedBlackShare, 0) + " % of the black pixels outside black regions)";
  r.extended = "decision rule: whether the noise reaches black also read at half resolution, where a JPEG leaves it; "
               "then black censored only where the sharp shot's 5x5 median is black (calib/src/crf_preparation.cpp, the "
               "default; `bench pairs --black-end per-pixel` is the rule before)";
  r.gain = "pair G vs its bracket in shape, per-pixel -> median: " + vs + "; the pairs' G shape spread over x " + range(common) +
           ": " + fmt(curveShapeSpread(per_pixel, common), 3) + " -> " + fmt(curveShapeSpread(median, common), 3) +
           ". Semi-real (`crfcal bench pairs --ratio 4|8 [--black-end per-pixel]`, RESULTS 'black end'): r within 5 % "
           "23 -> 27 / 21 -> 24 of 27; r = 1, 2 identical";
  return r;
}

void detailRows(const PairMeasurement& p, StudyTable& table) {
  auto row = [&](const std::string& cause, const std::string& quantity, const std::string& value, const std::string& note) {
    table.rows.push_back({p.id, cause, quantity, value, note});
  };
  row("a", "r EXIF / images / evidence", fmt(p.exif_ratio, 3) + " / " + fmt(imagesRatio(p.images), 3) + " / " +
      fmt(p.evidence.fits.at("G").ratio, 3), std::string("decision ") + toString(p.evidence.ratio_evidence.decision) +
      (p.images.ratio_fixed_by_small_blur ? ", held by the small-blur rule" : ""));
  row("a", "brightness ratio (g0)", fmt(p.brightness_ratio, 3), "quantile matching noisy -> blurred, G");
  row("a", "ambiguity rise images / evidence", fmt(p.images.fits.at("G").ambiguity_rise, 4) + " / " +
      fmt(p.evidence.fits.at("G").ambiguity_rise, 4), "relative rise of the G data energy at gamma 1 +- 0.1");
  row("a", "G covered range images / evidence / bracket", range(greenRange(p.images)) + " / " +
      range(greenRange(p.evidence)) + " / " + range(p.bracket_range.at("G")), "");
  row("b", "noise ratio noisy / g_truth per level", [&] {
        std::string s;
        for (std::size_t i = 0; i < p.noise.ratio.size(); ++i)
          s += (i ? " " : "") + fmt(p.noise.bins[i].intensity, 2) + ":" + fmt(p.noise.ratio[i], 2);
        return s;
      }(), "level:ratio");
  row("b", "edge width noisy / imitation / g_truth / blurred", fmt(p.edge_noisy.width, 2) + " / " +
      fmt(p.edge_control.width, 2) + " / " + fmt(p.edge_truth.width, 2) + " / " + fmt(p.edge_blurred.width, 2),
      std::to_string(p.edge_noisy.edges) + " / " + std::to_string(p.edge_control.edges) + " / " +
      std::to_string(p.edge_truth.edges) + " / " + std::to_string(p.edge_blurred.edges) + " edges");
  row("c", "noisy -> blurred through bracket phi_G / EXIF", fmt(p.bracket_phi_ratio, 3) + " / " + fmt(p.exif_ratio, 3), "");
  row("c", "noisy -> g_truth through bracket phi_G / EXIF", fmt(p.bracket_self_ratio, 3) + " / " + fmt(bracketExifRatio(p), 3),
      "in-sample control");
  row("d", "overshoot / undershoot noisy", fmt(p.edge_noisy.overshoot, 3) + " / " + fmt(p.edge_noisy.undershoot, 3), "");
  row("d", "overshoot / undershoot g_truth", fmt(p.edge_truth.overshoot, 3) + " / " + fmt(p.edge_truth.undershoot, 3), "");
  row("d", "overshoot / undershoot blurred", fmt(p.edge_blurred.overshoot, 3) + " / " + fmt(p.edge_blurred.undershoot, 3), "");
  std::string verdicts;
  for (const auto& [c, v] : p.evidence.verdicts) verdicts += (verdicts.empty() ? "" : " ") + c + ":" + toString(v.level);
  row("e", "chroma noisy / blurred / g_truth", p.noisy.chroma + " / " + p.blurred.chroma + " / " + p.truth.chroma, verdicts);
  for (const auto& [name, k] : {std::pair<std::string, const KernelShape*>{"noisy -> blurred", &p.kernel},
                                {"g_truth -> blurred", p.truth_kernel ? &*p.truth_kernel : nullptr}})
    if (!k) row("f", "kernel " + name, "none", p.truth_kernel_failure);
    else row("f", "kernel " + name + ": components / largest mass / support", std::to_string(k->components) + " / " +
        fmt(k->largest_mass, 2) + " / " + std::to_string(k->support), "RMS radius " + fmt(k->rms_radius, 2) +
        " px, elongation " + fmt(k->elongation, 2));
  row("g", "G noise estimate of noisy, full / half resolution [levels]", fmt(p.noise_sigma_full * 255, 3) + " / " +
      fmt(p.noise_sigma_half * 255, 3), "full below 1: taken as clean before stop 37");
  row("g", "G black pixels of noisy / share outside black regions", std::to_string(p.black_pixels) + " / " +
      fmt(100 * p.isolated_black_share, 1) + " %", "5x5 median not black");
  row("g", "G pixels used per-pixel / median black test", std::to_string(p.black_per_pixel.fits.at("G").pixels.used) + " / " +
      std::to_string(p.evidence.fits.at("G").pixels.used), "each with its own kernel rounds");
}

nlohmann::json kernelJson(const KernelShape& k) {
  return {{"components", k.components}, {"largest_mass", k.largest_mass}, {"rms_radius", k.rms_radius},
          {"elongation", k.elongation}, {"support", k.support}};
}

nlohmann::json pairJson(const PairMeasurement& p) {
  return {{"exif_ratio", p.exif_ratio},
          {"images_ratio", imagesRatio(p.images)},
          {"evidence_ratio", p.evidence.fits.at("G").ratio},
          {"brightness_ratio", p.brightness_ratio},
          {"bracket_phi_ratio", p.bracket_phi_ratio},
          {"bracket_self_ratio", p.bracket_self_ratio},
          {"bracket_exif_ratio", bracketExifRatio(p)},
          {"ambiguity_rise", {{"images", p.images.fits.at("G").ambiguity_rise}, {"evidence", p.evidence.fits.at("G").ambiguity_rise}}},
          {"blur_radius", p.images.blur_radius},
          {"noise_ratio_median", p.noise.median_ratio},
          {"noise_ratio", p.noise.ratio},
          {"edge_width", {{"noisy", p.edge_noisy.width}, {"imitation", p.edge_control.width}, {"g_truth", p.edge_truth.width}, {"blurred", p.edge_blurred.width}}},
          {"edge_halo", {{"noisy", p.edge_noisy.halo()}, {"g_truth", p.edge_truth.halo()}, {"blurred", p.edge_blurred.halo()}}},
          {"chroma", {{"noisy", p.noisy.chroma}, {"blurred", p.blurred.chroma}, {"g_truth", p.truth.chroma}}},
          {"bracket_phi_spread", p.bracket_phi_spread},
          {"bracket_self_spread", p.bracket_self_spread},
          {"edge_width_smoothed_imitation", p.edge_control_smoothed.width},
          {"kernel", kernelJson(p.kernel)},
          {"black_end", {{"noise_sigma_levels", p.noise_sigma_full * 255},
                         {"noise_sigma_half_resolution_levels", p.noise_sigma_half * 255},
                         {"pixels_used_per_pixel", p.black_per_pixel.fits.at("G").pixels.used},
                         {"pixels_used_median", p.evidence.fits.at("G").pixels.used},
                         {"black_pixels", p.black_pixels}, {"isolated_black_share", p.isolated_black_share}}},
          {"kernel_g_truth", p.truth_kernel ? kernelJson(*p.truth_kernel) : nlohmann::json(p.truth_kernel_failure)}};
}

}  // namespace

int runPairs(const StudyArgs& args) {
  const fs::path root = requireData(args, "pairs/vivo_x6s");
  const fs::path dir = root / "pairs" / "vivo_x6s";
  io::OutputDirectory out(args.output, {"study pairs", {dir}, args.force});  // refused or unwritable: fails now
  std::map<std::string, io::ExifCsvRow> exif;
  for (const auto& row : io::readExifCsv(dir / "exif.csv")) exif[row.file] = row;
  Progress progress(args.quiet);
  std::vector<PairMeasurement> pairs;
  for (int n = 1; n <= 9; ++n) {
    const std::string id = std::to_string(n);
    if (!fs::exists(dir / ("noisy_" + id + ".jpg"))) continue;
    progress.stage("pair " + id);
    pairs.push_back(measurePair(dir, id, exif, progress));
    progress.done();
  }
  if (pairs.size() < 2) throw Error("fewer than two noisy_N / blurred_N / g_truth_N pairs", dir.string());
  StudyTable table;
  table.study = "pairs";
  table.header = {"pair", "row", "quantity", "value", "note"};
  const ShapeSpreads spreads = shapeSpreads(pairs);
  table.summary = {ambiguityRow(pairs, spreads), noiseRow(pairs), toneRow(pairs, spreads),
                   haloRow(pairs),         chromaRow(pairs), multiFrameRow(pairs), blackEndRow(pairs)};
  for (const auto& p : pairs) {
    detailRows(p, table);
    table.extra["pairs"][p.id] = pairJson(p);
  }
  table.extra["shape_spread"] = {{"range", {spreads.pairs_range.first, spreads.pairs_range.second}},
                                 {"images", spreads.pairs_images}, {"evidence", spreads.pairs_evidence},
                                 {"brackets", spreads.brackets},
                                 {"brackets_range", {spreads.brackets_range.first, spreads.brackets_range.second}},
                                 {"pair_vs_bracket_images", spreads.vs_bracket_images},
                                 {"pair_vs_bracket_evidence", spreads.vs_bracket_evidence}};
  emit(table, out);
  out.commit();
  std::printf("wrote %s/{table.csv, details.csv, table.json}\n", args.output.c_str());
  return kExitOk;
}

}  // namespace crfcal::app::study
