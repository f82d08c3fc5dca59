#include "crfcal/io/lut_export.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>

#include <opencv2/core.hpp>
#include <opencv2/core/persistence.hpp>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/io/atomic_output.hpp"

namespace crfcal::io {
namespace {

struct FormatInfo {
  LutFormat format;
  const char* name;
};
constexpr FormatInfo kFormats[] = {{LutFormat::Csv, "csv"},     {LutFormat::OpenCv, "opencv"},
                                   {LutFormat::Cube, "cube"},   {LutFormat::Spi1d, "spi1d"},
                                   {LutFormat::Clf, "clf"},     {LutFormat::Pfstools, "pfstools"},
                                   {LutFormat::Hugin, "hugin"}};

constexpr int kHuginTerms = 5;  // Ra, Rb, Rc, Rd, Re
constexpr double kPfsMinWeight = 1e-3;  // pfstools' MIN_WEIGHT (responses.cpp)

std::string lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return s;
}

std::string fixed9(double v) {
  char buffer[48];
  std::snprintf(buffer, sizeof buffer, "%.9f", v);
  return buffer;
}

// The value a reader obtains from the text `written`: parsed, and rounded to float for float readers.
double readBack(const std::string& written, bool as_float) {
  const double v = std::strtod(written.c_str(), nullptr);
  return as_float ? static_cast<double>(static_cast<float>(v)) : v;
}

std::string xmlEscape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

std::string oneLine(std::string text) {
  for (char& c : text)
    if (c == '\n' || c == '\r' || c == '"') c = ' ';
  return text;
}

bool isPowerOfTwo(int n) { return n > 0 && (n & (n - 1)) == 0; }

// Node i of the LUT: x = lo + (hi − lo)·i/(N−1).
double nodeInput(const LutExportOptions& options, int size, int i) {
  return options.range_min + (options.range_max - options.range_min) * double(i) / double(size - 1);
}

double evaluate(const ResponseCurve& curve, LutDirection direction, double x) {
  return direction == LutDirection::Inverse ? curve.inverse(x) : curve.forward(x);
}

// Measured precision of a node table (values as read back): max |pl(x) − curve(x)| on a grid 8× finer.
double tableError(const ExportCurves& curves, const LutExportOptions& options, int size,
                  const std::array<std::vector<double>, 3>& read_back) {
  const int refine = std::clamp(131072 / std::max(1, size - 1), 1, 8);
  const int grid = (size - 1) * refine + 1;
  double worst = 0;
  for (int c = 0; c < 3; ++c) {
    const auto& table = read_back[static_cast<size_t>(c)];
    for (int j = 0; j < grid; ++j) {
      const int i = std::min(j / refine, size - 2);
      const double t = double(j - i * refine) / refine;
      const double lut = table[static_cast<size_t>(i)] + t * (table[static_cast<size_t>(i) + 1] - table[static_cast<size_t>(i)]);
      const double x = options.range_min + (options.range_max - options.range_min) * double(j) / double(grid - 1);
      worst = std::max(worst, std::abs(lut - evaluate(curves.rgb[static_cast<size_t>(c)], options.direction, x)));
    }
  }
  return worst;
}

// Exact node values, R, G, B.
std::array<std::vector<double>, 3> nodeValues(const ExportCurves& curves, const LutExportOptions& options, int size) {
  std::array<std::vector<double>, 3> values;
  for (int c = 0; c < 3; ++c) {
    auto& v = values[static_cast<size_t>(c)];
    v.resize(static_cast<size_t>(size));
    for (int i = 0; i < size; ++i)
      v[static_cast<size_t>(i)] = evaluate(curves.rgb[static_cast<size_t>(c)], options.direction, nodeInput(options, size, i));
  }
  return values;
}

// Text rows "r g b" with %.9f; fills the read-back table (float readers).
std::string rgbRows(const std::array<std::vector<double>, 3>& values, const char* indent, const char* separator,
                    std::array<std::vector<double>, 3>& read_back, double& rounding) {
  std::string text;
  const size_t n = values[0].size();
  text.reserve(n * 40);
  for (auto& r : read_back) r.resize(n);
  for (size_t i = 0; i < n; ++i) {
    text += indent;
    for (size_t c = 0; c < 3; ++c) {
      const std::string s = fixed9(values[c][i]);
      read_back[c][i] = readBack(s, true);
      rounding = std::max(rounding, std::abs(read_back[c][i] - values[c][i]));
      if (c > 0) text += separator;
      text += s;
    }
    text += '\n';
  }
  return text;
}

std::string directionWords(LutDirection direction) {
  return direction == LutDirection::Inverse ? "inverse CRF phi (intensity -> relative irradiance)"
                                            : "forward CRF psi (relative irradiance -> intensity)";
}

std::string renderCsv(const ExportCurves& curves, const LutExportOptions& options, int size, LutExportResult& info) {
  const auto values = nodeValues(curves, options, size);
  std::array<std::vector<double>, 3> read_back;
  for (auto& r : read_back) r.resize(static_cast<size_t>(size));
  std::string text = "x,R,G,B\n";
  for (int i = 0; i < size; ++i) {
    text += fixed9(nodeInput(options, size, i));
    for (size_t c = 0; c < 3; ++c) {
      const std::string s = fixed9(values[c][static_cast<size_t>(i)]);
      read_back[c][static_cast<size_t>(i)] = readBack(s, false);
      info.rounding_error = std::max(info.rounding_error, std::abs(read_back[c][static_cast<size_t>(i)] - values[c][static_cast<size_t>(i)]));
      text += ',';
      text += s;
    }
    text += '\n';
  }
  info.max_error = tableError(curves, options, size, read_back);
  return text;
}

std::string renderCube(const ExportCurves& curves, const LutExportOptions& options, int size, LutExportResult& info) {
  const auto values = nodeValues(curves, options, size);
  std::array<std::vector<double>, 3> read_back;
  std::string text = "# " + directionWords(options.direction) + ", written by crfcal\n";
  text += "TITLE \"" + oneLine(options.title) + "\"\n";
  text += "LUT_1D_SIZE " + std::to_string(size) + "\n";
  if (options.range_min != 0.0 || options.range_max != 1.0) {
    const std::string lo = fixed9(options.range_min), hi = fixed9(options.range_max);
    text += "DOMAIN_MIN " + lo + " " + lo + " " + lo + "\n";
    text += "DOMAIN_MAX " + hi + " " + hi + " " + hi + "\n";
  }
  text += "\n";
  text += rgbRows(values, "", " ", read_back, info.rounding_error);
  info.max_error = tableError(curves, options, size, read_back);
  return text;
}

std::string renderSpi1d(const ExportCurves& curves, const LutExportOptions& options, int size, LutExportResult& info) {
  const auto values = nodeValues(curves, options, size);
  std::array<std::vector<double>, 3> read_back;
  std::string text = "Version 1\n";
  text += "From " + fixed9(options.range_min) + " " + fixed9(options.range_max) + "\n";
  text += "Length " + std::to_string(size) + "\n";
  text += "Components 3\n{\n";
  text += rgbRows(values, "    ", " ", read_back, info.rounding_error);
  text += "}\n";
  info.max_error = tableError(curves, options, size, read_back);
  return text;
}

std::string renderClf(const ExportCurves& curves, const LutExportOptions& options, int size, LutExportResult& info) {
  const auto values = nodeValues(curves, options, size);
  std::array<std::vector<double>, 3> read_back;
  std::string text = "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  text += "<ProcessList id=\"crfcal-" + std::string(options.direction == LutDirection::Inverse ? "inverse" : "forward") +
          "-crf\" name=\"" + xmlEscape(options.title) + "\" compCLFversion=\"3\">\n";
  text += "    <Description>" + xmlEscape(directionWords(options.direction)) + ", written by crfcal</Description>\n";
  if (options.range_min != 0.0 || options.range_max != 1.0) {
    text += "    <Range id=\"domain\" inBitDepth=\"32f\" outBitDepth=\"32f\">\n";
    text += "        <minInValue>" + fixed9(options.range_min) + "</minInValue>\n";
    text += "        <maxInValue>" + fixed9(options.range_max) + "</maxInValue>\n";
    text += "        <minOutValue>0</minOutValue>\n        <maxOutValue>1</maxOutValue>\n";
    text += "    </Range>\n";
  }
  text += "    <LUT1D id=\"crf\" name=\"" + xmlEscape(options.title) +
          "\" inBitDepth=\"32f\" outBitDepth=\"32f\" interpolation=\"linear\">\n";
  text += "        <Array dim=\"" + std::to_string(size) + " 3\">\n";
  text += rgbRows(values, "", " ", read_back, info.rounding_error);
  text += "        </Array>\n    </LUT1D>\n</ProcessList>\n";
  info.max_error = tableError(curves, options, size, read_back);
  return text;
}

std::string renderOpenCv(const ExportCurves& curves, const LutExportOptions& options, int size, LutExportResult& info,
                         const std::filesystem::path& file) {
  auto values = nodeValues(curves, options, size);  // R, G, B
  // Row i is the response for pixel value i. MergeDebevec takes log(response) and gives pixel value 0 a non-zero
  // (triangle) weight, so φ(0) = 0 would make every pixel that is 0 in any shot log(0) = −inf: raise entries ≤ 0 to
  // the channel's smallest positive entry — row 0 = φ(1/255), exactly what OpenCV does to its own default linear
  // response (modules/photo/src/merge.cpp: response.at<Vec3f>(0) = response.at<Vec3f>(1)). Rows 1..255 are φ(i/255).
  for (auto& v : values) {
    double floor = std::numeric_limits<double>::infinity();
    for (double e : v)
      if (e > 0) floor = std::min(floor, e);
    if (!std::isfinite(floor)) floor = 1e-6;
    for (double& e : v) e = std::max(e, floor);
  }
  cv::Mat response(size, 1, CV_32FC3);
  std::array<std::vector<double>, 3> read_back;
  for (auto& r : read_back) r.resize(static_cast<size_t>(size));
  for (int i = 0; i < size; ++i) {
    cv::Vec3f& bgr = response.at<cv::Vec3f>(i);
    for (int c = 0; c < 3; ++c) {
      const float f = static_cast<float>(values[static_cast<size_t>(c)][static_cast<size_t>(i)]);
      bgr[2 - c] = f;
      read_back[static_cast<size_t>(c)][static_cast<size_t>(i)] = f;
    }
  }
  // The raised zero is not an error of the table: measure against the exact values elsewhere.
  const auto exact = nodeValues(curves, options, size);
  for (size_t c = 0; c < 3; ++c)
    for (size_t i = 1; i < static_cast<size_t>(size); ++i)
      info.rounding_error = std::max(info.rounding_error, std::abs(read_back[c][i] - exact[c][i]));
  info.max_error = tableError(curves, options, size, read_back);

  const std::string extension = lower(file.extension().string());
  int flavour = cv::FileStorage::FORMAT_YAML;
  if (extension == ".xml") flavour = cv::FileStorage::FORMAT_XML;
  if (extension == ".json") flavour = cv::FileStorage::FORMAT_JSON;
  cv::FileStorage storage(".yml", cv::FileStorage::WRITE | cv::FileStorage::MEMORY | flavour);
  storage << "response" << response;
  storage << "crfcal_channel_order" << "BGR";
  storage << "crfcal_description"
          << "row i = pixel value i (0..255) -> relative irradiance phi(i/255); "
             "for cv::MergeDebevec/MergeRobertson::process(images, hdr, times, response)";
  storage << "crfcal_source_channels"
          << (curves.source_channel[2] + "," + curves.source_channel[1] + "," + curves.source_channel[0]);
  return storage.releaseAndGetString();
}

std::string renderPfstools(const ExportCurves& curves, const LutExportOptions& options, int size, LutExportResult& info) {
  const auto values = nodeValues(curves, options, size);
  std::array<std::vector<double>, 3> read_back;
  for (auto& r : read_back) r.resize(static_cast<size_t>(size));
  std::string text;
  char line[128];
  auto block = [&](const std::vector<double>& curve, const char* name, std::vector<double>& back) {
    // Layout of pfstools' responseSave() (src/camera/responses.cpp).
    std::snprintf(line, sizeof line, "# Camera response curve, channel %s\n", name);
    text += line;
    text += "# data layout: log10(response) | camera output | response\n";
    std::snprintf(line, sizeof line, "# name: %s\n", name);
    text += line;
    text += "# type: matrix\n";
    text += "# rows: " + std::to_string(size) + "\n";
    text += "# columns: 3\n";
    for (int m = 0; m < size; ++m) {
      const float value = static_cast<float>(curve[static_cast<size_t>(m)]);
      const float log_value = value > 0.0f ? std::log10(value) : -6.0f;
      std::snprintf(line, sizeof line, " %e %4d %e\n", static_cast<double>(log_value), m, static_cast<double>(value));
      text += line;
      char number[32];
      std::snprintf(number, sizeof number, "%e", static_cast<double>(value));
      back[static_cast<size_t>(m)] = readBack(number, true);
      info.rounding_error = std::max(info.rounding_error, std::abs(back[static_cast<size_t>(m)] - curve[static_cast<size_t>(m)]));
    }
    text += "\n";
  };
  if (options.channel.empty()) {
    block(values[0], "IR", read_back[0]);
    block(values[1], "IG", read_back[1]);
    block(values[2], "IB", read_back[2]);
  } else {
    block(values[1], "IY", read_back[1]);
    read_back[0] = read_back[2] = read_back[1];
  }
  // Weighting block "W" (pfstools' weightsSave()): the hat of Debevec & Malik, floored at pfstools' MIN_WEIGHT.
  text += "# Weighting function\n";
  text += "# data layout: weight | camera output\n";
  text += "# name: W\n# type: matrix\n";
  text += "# rows: " + std::to_string(size) + "\n";
  text += "# columns: 2\n";
  for (int m = 0; m < size; ++m) {
    const double w = std::max(kPfsMinWeight, 1.0 - std::abs(2.0 * m / double(size - 1) - 1.0));
    std::snprintf(line, sizeof line, " %e %4d\n", static_cast<double>(static_cast<float>(w)), m);
    text += line;
  }
  text += "\n";
  info.max_error = tableError(curves, options, size, read_back);
  return text;
}

std::string renderHugin(const ExportCurves& curves, const LutExportOptions& options, LutExportResult& info) {
  const ResponseCurve& curve = curves.rgb[1];  // G (or the chosen channel, replicated)
  std::vector<double> psi(emor::kSamples);
  for (int i = 0; i < emor::kSamples; ++i) psi[static_cast<size_t>(i)] = curve.forward(double(i) / (emor::kSamples - 1));
  const std::vector<double> c = emor::fitForward(psi, kHuginTerms);
  char number[6][40];
  for (int k = 0; k < kHuginTerms; ++k) std::snprintf(number[k], sizeof number[k], "%.9g", c[static_cast<size_t>(k)]);
  std::vector<double> written(kHuginTerms);
  for (int k = 0; k < kHuginTerms; ++k) {
    written[static_cast<size_t>(k)] = std::strtod(number[k], nullptr);
    info.rounding_error = std::max(info.rounding_error, std::abs(written[static_cast<size_t>(k)] - c[static_cast<size_t>(k)]));
  }
  const std::vector<double> fitted = emor::evaluateForward(written);
  double sum = 0, worst = 0;
  for (size_t i = 0; i < psi.size(); ++i) {
    const double e = fitted[i] - psi[i];
    sum += e * e;
    worst = std::max(worst, std::abs(e));
  }
  info.max_error = worst;
  info.emor_rmse = std::sqrt(sum / double(psi.size()));
  info.hugin_coefficients = written;

  char line[256];
  std::string text = "# Hugin/PanoTools EMoR camera response, written by crfcal\n";
  text += "# psi(E) = f0(E) + Ra*h1(E) + Rb*h2(E) + Rc*h3(E) + Rd*h4(E) + Re*h5(E), E = irradiance in [0,1]\n";
  text += "# (f0, h_k: Grossberg & Nayar's EMoR forward basis, emor.txt, as in Hugin's vigra_ext/emor.h)\n";
  text += "# channel: " + curves.source_channel[1] + " (" + curves.source[1] + "); response type Rt0 = EMoR\n";
  std::snprintf(line, sizeof line, "# EMoR-5 representation error of psi: RMSE %.3e, max %.3e (1024 samples)\n",
                info.emor_rmse, info.max_error);
  text += line;
  text += "# Paste into a PTO 'i' line (value follows the key; 'Ra=0' would link to image 0 instead):\n";
  text += std::string("Ra") + number[0] + " Rb" + number[1] + " Rc" + number[2] + " Rd" + number[3] + " Re" + number[4] + "\n";
  (void)options;
  return text;
}

}  // namespace

LutFormat parseLutFormat(const std::string& name) {
  const std::string key = lower(name);
  for (const auto& f : kFormats)
    if (key == f.name) return f.format;
  if (key == "yml" || key == "yaml" || key == "xml") return LutFormat::OpenCv;
  if (key == "pfs" || key == "pfshdrcalibrate") return LutFormat::Pfstools;
  if (key == "emor" || key == "pto") return LutFormat::Hugin;
  std::string list;
  for (const auto& f : kFormats) list += (list.empty() ? "" : ", ") + std::string(f.name);
  throw InvalidInput("unknown export format '" + name + "' (one of: " + list + ")");
}

std::string lutFormatName(LutFormat format) {
  for (const auto& f : kFormats)
    if (f.format == format) return f.name;
  return "?";
}

std::vector<std::string> lutFormatNames() {
  std::vector<std::string> names;
  for (const auto& f : kFormats) names.emplace_back(f.name);
  return names;
}

std::optional<LutFormat> lutFormatFromExtension(const std::filesystem::path& file) {
  const std::string e = lower(file.extension().string());
  if (e == ".csv") return LutFormat::Csv;
  if (e == ".yml" || e == ".yaml" || e == ".xml" || e == ".json") return LutFormat::OpenCv;
  if (e == ".cube") return LutFormat::Cube;
  if (e == ".spi1d") return LutFormat::Spi1d;
  if (e == ".clf") return LutFormat::Clf;
  if (e == ".m" || e == ".rsp") return LutFormat::Pfstools;
  if (e == ".pto" || e == ".emor") return LutFormat::Hugin;
  return std::nullopt;
}

int defaultLutSize(LutFormat format) {
  switch (format) {
    case LutFormat::Cube:
    case LutFormat::Spi1d:
    case LutFormat::Clf: return 4096;
    case LutFormat::OpenCv:
    case LutFormat::Pfstools: return 256;
    case LutFormat::Csv:
    case LutFormat::Hugin: return kCurveSamples;
  }
  return kCurveSamples;
}

bool lutSupportsRange(LutFormat format) {
  return format == LutFormat::Csv || format == LutFormat::Cube || format == LutFormat::Spi1d || format == LutFormat::Clf;
}

bool lutSupportsDirection(LutFormat format, LutDirection direction) {
  switch (format) {
    case LutFormat::OpenCv:
    case LutFormat::Pfstools: return direction == LutDirection::Inverse;  // pixel value → irradiance by definition
    case LutFormat::Hugin: return direction == LutDirection::Forward;     // EMoR coefficients of ψ
    default: return true;
  }
}

void LutExportOptions::check() const {
  const std::string name = lutFormatName(format);
  if (!lutSupportsDirection(format, direction))
    throw InvalidInput(name + " stores only the " +
                       std::string(direction == LutDirection::Inverse ? "forward response psi (--direction forward)"
                                                                      : "inverse response phi (--direction inverse)"));
  if (!(std::isfinite(range_min) && std::isfinite(range_max) && 0.0 <= range_min && range_min < range_max &&
        range_max <= 1.0))
    throw InvalidInput("LUT range must satisfy 0 <= lo < hi <= 1");
  if ((range_min != 0.0 || range_max != 1.0) && !lutSupportsRange(format))
    throw InvalidInput(name + " has no input range: it always covers [0,1]");
  if (size != 0) {
    if (size < 2) throw InvalidInput("LUT size must be at least 2");
    if (format == LutFormat::OpenCv && size != 256)
      throw InvalidInput("opencv: MergeDebevec/MergeRobertson need exactly 256 entries");
    if (format == LutFormat::Hugin && size != kCurveSamples)
      throw InvalidInput("hugin: the EMoR coefficients have no size option");
    if (format == LutFormat::Pfstools && (!isPowerOfTwo(size) || size < 256 || size > 65536))
      throw InvalidInput("pfstools: size must be 2^bits, 256 .. 65536 (pfshdrcalibrate --bpp)");
    if (format == LutFormat::Cube && size > 65536) throw InvalidInput("cube: LUT_1D_SIZE must be at most 65536");
    if (size > (1 << 24)) throw InvalidInput("LUT size too large");
  }
  if (!channel.empty() && channel != "R" && channel != "G" && channel != "B")
    throw InvalidInput("channel must be R, G or B");
}

ExportCurves exportCurves(const CalibrationReport& report, const std::string& channel) {
  const std::vector<std::string> available = report.channels();
  if (available.empty()) throw InvalidInput("the report has no curve");
  std::array<std::string, 3> picks;
  if (!channel.empty()) {
    if (!report.inverse_crf.count(channel)) {
      if (available.size() != 1)
        throw InvalidInput("the report has no channel " + channel);
      picks.fill(available.front());  // a grey report: its only curve stands for every channel
    } else {
      picks.fill(channel);
    }
  } else if (available.size() == 1) {
    picks.fill(available.front());
  } else {
    const char* rgb[3] = {"R", "G", "B"};
    for (size_t c = 0; c < 3; ++c) {
      if (!report.inverse_crf.count(rgb[c])) throw InvalidInput(std::string("the report has no channel ") + rgb[c]);
      picks[c] = rgb[c];
    }
  }
  ExportCurves curves;
  for (size_t c = 0; c < 3; ++c) {
    const std::string& name = picks[c];
    if (c > 0 && picks[c] == picks[c - 1]) {
      curves.rgb[c] = curves.rgb[c - 1];
      curves.source[c] = curves.source[c - 1];
      curves.source_channel[c] = name;
      continue;
    }
    const std::vector<double>& samples = report.inverse_crf.at(name);
    curves.source_channel[c] = name;
    bool from_model = false;
    if (const auto it = report.models.find(name); it != report.models.end()) {
      // The parametric model is exact between samples; use it when it is the curve the samples show.
      try {
        double worst = 0;
        for (size_t i = 0; i < samples.size(); ++i)
          worst = std::max(worst, std::abs(evaluateInverse(it->second, double(i) / double(samples.size() - 1)) - samples[i]));
        if (worst <= 1e-6) {
          curves.rgb[c] = ResponseCurve(it->second);
          curves.source[c] = "model:" + describe(it->second);
          from_model = true;
        }
      } catch (const InvalidInput&) {
      }
    }
    if (!from_model) {
      try {
        curves.rgb[c] = ResponseCurve::fromSamples(samples);
      } catch (const InvalidInput& e) {
        throw InvalidInput("channel " + name + ": " + e.reason());
      }
      curves.source[c] = "samples";
    }
  }
  return curves;
}

std::string renderLut(const ExportCurves& curves, const LutExportOptions& options, LutExportResult* info,
                      const std::filesystem::path& file) {
  options.check();
  LutExportResult local;
  LutExportResult& out = info ? *info : local;
  out.format = options.format;
  out.direction = options.direction;
  out.size = options.size > 0 ? options.size : defaultLutSize(options.format);
  out.range_min = options.range_min;
  out.range_max = options.range_max;
  out.source_channel = curves.source_channel;
  out.source = curves.source;
  out.max_error = out.rounding_error = out.emor_rmse = 0;
  out.hugin_coefficients.clear();
  switch (options.format) {
    case LutFormat::Csv: return renderCsv(curves, options, out.size, out);
    case LutFormat::Cube: return renderCube(curves, options, out.size, out);
    case LutFormat::Spi1d: return renderSpi1d(curves, options, out.size, out);
    case LutFormat::Clf: return renderClf(curves, options, out.size, out);
    case LutFormat::OpenCv: return renderOpenCv(curves, options, out.size, out, file);
    case LutFormat::Pfstools: return renderPfstools(curves, options, out.size, out);
    case LutFormat::Hugin: return renderHugin(curves, options, out);
  }
  throw InvalidInput("unknown export format");
}

LutExportResult exportLut(const CalibrationReport& report, const std::filesystem::path& file,
                          const LutExportOptions& options) {
  options.check();
  std::string channel = options.channel;
  if (options.format == LutFormat::Hugin && channel.empty()) channel = "G";  // one response per image in Hugin
  const ExportCurves curves = exportCurves(report, channel);
  LutExportResult result;
  const std::string text = renderLut(curves, options, &result, file);
  writeTextFile(file, text);
  result.file = file;
  return result;
}

std::string LutExportResult::summary() const {
  char line[512];
  std::string channels;
  for (size_t c = 0; c < 3; ++c) {
    if (c > 0 && source_channel[c] == source_channel[c - 1] && source[c] == source[c - 1]) continue;
    channels += (channels.empty() ? "" : ", ") + source_channel[c] + " from " + source[c];
  }
  if (format == LutFormat::Hugin) {
    std::snprintf(line, sizeof line,
                  "%s: hugin EMoR Ra..Re = %.6g %.6g %.6g %.6g %.6g (forward psi of %s); EMoR-5 error RMSE %.3e, max %.3e",
                  file.string().c_str(), hugin_coefficients.size() > 4 ? hugin_coefficients[0] : 0.0,
                  hugin_coefficients.size() > 4 ? hugin_coefficients[1] : 0.0,
                  hugin_coefficients.size() > 4 ? hugin_coefficients[2] : 0.0,
                  hugin_coefficients.size() > 4 ? hugin_coefficients[3] : 0.0,
                  hugin_coefficients.size() > 4 ? hugin_coefficients[4] : 0.0, channels.c_str(), emor_rmse, max_error);
    return line;
  }
  std::snprintf(line, sizeof line, "%s: %s, %s, %d nodes on [%g, %g] (%s); max |LUT - curve| %.3e (rounding %.1e)",
                file.string().c_str(), lutFormatName(format).c_str(),
                direction == LutDirection::Inverse ? "inverse phi" : "forward psi", size, range_min, range_max,
                channels.c_str(), max_error, rounding_error);
  return line;
}

}  // namespace crfcal::io
