#pragma once
// The arguments of `crfcal bench pairs` (cmd_bench_pairs.cpp) and their command-line options: what the semi-real
// pairs are made of, how each is calibrated (calibrate's options and the bench's ablations), the band, the output.
#include <memory>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "crfcal/handheld_simulation.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal::app {

struct PairsArgs {
  std::vector<std::string> images;
  std::string data;  // ../shared/data (or CRFCAL_SHARED_DATA): default photos when no --image is given
  std::vector<std::string> crfs;
  std::vector<std::string> kernels{"levin:1", "levin:3", "levin:8"};
  std::vector<double> ratios{1.0};
  std::string output;
  double exif_error = 0.04;  // EXIF ratio = truth × (1 + this): camera hardware imprecision (Sec. 4)
  double shift = 4.3;
  double rotation = 0.4;
  int quality = 95;
  // One part of the simulation changed at a time (docs/RESULTS.md#black-end): the sharp shot's own JPEG quality (0:
  // --quality) and, in the real regime, a factor on its noise variance (0: noise-free).
  int sharp_quality = 0;
  double sharp_noise_scale = 1;
  std::string jpeg_sampling = "4:2:0";
  std::string chroma_model = "check";  // as calibrate --chroma-model
  int max_side = 800;
  int kernel_size = 35;
  int max_kernel_size = PairCalibrationOptions{}.max_kernel_size;  // 0: automatic (PairCalibrationOptions)
  std::string channels = "g";
  double ratio_prior = PairCalibrationOptions{}.fit.ratio_prior_sigma;
  double censored_weight = PairCalibrationOptions{}.fit.censored_weight;  // B's clipped pixels, censored
  std::string model = "auto";                                   // as calibrate --model
  int emor_terms = PairCalibrationOptions{}.fit.emor_terms;     // as calibrate --emor-terms
  std::string noise_handling = toString(PairCalibrationOptions{}.fit.experimental.noise);
  bool fix_ratio = false;
  bool always_fit_ratio = false;
  std::string ratio_evidence = PairCalibrationOptions{}.ratio_evidence.enabled ? "on" : "off";
  double irradiance_kernel_lambda = PairCalibrationOptions{}.irradiance_kernel_lambda;
  bool unweighted_irradiance_kernel = false;
  std::string shoulder =
      PairCalibrationOptions{}.fit.experimental.shoulder_follows_emor_mean ? "mean-camera" : "rising-free";
  double learned_prior_weight = PairCalibrationOptions{}.fit.learned_prior_weight;  // --shoulder learned
  std::string black_end = PairCalibrationOptions{}.fit.experimental.black_per_pixel_when_clean ? "per-pixel" : "median";
  bool noise_oracle = false;  // real regime: the fit is given the sharp shot's true noise per level (an oracle)
  std::string warp_domain = HandheldPairOptions{}.warp_irradiance ? "irradiance" : "intensity";  // the blurred frame's
  bool pairs_only = false;
  int band_replicates = PairCalibrationOptions{}.band.replicates;  // 0: no band (and no band table)
  // r of the band's refits when r came from the evidence: "combined" (each half combines its r with EXIF, the
  // default) or "own" (each half keeps its images' r, as before; CurveBandOptions::replicates_combine_ratio).
  std::string band_replicate_ratio = PairCalibrationOptions{}.band.replicates_combine_ratio ? "combined" : "own";
  // The band's ratio term (band_ratio_term.hpp; CurveBandOptions::include_ratio_term): "on" or "off".
  std::string band_ratio_term = PairCalibrationOptions{}.band.include_ratio_term ? "on" : "off";
  // The band's prior term (CurveBandOptions::include_prior_term): "on" or "off".
  std::string band_prior_term = PairCalibrationOptions{}.band.include_prior_term ? "on" : "off";
  // The band's offset term at r = 1 (CurveBandOptions::include_offset_term): "on" or "off".
  std::string band_offset_term = PairCalibrationOptions{}.band.include_offset_term ? "on" : "off";
  // The band above the data (CurveBandOptions::above_data_prior): "learned" (the learned prior's quantiles, as
  // `calibrate` uses it, here leave-one-camera-out like --shoulder learned) or "bounds" (the exponent bounds).
  std::string band_above = "learned";
  // σ of the ratio term (CurveBandOptions::ratio_term_sigma): "birge" or "disagreement".
  std::string band_ratio_sigma = "birge";  // or "disagreement", "disagreement-shift" (RatioTermSigma)
  bool force = false;  // write into an output directory holding other files (never deletes them)
  std::string regime = "auto";  // auto | sharp-normal | real (cmd_bench_pairs.cpp's top comment); auto: real for r > 2
  std::string noise_camera = "LGE Nexus 5";  // real regime: darktable's only phone (real pairs are phone pairs)
  std::string noise_profiles;   // darktable noise-profile file (default: io::defaultNoiseProfiles(data))
  double blurred_iso = 0;       // real regime: ISO of the blurred shot (0: the noise camera's lowest profiled ISO);
                                // the sharp shot gets blurred_iso · r
};

// Registers every option of `bench pairs` on `command`, bound to `args`, in four groups (bench_pairs_args.cpp).
void addPairsOptions(CLI::App& command, const std::shared_ptr<PairsArgs>& args);

}  // namespace crfcal::app
