#include "bench_pairs_args.hpp"

#include "command.hpp"
#include "option_checks.hpp"

namespace crfcal::app {
namespace {

// What the semi-real pairs are made of: photos, curves, kernels, r, the handheld motion, noise and JPEG.
void addSimulationOptions(CLI::App& command, const std::shared_ptr<PairsArgs>& args) {
  command.add_option("--image", args->images, "Real photo(s) to make pairs from (default: three photos of --data)")
      ->check(CLI::ExistingFile);
  command.add_option("--data", args->data,
                     "The shared data directory (default: $CRFCAL_SHARED_DATA or ../shared/data)");
  command.add_option("--crf", args->crfs,
                     "True inverse response(s) phi (spec; default: measured curves of three cameras in "
                     "samples/camera_curves)");
  command.add_option("--kernel", args->kernels, "True kernel(s): levin:N | levin:N@S (scaled by S) | box:L | FILE")
      ->capture_default_str();
  command.add_option("--ratio", args->ratios,
                     "True exposure ratio(s) r (r > 2: the real regime unless --regime says otherwise)")
      ->capture_default_str()
      ->check(exposureRatioOption(false));
  command.add_option("--exif-error", args->exif_error, "Relative error of the EXIF ratio against the truth")
      ->capture_default_str();
  command.add_option("--shift", args->shift, "Handheld shift magnitude, pixels (direction varies per case)")
      ->capture_default_str();
  command.add_option("--rotation", args->rotation, "Handheld rotation, degrees (sign alternates per case)")
      ->capture_default_str();
  command.add_option("--quality", args->quality, "JPEG quality")->capture_default_str()->check(CLI::Range(50, 100));
  command.add_option("--sharp-quality", args->sharp_quality,
                     "JPEG quality of the sharp shot alone (0: --quality), to change one part of the simulation at "
                     "a time")
      ->capture_default_str()
      ->check(CLI::Range(0, 100));
  command.add_option("--sharp-noise-scale", args->sharp_noise_scale,
                     "Real regime: factor on the sharp shot's noise variance (0: noise-free; 1: its ISO's measured "
                     "noise)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_option("--jpeg-sampling", args->jpeg_sampling,
                     "Chroma sampling of both JPEG shots: 4:2:0 (OpenCV's writer, as cameras), 4:2:2 (many "
                     "DSLRs) or 4:4:4 (libjpeg)")
      ->capture_default_str()
      ->check(CLI::IsMember({"4:2:0", "4:2:2", "4:4:4"}));
  command.add_option("--max-side", args->max_side, "Downscale the photo to this longest side")->capture_default_str();
  command.add_option("--warp-domain", args->warp_domain,
                     "Where the blurred frame's handheld motion is applied: intensity (its 8-bit values after the "
                     "response and clip, bilinear: the record) or irradiance (before the noise and the response: "
                     "the hand moves before the sensor; docs/RESULTS.md#blurred-rim)")
      ->capture_default_str()
      ->check(CLI::IsMember({"intensity", "irradiance"}));
  command.add_option("--regime", args->regime,
                     "Exposure regime: sharp-normal (the sharp shot normally exposed, the blurred one r x brighter, "
                     "generic noise: the r = 1, 2 benches), real (the blurred shot normally exposed at "
                     "--blurred-iso, the sharp one underexposed by r at ISO r x that, each with --noise-camera's "
                     "measured noise; adds the shape-RMSE columns and a per-r summary), auto (real for r > 2)")
      ->capture_default_str()
      ->check(CLI::IsMember({"auto", "sharp-normal", "real"}));
  command.add_option("--noise-camera", args->noise_camera,
                     "Real regime: camera whose measured raw noise (darktable profile) the shots get, \"maker "
                     "model\" (default: darktable's only phone, as real pairs are phone pairs)")
      ->capture_default_str();
  command.add_option("--noise-profiles", args->noise_profiles,
                     "Real regime: darktable noiseprofiles.json (default: --data's noise_profiles/noiseprofiles.json, "
                     "else the bundled excerpt samples/noise_profiles/)")
      ->check(CLI::ExistingFile);
  command.add_option("--blurred-iso", args->blurred_iso,
                     "Real regime: ISO of the blurred shot; the sharp shot gets this x r (default 0: the noise "
                     "camera's lowest profiled ISO)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
}

// How each pair is calibrated: the options of calibrate, and the ablations and oracles of the bench.
void addCalibrationOptions(CLI::App& command, const std::shared_ptr<PairsArgs>& args) {
  command.add_option("--chroma-model", args->chroma_model, "check, auto or off, as calibrate --chroma-model")
      ->capture_default_str()
      ->check(chromaModelNames());
  command.add_option("--kernel-size", args->kernel_size,
                     "Kernel size for estimation (odd); an estimate that reaches it grows 1.5x, up to "
                     "--max-kernel-size")
      ->capture_default_str()
      ->check(CLI::Range(3, 151) & oddNumber());
  command.add_option("--max-kernel-size", args->max_kernel_size,
                     "Largest size the kernel may grow to, odd, at least --kernel-size (0: a quarter of the "
                     "sharp shot's shorter side, at most 79; = --kernel-size: no growth)")
      ->capture_default_str()
      ->check(CLI::Range(0, 151));
  command.add_option("--channels", args->channels, "g or rgb")
      ->capture_default_str()
      ->check(CLI::IsMember({"g", "rgb"}));
  command.add_option("--noise-handling", args->noise_handling,
                     "The sharp shot's noise in the fit: jensen, none, debias, denoise")
      ->capture_default_str()
      ->check(CLI::IsMember({"jensen", "none", "debias", "denoise"}));
  command.add_flag("--fix-ratio", args->fix_ratio,
                   "Keep r at the (deliberately off) EXIF value, as calibrate --fix-ratio");
  command.add_option("--learned-prior-weight", args->learned_prior_weight,
                     "--shoulder learned: weight of the learned prior's rows")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_option("--shoulder", args->shoulder,
                     "Extrapolation above the data: rising-free, mean-camera or learned (a prior learned from the "
                     "samples/camera_curves cameras except each case's own: leave one camera out)")
      ->capture_default_str()
      ->check(CLI::IsMember({"rising-free", "mean-camera", "learned"}));
  command.add_option("--black-end", args->black_end,
                     "Black pixels of the sharp shot censored: median (every one of a clean shot, only black regions "
                     "where its noise reaches black at full or half resolution: the default) or per-pixel (the noise "
                     "read at full resolution only: the rule before stop 37; docs/RESULTS.md#black-end)")
      ->capture_default_str()
      ->check(CLI::IsMember({"median", "per-pixel"}));
  command.add_flag("--noise-oracle", args->noise_oracle,
                   "Real regime: give the fit the sharp shot's true noise per level (an oracle: what a noise "
                   "estimate would have to deliver; with --noise-handling debias, docs/RESULTS.md#stop-38-leads)");
  command.add_flag("--always-fit-ratio", args->always_fit_ratio,
                   "Fit r even when a sub-pixel blur leaves it undetermined, as calibrate --always-fit-ratio");
  command.add_option("--ratio-evidence", args->ratio_evidence,
                     "on: the images' r combined with EXIF by their precisions (as calibrate); off: the images alone")
      ->capture_default_str()
      ->check(CLI::IsMember({"on", "off"}));
  command.add_option("--ratio-prior", args->ratio_prior,
                     "Sigma of the EXIF prior on log r (0: r from the images alone)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_option("--censored-weight", args->censored_weight,
                     "Weight of the blurred shot's clipped pixels as censored observations of the fit (where B "
                     "clips, r (phi(I) (x) K) >= phi(1); 1: as data, 0: excluded as in the seed)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_option("--model", args->model, "Model of phi, as calibrate --model: ggcm, emor or auto")
      ->capture_default_str()
      ->check(crfModelNames());
  command.add_option("--emor-terms", args->emor_terms, "EMoR basis curves of the fit, as calibrate --emor-terms")
      ->capture_default_str()
      ->check(CLI::Range(1, 25));
  command.add_option("--irradiance-kernel-lambda", args->irradiance_kernel_lambda,
                     "Sparsity weight of the irradiance-domain kernel rounds, as calibrate")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  command.add_flag("--unweighted-irradiance-kernel", args->unweighted_irradiance_kernel,
                   "Irradiance-domain kernel rounds without the 1/phi'(B) weights, as calibrate (ablation)");
}

// The band of phi (calibrate --band-replicates) and its terms.
void addBandOptions(CLI::App& command, const std::shared_ptr<PairsArgs>& args) {
  command.add_option("--band-replicates", args->band_replicates,
                     "Half-sample refits of the band of phi (even; 0: no band, no band table), as calibrate")
      ->capture_default_str()
      ->check(bandReplicates());
  command.add_option("--band-replicate-ratio", args->band_replicate_ratio,
                     "r of the band's refits when r came from the evidence: combined (each half combines its own "
                     "r with EXIF as the pair did) or own (each half keeps its images' r)")
      ->capture_default_str()
      ->check(CLI::IsMember({"combined", "own"}));
  command.add_option("--band-ratio-term", args->band_ratio_term,
                     "The band's ratio term: the error of r every half-sample shares, scaled by how well the "
                     "images' r and EXIF agree, through fits at r held a sigma away (on) or none (off)")
      ->capture_default_str()
      ->check(CLI::IsMember({"on", "off"}));
  command.add_option("--band-ratio-sigma", args->band_ratio_sigma,
                     "sigma of log r in the band's ratio term: birge (the a-priori sigma scaled by the images' "
                     "and EXIF's agreement) or disagreement (EXIF's stated sigma believed, the images' sigma "
                     "estimated from their distance to EXIF) or disagreement-shift (that rule's expected error "
                     "of r alone)")
      ->capture_default_str()
      ->check(CLI::IsMember({"birge", "disagreement", "disagreement-shift"}));
  command.add_option("--band-above", args->band_above,
                     "The band above the covered range: the quantiles of the prior learned from the bundled camera "
                     "curves without the case's camera (learned) or the exponent bounds (bounds)")
      ->capture_default_str()
      ->check(CLI::IsMember({"bounds", "learned"}));
  command.add_option("--band-offset-term", args->band_offset_term,
                     "The band's offset term at r = 1: the offset a + b*phi that Eq. 4 leaves free there, bounded "
                     "by phi at the bottom of the covered range (on) or none (off)")
      ->capture_default_str()
      ->check(CLI::IsMember({"on", "off"}));
  command.add_option("--band-prior-term", args->band_prior_term,
                     "The band's prior term: phi's difference to a refit without the extrapolation priors, which "
                     "every half-sample shares (on) or none (off)")
      ->capture_default_str()
      ->check(CLI::IsMember({"on", "off"}));
}

// What is written, and where.
void addOutputOptions(CLI::App& command, const std::shared_ptr<PairsArgs>& args) {
  command.add_flag("--pairs-only", args->pairs_only, "Only write the pairs (no calibration)");
  command.add_option("-o,--output", args->output, "Output directory")->required();
  command.add_flag("--force", args->force, kForceHelp);
}

}  // namespace

void addPairsOptions(CLI::App& command, const std::shared_ptr<PairsArgs>& args) {
  addSimulationOptions(command, args);
  addCalibrationOptions(command, args);
  addBandOptions(command, args);
  addOutputOptions(command, args);
}

}  // namespace crfcal::app
