#include "crfcal/io/curve_prior_io.hpp"

#include <algorithm>

#include "crfcal/error.hpp"
#include "crfcal/io/kernel_io.hpp"
#include "crfcal/io/response_io.hpp"

namespace crfcal::io {
namespace fs = std::filesystem;

std::vector<NamedCurve> readCameraCurves(const fs::path& dir_arg) {
  const fs::path dir = dir_arg.empty() ? samplesDirectory() / "camera_curves" : dir_arg;
  std::vector<NamedCurve> curves;
  if (fs::is_directory(dir))
    for (const auto& e : fs::directory_iterator(dir))
      if (e.path().extension() == ".csv") curves.push_back({e.path().stem().string(), readCurveTable(e.path())});
  if (curves.empty()) throw Error("no camera curve tables (<Camera>.csv) for the learned prior", dir.string());
  std::sort(curves.begin(), curves.end(), [](const NamedCurve& a, const NamedCurve& b) { return a.name < b.name; });
  return curves;
}

std::shared_ptr<const LearnedCurvePrior> learnPriorFromCameraCurves(const std::vector<std::string>& excluded,
                                                                    const fs::path& dir,
                                                                    const LearnedCurvePriorOptions& options) {
  std::vector<std::vector<double>> training;
  for (const NamedCurve& c : readCameraCurves(dir))
    if (std::find(excluded.begin(), excluded.end(), c.name) == excluded.end()) training.push_back(c.inverse_crf);
  return std::make_shared<const LearnedCurvePrior>(learnCurvePrior(training, options));
}

}  // namespace crfcal::io
