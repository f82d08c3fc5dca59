#pragma once
// darktable's measured camera noise profiles (noiseprofiles.json: ../shared/data/noise_profiles, and a bundled
// excerpt in samples/noise_profiles):
//   {"version": 0, "noiseprofiles": [{"maker": .., "models": [{"model": .., "comment": ..,
//     "profiles": [{"name": .., "iso": .., "a": [r, g, b], "b": [r, g, b], "skip"?: true}, ..]}]}]}
// variance(x) = a·x + b per raw channel for x ∈ [0, 1] (sensor_noise.hpp). As in darktable, profiles marked
// "skip" (superseded measurements) are ignored; repeated measurements of one ISO are averaged. Every error names
// the file.
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "crfcal/sensor_noise.hpp"

namespace crfcal::io {

struct CameraNoiseProfile {
  std::string maker, model;                            // as in the file
  std::vector<std::pair<double, SensorNoise>> by_iso;  // one per measured ISO, ISO ascending
  std::string source;                                  // the file read

  std::string camera() const;  // "maker model" (the model alone when it already starts with the maker)
  double minIso() const;
  double maxIso() const;
  // The noise at `iso`: linear in ISO between the two nearest measured ISOs (a, the shot-noise term, grows about
  // linearly with the gain). Throws InvalidInput naming the file outside [minIso, maxIso] (no extrapolation).
  SensorNoise atIso(double iso) const;
  std::string summary() const;  // "LGE Nexus 5: ISO 100–3200 (6 ISOs), from FILE"
};

// The profile of `camera` in `json_path`: "maker model" ("Canon EOS 5D Mark II") or the model alone
// ("EOS 5D Mark II"), case-insensitive, spaces collapsed. Throws crfcal::Error naming the file: cannot open,
// invalid JSON, unexpected layout, camera absent (with the names that contain the request's words) or ambiguous.
CameraNoiseProfile readCameraNoiseProfile(const std::filesystem::path& json_path, const std::string& camera);

// Every camera of the file ("maker model"), sorted.
std::vector<std::string> listNoiseProfileCameras(const std::filesystem::path& json_path);

// The noise-profile file to use when none is given: <data>/noise_profiles/noiseprofiles.json (the full darktable
// database; `data` as io::defaultSharedData) when it exists, else the bundled excerpt samples/noise_profiles/.
std::filesystem::path defaultNoiseProfiles(const std::string& data = {});

}  // namespace crfcal::io
