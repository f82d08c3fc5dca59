#pragma once
// The pictures `crfcal calibrate` writes next to report.json, each with its title, scale and legend:
//   curve.png      φ per channel (thick where the data support it, thin where extrapolated; bars: covered ranges)
//   gamma_map.png  Γ = B − I⊗K on G (Sec. 3.1), diverging colours centred at 0 with a colour bar
//   kernel.png     the kernel enlarged, ticks in pixels, colour bar (a picture: kernel.txt holds the data)
//   weights.png    the pixels the G fit used, over a dimmed copy of the sharp shot
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "crfcal/io/pair_input.hpp"
#include "crfcal/pair_calibration.hpp"

namespace crfcal::io {

struct CalibrationFigureInputs {
  const PairCalibrationResult& result;
  const LoadedPair& pair;
  const std::map<std::string, std::vector<double>>* raw_truth = nullptr;  // RAW truth φ per channel, if measured
};

// curve.png alone (a joint calibration of several pairs has no single pair's Γ map, kernel or weights):
// inputs.result's fits, bands, covered ranges and verdicts; the title names inputs.pair's camera.
void writeCalibrationCurveFigure(const std::filesystem::path& path, const CalibrationFigureInputs& inputs);

// Writes the four pictures into `directory` (atomically, one by one).
void writeCalibrationFigures(const std::filesystem::path& directory, const CalibrationFigureInputs& inputs);

}  // namespace crfcal::io
