#include "crfcal/io/datasets.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdlib>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <sstream>

#include <nlohmann/json.hpp>

#include "crfcal/error.hpp"
#include "crfcal/io/image_io.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

fs::path defaultSharedData(const std::string& given) {
  if (!given.empty()) return given;
  if (const char* env = std::getenv("CRFCAL_SHARED_DATA"); env && *env) return env;
  return fs::path("..") / "shared" / "data";
}

namespace {

cv::Mat readRgb8(const fs::path& path) {
  cv::Mat image = readColorImage(path);
  if (image.cols != 390 || image.rows != 260) throw Error("expected a 390x260 rectified chart", path.string());
  return image;  // BGR
}

std::array<double, 3> patchMedian(const cv::Mat& bgr, int row, int col, int inner) {
  const int pitch = 65;
  const int off = (pitch - inner) / 2;
  const cv::Mat roi = bgr(cv::Rect(col * pitch + off, row * pitch + off, inner, inner));
  std::array<double, 3> out{};
  for (int c = 0; c < 3; ++c) {
    std::vector<int> v;
    v.reserve(static_cast<size_t>(inner * inner));
    for (int y = 0; y < roi.rows; ++y)
      for (int x = 0; x < roi.cols; ++x) v.push_back(roi.at<cv::Vec3b>(y, x)[c]);
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    out[static_cast<size_t>(2 - c)] = v[v.size() / 2];  // BGR → RGB
  }
  return out;
}

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::vector<std::string> splitCsvLine(const std::string& line) {
  std::vector<std::string> out;
  std::string cur;
  bool quoted = false;
  for (char ch : line) {
    if (ch == '"') {
      quoted = !quoted;
    } else if (ch == ',' && !quoted) {
      out.push_back(cur);
      cur.clear();
    } else if (ch != '\r') {
      cur += ch;
    }
  }
  out.push_back(cur);
  return out;
}

double parseNumber(const std::string& text) {
  if (text.empty()) return 0;
  const auto slash = text.find('/');
  try {
    if (slash != std::string::npos) return std::stod(text.substr(0, slash)) / std::stod(text.substr(slash + 1));
    return std::stod(text);
  } catch (const std::exception&) {
    return 0;
  }
}

}  // namespace

std::vector<MiddleburyCamera> readMiddleburyPatches(const fs::path& root, const MiddleburyPatchOptions& options) {
  if (!fs::is_directory(root)) throw Error("not a directory", root.string());
  std::vector<std::string> names;
  for (const auto& entry : fs::directory_iterator(root))
    if (entry.is_directory() && fs::exists(entry.path() / "wb1i1e1-jpg.png")) names.push_back(entry.path().filename());
  std::sort(names.begin(), names.end());
  if (names.empty()) throw Error("no camera folders with wb1i*e*-{jpg,raw}.png", root.string());
  std::vector<MiddleburyCamera> cameras;
  for (const auto& name : names) {
    MiddleburyCamera camera;
    camera.name = name;
    for (int scene = 1; scene <= 2; ++scene) {
      for (int e = 1; e <= 4; ++e) {
        const std::string stem = "wb1i" + std::to_string(scene) + "e" + std::to_string(e);
        const fs::path jpg = root / name / (stem + "-jpg.png");
        const fs::path raw = root / name / (stem + "-raw.png");
        if (!fs::exists(jpg) || !fs::exists(raw)) continue;
        const cv::Mat j = readRgb8(jpg), r = readRgb8(raw);
        for (int row = 0; row < 4; ++row) {
          for (int col = 0; col < 6; ++col) {
            const auto rm = patchMedian(r, row, col, options.inner);
            const auto jm = patchMedian(j, row, col, options.inner);
            if (*std::max_element(rm.begin(), rm.end()) >= options.raw_clip) {
              ++camera.dropped_clipped;
              continue;
            }
            ColourSample s;
            for (size_t c = 0; c < 3; ++c) {
              s.raw[c] = rm[c] / 255.0;
              s.jpeg[c] = jm[c] / 255.0;
            }
            s.group = scene;
            s.patch = row * 6 + col;
            camera.samples.push_back(s);
          }
        }
      }
    }
    cameras.push_back(std::move(camera));
  }
  return cameras;
}

std::vector<DarktableNoiseProfile> readNoiseProfiles(const fs::path& json_path) {
  std::ifstream in(json_path);
  if (!in) throw Error("cannot open", json_path.string());
  nlohmann::json doc;
  try {
    in >> doc;
  } catch (const std::exception& e) {
    throw Error(std::string("invalid JSON: ") + e.what(), json_path.string());
  }
  std::vector<DarktableNoiseProfile> out;
  try {
    for (const auto& maker : doc.at("noiseprofiles")) {
      for (const auto& model : maker.at("models")) {
        for (const auto& p : model.at("profiles")) {
          DarktableNoiseProfile profile;
          profile.maker = maker.value("maker", "");
          profile.model = model.value("model", "");
          profile.name = p.value("name", "");
          profile.iso = p.at("iso").get<double>();
          for (size_t c = 0; c < 3; ++c) {
            profile.a[c] = p.at("a").at(c).get<double>();
            profile.b[c] = p.at("b").at(c).get<double>();
          }
          out.push_back(profile);
        }
      }
    }
  } catch (const nlohmann::json::exception& e) {
    throw Error(std::string("unexpected noise-profile layout: ") + e.what(), json_path.string());
  }
  return out;
}

std::optional<DarktableNoiseProfile> findNoiseProfile(const std::vector<DarktableNoiseProfile>& profiles,
                                                      const std::string& model, double iso) {
  std::optional<DarktableNoiseProfile> best;
  const std::string want = lower(model);
  for (const auto& p : profiles) {
    if (lower(p.model).find(want) == std::string::npos) continue;
    if (!best || std::abs(std::log(p.iso / iso)) < std::abs(std::log(best->iso / iso))) best = p;
  }
  return best;
}

std::vector<ExifCsvRow> readExifCsv(const fs::path& path) {
  std::ifstream in(path);
  if (!in) throw Error("cannot open", path.string());
  std::string line;
  if (!std::getline(in, line)) throw Error("empty CSV", path.string());
  const auto header = splitCsvLine(line);
  auto column = [&](const std::string& name) -> int {
    for (size_t i = 0; i < header.size(); ++i)
      if (header[i] == name) return static_cast<int>(i);
    return -1;
  };
  const int file = column("FileName"), make = column("Make"), model = column("Model"), iso = column("ISO"),
            time = column("ExposureTime"), fnum = column("FNumber"), width = column("ImageWidth"),
            height = column("ImageHeight");
  if (file < 0 || iso < 0 || time < 0) throw Error("missing FileName/ISO/ExposureTime columns", path.string());
  std::vector<ExifCsvRow> rows;
  while (std::getline(in, line)) {
    if (line.empty() || line == "\r") continue;
    const auto f = splitCsvLine(line);
    auto get = [&](int i) { return i >= 0 && static_cast<size_t>(i) < f.size() ? f[static_cast<size_t>(i)] : std::string(); };
    ExifCsvRow row;
    row.file = get(file);
    row.make = get(make);
    row.model = get(model);
    row.iso = parseNumber(get(iso));
    row.exposure_text = get(time);
    row.exposure_time = parseNumber(row.exposure_text);
    row.f_number = parseNumber(get(fnum));
    row.width = static_cast<int>(parseNumber(get(width)));
    row.height = static_cast<int>(parseNumber(get(height)));
    rows.push_back(row);
  }
  return rows;
}

cv::Mat readNpy(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot open", path.string());
  char magic[6];
  in.read(magic, 6);
  if (!in || std::memcmp(magic, "\x93NUMPY", 6) != 0) throw Error("not a .npy file", path.string());
  unsigned char version[2];
  in.read(reinterpret_cast<char*>(version), 2);
  std::uint32_t header_len = 0;
  if (version[0] == 1) {
    unsigned char l[2];
    in.read(reinterpret_cast<char*>(l), 2);
    header_len = l[0] | (l[1] << 8);
  } else {
    unsigned char l[4];
    in.read(reinterpret_cast<char*>(l), 4);
    header_len = l[0] | (l[1] << 8) | (l[2] << 16) | (static_cast<std::uint32_t>(l[3]) << 24);
  }
  std::string header(header_len, '\0');
  in.read(header.data(), header_len);
  if (!in) throw Error("truncated .npy header", path.string());
  const bool f8 = header.find("'<f8'") != std::string::npos;
  const bool f4 = header.find("'<f4'") != std::string::npos;
  if (!f8 && !f4) throw Error("only little-endian float32/float64 .npy supported", path.string());
  if (header.find("'fortran_order': True") != std::string::npos) throw Error("Fortran-order .npy not supported", path.string());
  const auto open = header.find('('), close = header.find(')');
  if (open == std::string::npos || close == std::string::npos) throw Error("no shape in .npy header", path.string());
  std::vector<int> shape;
  std::stringstream s(header.substr(open + 1, close - open - 1));
  std::string item;
  while (std::getline(s, item, ','))
    if (item.find_first_of("0123456789") != std::string::npos) shape.push_back(std::stoi(item));
  if (shape.empty() || shape.size() > 2) throw Error("only 1-D or 2-D .npy supported", path.string());
  const int rows = shape[0], cols = shape.size() == 2 ? shape[1] : 1;
  cv::Mat out(rows, cols, CV_64F);
  for (int i = 0; i < rows * cols; ++i) {
    double v = 0;
    if (f8) {
      in.read(reinterpret_cast<char*>(&v), 8);
    } else {
      float f = 0;
      in.read(reinterpret_cast<char*>(&f), 4);
      v = f;
    }
    out.at<double>(i / cols, i % cols) = v;
  }
  if (!in) throw Error("truncated .npy data", path.string());
  return out;
}

}  // namespace crfcal::io
