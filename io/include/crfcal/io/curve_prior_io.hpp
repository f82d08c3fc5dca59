#pragma once
// The training curves of the learned curve prior (calib/learned_curve_prior.hpp, issue 19): the measured camera
// curves bundled in samples/camera_curves (<Camera>.csv, green, RAW-vs-JPEG fits of ten Middlebury cameras; see
// the PROVENANCE.md there), read here so that calib/ stays free of file I/O.
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include "crfcal/learned_curve_prior.hpp"

namespace crfcal::io {

struct NamedCurve {
  std::string name;                 // the file's stem: the camera
  std::vector<double> inverse_crf;  // 1024 samples
};

// Every <name>.csv of `dir` (default: samples/camera_curves), sorted by name. Throws crfcal::Error naming the
// directory when it holds none.
std::vector<NamedCurve> readCameraCurves(const std::filesystem::path& dir = {});

// The prior learned from those curves without the cameras named in `excluded` (leave-one-camera-out benches).
std::shared_ptr<const LearnedCurvePrior> learnPriorFromCameraCurves(const std::vector<std::string>& excluded = {},
                                                                    const std::filesystem::path& dir = {},
                                                                    const LearnedCurvePriorOptions& options = {});

}  // namespace crfcal::io
