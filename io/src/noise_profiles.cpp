#include "crfcal/io/noise_profiles.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

#include <nlohmann/json.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/datasets.hpp"
#include "crfcal/io/kernel_io.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;
namespace {

// Lower case, runs of white space collapsed to one space, trimmed: "Canon  EOS 5D" → "canon eos 5d".
std::string normalised(const std::string& name) {
  std::string out;
  for (const char ch : name) {
    if (std::isspace(static_cast<unsigned char>(ch))) {
      if (!out.empty() && out.back() != ' ') out += ' ';
    } else {
      out += static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
    }
  }
  if (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

std::string cameraName(const std::string& maker, const std::string& model) {
  if (normalised(model).rfind(normalised(maker), 0) == 0) return model;  // "Canon PowerShot SX160 IS" in darktable
  return maker + " " + model;
}

nlohmann::json readJson(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw Error("cannot open the noise-profile file", path.string());
  try {
    return nlohmann::json::parse(in);
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("invalid JSON: ") + e.what(), path.string());
  }
}

PoissonGaussian channel(const nlohmann::json& profile, size_t c) {
  return {profile.at("a").at(c).get<double>(), profile.at("b").at(c).get<double>()};
}

// The used (not "skip") profiles of one model, one per ISO (repeated measurements averaged), ISO ascending.
std::vector<std::pair<double, SensorNoise>> profilesByIso(const nlohmann::json& model) {
  std::map<double, std::pair<SensorNoise, int>> sums;
  for (const auto& p : model.at("profiles")) {
    if (p.value("skip", false)) continue;
    const double iso = p.at("iso").get<double>();
    if (!(iso > 0)) throw InvalidInput("profile \"" + p.value("name", "") + "\" has ISO <= 0");
    auto& [sum, n] = sums[iso];
    PoissonGaussian* channels[] = {&sum.red, &sum.green, &sum.blue};
    for (size_t c = 0; c < 3; ++c) {
      const PoissonGaussian v = channel(p, c);
      channels[c]->a += v.a;
      channels[c]->b += v.b;
    }
    ++n;
  }
  std::vector<std::pair<double, SensorNoise>> out;
  for (auto& [iso, entry] : sums) {
    auto& [sum, n] = entry;
    for (PoissonGaussian* c : {&sum.red, &sum.green, &sum.blue}) {
      c->a /= n;
      c->b /= n;
    }
    out.emplace_back(iso, sum);
  }
  return out;
}

PoissonGaussian lerp(const PoissonGaussian& lo, const PoissonGaussian& hi, double t) {
  return {lo.a + t * (hi.a - lo.a), lo.b + t * (hi.b - lo.b)};
}

}  // namespace

std::string CameraNoiseProfile::camera() const { return cameraName(maker, model); }

double CameraNoiseProfile::minIso() const { return by_iso.empty() ? 0 : by_iso.front().first; }

double CameraNoiseProfile::maxIso() const { return by_iso.empty() ? 0 : by_iso.back().first; }

SensorNoise CameraNoiseProfile::atIso(double iso) const {
  if (by_iso.empty()) throw InvalidInput(camera() + " has no usable noise profile", source);
  if (!(iso >= minIso() && iso <= maxIso())) {
    std::ostringstream why;
    why << camera() << " has noise profiles for ISO " << minIso() << "–" << maxIso() << " only, not ISO " << iso;
    throw InvalidInput(why.str(), source);
  }
  const auto hi = std::lower_bound(by_iso.begin(), by_iso.end(), iso,
                                   [](const auto& entry, double value) { return entry.first < value; });
  if (hi->first == iso) return hi->second;
  const auto lo = hi - 1;
  const double t = (iso - lo->first) / (hi->first - lo->first);
  return {lerp(lo->second.red, hi->second.red, t), lerp(lo->second.green, hi->second.green, t),
          lerp(lo->second.blue, hi->second.blue, t)};
}

std::string CameraNoiseProfile::summary() const {
  std::ostringstream out;
  out << camera() << ": ISO " << minIso() << "–" << maxIso() << " (" << by_iso.size() << " ISOs), from " << source;
  return out.str();
}

std::vector<std::string> listNoiseProfileCameras(const fs::path& json_path) {
  const nlohmann::json doc = readJson(json_path);
  std::vector<std::string> names;
  try {
    for (const auto& maker : doc.at("noiseprofiles"))
      for (const auto& model : maker.at("models"))
        names.push_back(cameraName(maker.at("maker").get<std::string>(), model.at("model").get<std::string>()));
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("unexpected noise-profile layout: ") + e.what(), json_path.string());
  }
  std::sort(names.begin(), names.end());
  return names;
}

CameraNoiseProfile readCameraNoiseProfile(const fs::path& json_path, const std::string& camera) {
  const std::string want = normalised(camera);
  if (want.empty()) throw InvalidInput("empty camera name for the noise profile", json_path.string());
  const nlohmann::json doc = readJson(json_path);
  std::vector<CameraNoiseProfile> found;
  try {
    for (const auto& maker : doc.at("noiseprofiles")) {
      const std::string maker_name = maker.at("maker").get<std::string>();
      for (const auto& model : maker.at("models")) {
        const std::string model_name = model.at("model").get<std::string>();
        if (want != normalised(model_name) && want != normalised(cameraName(maker_name, model_name))) continue;
        CameraNoiseProfile profile;
        profile.maker = maker_name;
        profile.model = model_name;
        profile.source = json_path.string();
        profile.by_iso = profilesByIso(model);
        found.push_back(profile);
      }
    }
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("unexpected noise-profile layout: ") + e.what(), json_path.string());
  } catch (const InvalidInput& e) {
    throw InvalidInput(camera + ": " + e.reason(), json_path.string());
  }
  if (found.size() > 1) {
    std::string names;
    for (const auto& f : found) names += (names.empty() ? "" : ", ") + f.camera();
    throw InvalidInput("camera \"" + camera + "\" is ambiguous in the noise profiles (" + names + "): give the maker too",
                       json_path.string());
  }
  if (found.empty()) {
    // Suggest the cameras whose name contains every word of the request except the first (the maker, often).
    std::string suggestions;
    const std::string tail = want.find(' ') == std::string::npos ? want : want.substr(want.find(' ') + 1);
    for (const auto& name : listNoiseProfileCameras(json_path))
      if (normalised(name).find(tail) != std::string::npos) suggestions += (suggestions.empty() ? "" : ", ") + name;
    throw InvalidInput("no noise profile for camera \"" + camera + "\"" +
                           (suggestions.empty() ? std::string(" (give \"maker model\" as darktable spells it)")
                                                : " (did you mean: " + suggestions + "?)"),
                       json_path.string());
  }
  if (found.front().by_iso.empty())
    throw InvalidInput(found.front().camera() + " has only skipped noise profiles", json_path.string());
  return found.front();
}

fs::path defaultNoiseProfiles(const std::string& data) {
  const fs::path shared = defaultSharedData(data) / "noise_profiles" / "noiseprofiles.json";
  if (fs::exists(shared)) return shared;
  return samplesDirectory() / "noise_profiles" / "noiseprofiles.json";
}

}  // namespace crfcal::io
