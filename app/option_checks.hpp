#pragma once
// Command-line checks shared by several commands (CLI11 validators): a value outside them is a command-line error,
// exit 2 with the valid range, before anything is read or computed.
#include <cmath>
#include <string>

#include <CLI/CLI.hpp>

#include "crfcal/crf_fitter.hpp"
#include "crfcal/error.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal::app {

// --threads: far above any machine crfcal runs on, and below what TBB's allocator survives (100000 threads
// crashed it after the outputs were written).
inline constexpr int kMaxThreads = 256;

// Exposure ratios r = Δt_B/Δt_I: 1/1000 .. 1000 (ten stops either way and more). Beyond, the blurred shot is
// clipped or black wherever the sharp one has data, and the fit's energies overflow (r = 1e9 gave 1e17).
inline constexpr double kMinExposureRatio = 1e-3, kMaxExposureRatio = 1e3;

inline bool isExposureRatio(double r) { return std::isfinite(r) && r >= kMinExposureRatio && r <= kMaxExposureRatio; }

// r in [1/1000, 1000]; with `zero_means_exif`, also 0 (the default: r from the EXIF).
inline CLI::Validator exposureRatioOption(bool zero_means_exif = true) {
  return CLI::Validator(
      [zero_means_exif](std::string& text) -> std::string {
        double r = 0;
        if (!CLI::detail::lexical_cast(text, r)) return "'" + text + "' is not a number";
        if ((zero_means_exif && r == 0) || isExposureRatio(r)) return {};
        return "exposure ratio " + text + " is outside 0.001 .. 1000" +
               std::string(zero_means_exif ? " (or 0: from EXIF)" : "");
      },
      zero_means_exif ? "0|0.001..1000" : "0.001..1000");
}

// --max-kernel-size against --kernel-size (PairCalibrationOptions::max_kernel_size): 0 (automatic), or odd and at
// least the size the estimate starts at. Throws Error (subject: options) naming both flags.
inline void checkKernelSizes(int kernel_size, int max_kernel_size) {
  if (max_kernel_size != 0 && (max_kernel_size % 2 == 0 || max_kernel_size < kernel_size))
    throw Error("--max-kernel-size " + std::to_string(max_kernel_size) + " must be 0 (automatic) or odd and at "
                "least --kernel-size (" + std::to_string(kernel_size) + ")", ErrorSubject::options);
}

// --model: the model of φ by its name (toString(CrfModelChoice)).
inline CLI::IsMember crfModelNames() { return CLI::IsMember({"ggcm", "emor", "auto"}); }
inline CrfModelChoice crfModelFromName(const std::string& name) {
  for (const CrfModelChoice c : {CrfModelChoice::ggcm, CrfModelChoice::emor, CrfModelChoice::automatic})
    if (name == toString(c)) return c;
  throw CLI::ValidationError("--model", "'" + name + "' is not ggcm, emor or auto");  // crfModelNames() refused it
}

// --chroma-model, for a sharp JPEG whose chroma is subsampled (docs/RESULTS.md#chroma-replace):
//   check (default): the pointwise model; the chroma check replaces an R or B fit the lost chroma biased
//   auto: R and B fitted both ways in every round, the chroma model kept where its fit lies above (ChromaModelChoice)
//   off: the pointwise model everywhere; the check only informs the verdict
inline CLI::IsMember chromaModelNames() { return CLI::IsMember({"check", "auto", "off"}); }
// Sets `options` for --chroma-model `name`; options.sharp_stored_chroma must already hold the sharp file's sampling.
inline void applyChromaModel(const std::string& name, PairCalibrationOptions& options) {
  if (name == "auto") options.sharp_chroma = options.sharp_stored_chroma;
  options.replace_chroma_biased_fits = name != "off";
}

// Refits of a band of φ (curve_band.hpp, scaled_fit_band.hpp): 0 (no band) to 200, even (they come in complementary
// halves). Every command with --band-replicates checks it this way; CurveBandOptions::check would refuse the same
// values later, after the images were read.
inline CLI::Validator bandReplicates() {
  return CLI::Range(0, 200) & CLI::Validator(
                                  [](std::string& text) -> std::string {
                                    int n = 0;
                                    if (!CLI::detail::lexical_cast(text, n)) return "'" + text + "' is not an integer";
                                    return n % 2 ? std::string("must be even") : std::string();
                                  },
                                  "EVEN");
}

// An odd integer (kernel sizes: the kernel has a centre pixel).
inline CLI::Validator oddNumber() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        long long n = 0;
        if (!CLI::detail::lexical_cast(text, n)) return "'" + text + "' is not an integer";
        return n % 2 != 0 ? std::string() : "must be odd (got " + text + ")";
      },
      "ODD");
}

}  // namespace crfcal::app
