#pragma once
// Readers for the measured reference data of ../shared/data used by `crfcal study`:
//   * Middlebury RAW-vs-JPEG ColorChecker charts (middlebury/<Camera>/wb1i{1,2}e{1..4}-{jpg,raw}.png),
//   * darktable's noise profiles (noise_profiles/noiseprofiles.json: variance = a·x + b per channel),
//   * exiftool dumps (exif.csv) of the brackets and phone pairs,
//   * small NumPy .npy arrays (the Debevec response fixture).
// Every error names the file.
#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/colour_mixing.hpp"

namespace crfcal::io {

// The shared data directory: `given` if non-empty, else $CRFCAL_SHARED_DATA, else ../shared/data (relative to the
// working directory). Returns the path whether or not it exists.
std::filesystem::path defaultSharedData(const std::string& given = {});

// ---- Middlebury -----------------------------------------------------------------------------------------------
struct MiddleburyPatchOptions {
  int inner = 41;            // side of the central square sampled in each 65×65 patch (avoids the patch borders)
  double raw_clip = 250.0;   // a sample whose RAW median (any channel) is ≥ this (8-bit) is dropped as clipped
};

struct MiddleburyCamera {
  std::string name;
  // Patch medians in [0, 1]; group = scene (1 or 2), one sample per (exposure, patch) with unclipped RAW.
  std::vector<ColourSample> samples;
  int dropped_clipped = 0;
};

// Reads every camera folder of `root` (sorted). Throws crfcal::Error naming the folder or file.
std::vector<MiddleburyCamera> readMiddleburyPatches(const std::filesystem::path& root,
                                                    const MiddleburyPatchOptions& options = {});

// ---- darktable noise profiles ---------------------------------------------------------------------------------
struct DarktableNoiseProfile {
  std::string maker, model, name;
  double iso = 0;
  std::array<double, 3> a{}, b{};  // variance(x) = a·x + b, x raw in [0, 1] (R, G, B)
};
std::vector<DarktableNoiseProfile> readNoiseProfiles(const std::filesystem::path& json_path);
// The profile of a camera (model name contains `model`, case-insensitive) with the ISO closest to `iso`.
std::optional<DarktableNoiseProfile> findNoiseProfile(const std::vector<DarktableNoiseProfile>& profiles,
                                                      const std::string& model, double iso);

// ---- exif.csv (exiftool dump) ---------------------------------------------------------------------------------
struct ExifCsvRow {
  std::string file, make, model;
  double iso = 0;
  double exposure_time = 0;   // seconds ("1/8" parsed)
  std::string exposure_text;  // as written ("1/60")
  double f_number = 0;
  int width = 0, height = 0;
};
std::vector<ExifCsvRow> readExifCsv(const std::filesystem::path& path);

// ---- NumPy --------------------------------------------------------------------------------------------------------
// A little-endian float64 (or float32) C-order 1-D or 2-D .npy array as CV_64F (1-D: one column). Throws on other
// dtypes / Fortran order.
cv::Mat readNpy(const std::filesystem::path& path);

}  // namespace crfcal::io
