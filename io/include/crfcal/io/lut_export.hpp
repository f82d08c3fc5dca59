#pragma once
// Writers that hand a measured response to other tools (one concept: "the curve as a lookup table in someone
// else's format"). Every file is written atomically (crfcal::io::writeAtomically).
//
// Formats (see docs/RESULTS.md#lut-export for the reader of each and how the tests load them back):
//   csv       x,R,G,B — N rows, x the LUT input (intensity for φ, irradiance for ψ), values %.9g.
//   opencv    cv::FileStorage (YAML, or XML/JSON by the file's extension): key "response" = 256×1 CV_32FC3,
//             BGR, pixel value → relative irradiance (what cv::MergeDebevec/MergeRobertson::process take and
//             CalibrateDebevec returns). Inverse φ only. Entries ≤ 0 (φ(0) = 0) are raised to the smallest
//             positive entry, as OpenCV does for its own linear response: MergeDebevec takes log(response).
//   cube      Adobe/Resolve 1D .cube: LUT_1D_SIZE N, DOMAIN_MIN/DOMAIN_MAX when the range is not [0,1].
//   spi1d     Sony Pictures Imageworks 1D (OpenColorIO): Version 1, From lo hi, Length N, Components 3.
//   clf       Academy/ASC Common LUT Format v3: ProcessList with a LUT1D (32f in/out, Array dim="N 3"),
//             preceded by a Range node mapping [lo,hi] → [0,1] when the range is not [0,1].
//   pfstools  pfshdrcalibrate --response-file / pfsinhdrgen: the text written by pfstools' responseSave():
//             blocks "IR", "IG", "IB" (or one "IY" block with --channel, for --luminance) of M = 2^bits rows
//             " log10(I) m I" and a weighting block "W". Inverse φ only; M = --size (power of two).
//   hugin     Hugin/PanoTools EMoR response: the first 5 coefficients (Ra..Re) of the least-squares fit of the
//             FORWARD response ψ = f0 + Σ c_k h_k (Grossberg & Nayar emor.txt), as a PTO image-line fragment
//             "Ra… Rb… Rc… Rd… Re…". One response per image in Hugin: channel --channel (default G).
#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "crfcal/io/report.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal::io {

enum class LutFormat { Csv, OpenCv, Cube, Spi1d, Clf, Pfstools, Hugin };
enum class LutDirection {
  Inverse,  // φ: intensity (pixel value) → irradiance, the calibrated curve
  Forward,  // ψ = φ⁻¹: irradiance → intensity, the camera response itself
};

// "csv", "opencv", "cube", "spi1d", "clf", "pfstools", "hugin" (throws InvalidInput listing them).
LutFormat parseLutFormat(const std::string& name);
std::string lutFormatName(LutFormat format);
// The format a file extension suggests (.csv .yml/.yaml/.xml/.json .cube .spi1d .clf .m/.rsp .pto/.emor), if any.
std::optional<LutFormat> lutFormatFromExtension(const std::filesystem::path& file);
std::vector<std::string> lutFormatNames();
// Default node count: 4096 (cube, spi1d, clf), 256 (opencv: MergeDebevec's LDR_SIZE; pfstools: 8-bit M),
// 1024 (csv: the report's own resolution), 1024 (hugin: the EMoR tables' length; fixed).
int defaultLutSize(LutFormat format);
// Whether the format stores a curve on a chosen input range (csv, cube, spi1d, clf) and the forward ψ.
bool lutSupportsRange(LutFormat format);
bool lutSupportsDirection(LutFormat format, LutDirection direction);

struct LutExportOptions {
  LutFormat format = LutFormat::Cube;
  LutDirection direction = LutDirection::Inverse;
  int size = 0;              // LUT nodes; 0 = defaultLutSize(format)
  double range_min = 0.0;    // input domain [range_min, range_max] ⊂ [0,1] covered by the nodes
  double range_max = 1.0;    // (outside it, LUT readers clamp to the end values)
  std::string channel;       // "" = R,G,B as in the report (a grey report's G is replicated);
                             // "R"/"G"/"B" = that channel in all three (pfstools: one "IY" block; hugin: default G)
  std::string title = "crfcal inverse camera response";
  void check() const;        // throws InvalidInput (bad size or range for the format, direction not supported)
};

// The three curves written (R, G, B order) and where each came from.
struct ExportCurves {
  std::array<ResponseCurve, 3> rgb;
  std::array<std::string, 3> source_channel;  // report channel feeding R, G, B
  std::array<std::string, 3> source;          // "model:<spec>" (the report's model, agreeing with its samples
                                              // to 1e-6) or "samples" (the report's 1024 samples, linear)
};

// Picks the curves of `report` for `channel` ("" = all; a grey report is replicated). Throws InvalidInput.
ExportCurves exportCurves(const CalibrationReport& report, const std::string& channel = {});

struct LutExportResult {
  std::filesystem::path file;
  LutFormat format = LutFormat::Cube;
  LutDirection direction = LutDirection::Inverse;
  int size = 0;
  double range_min = 0, range_max = 1;
  std::array<std::string, 3> source_channel;
  std::array<std::string, 3> source;
  // Measured precision: max |LUT − curve| over a grid 8× finer than the nodes, with the LUT interpolated
  // linearly between its values as written (rounding of the text included). For hugin: the EMoR-5 fit error.
  double max_error = 0;
  double rounding_error = 0;         // max |written value − exact value| at the nodes
  std::vector<double> hugin_coefficients;  // Ra..Re (hugin)
  double emor_rmse = 0;              // hugin: RMSE of the EMoR-5 ψ against ψ over 1024 samples
  std::string summary() const;
};

// Renders the file contents (without writing). `file` chooses the OpenCV FileStorage flavour by extension.
std::string renderLut(const ExportCurves& curves, const LutExportOptions& options, LutExportResult* info = nullptr,
                      const std::filesystem::path& file = "response.yml");
// Renders and writes `file` atomically. Throws crfcal::Error naming the file.
LutExportResult exportLut(const CalibrationReport& report, const std::filesystem::path& file,
                          const LutExportOptions& options);

}  // namespace crfcal::io
