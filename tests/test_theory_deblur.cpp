// The seed's Fig. 3 / Fig. 4 (theory_deblur.hpp) and their files from `crfcal theory`.
#include <cmath>
#include <filesystem>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "crfcal/theory_deblur.hpp"
#include "test_support.hpp"

namespace crfcal {
namespace {

// Eq. 18: B ⊗ K⁻¹ = I + P ⊗ K⁻¹. Taking the deconvolved artefact away leaves a much better estimate of I than
// B ⊗ K⁻¹ itself, and P ≥ 0 for the convex gamma 2.2 (Theorem 1).
TEST(TheoryDeblur, StepEdgeRingingIsTheDeconvolvedArtefact) {
  const theory::StepEdgeResult step = theory::stepEdgeDeconvolution();
  ASSERT_EQ(step.sharp.size(), 256u);
  double with_artefact = 0, without_artefact = 0, min_p = 0, max_p = 0;
  for (size_t i = 0; i < step.sharp.size(); ++i) {
    with_artefact += std::pow(step.deconvolved[i] - step.sharp[i], 2);
    without_artefact += std::pow(step.deconvolved[i] - step.artefact_deconvolved[i] - step.sharp[i], 2);
    min_p = std::min(min_p, step.artefact[i]);
    max_p = std::max(max_p, step.artefact[i]);
  }
  std::printf("%s; squared error %.4f with P (x) K^-1, %.4f without\n", step.summary().c_str(), with_artefact,
              without_artefact);
  EXPECT_GT(min_p, -1e-12);
  EXPECT_GT(max_p, 0.1);
  EXPECT_LT(without_artefact, 0.5 * with_artefact);
  EXPECT_GT(step.max_ringing, step.max_irradiance_error);
}

TEST(TheoryCli, WritesFigures3And4) {
  test::TempDir dir;
  std::filesystem::create_directories(dir / "images");
  cv::Mat crop;
  test::levinImage(1)(cv::Rect(60, 60, 96, 96)).convertTo(crop, CV_8U, 255.0);
  cv::imwrite((dir / "images" / "crop.png").string(), crop);
  std::filesystem::copy_file(test::samples() / "levin09" / "kernel05.txt", dir / "images" / "kernel05.txt");
  const auto result = test::run("'" + test::crfcalBinary().string() + "' theory -q --images-dir '" +
                                (dir / "images").string() + "' -o '" + (dir / "out").string() + "'");
  ASSERT_EQ(result.exit_code, 0) << result.output;
  for (const char* name : {"fig3_step_edge.png", "fig3_step_edge.csv", "fig4_tv_results.png",
                           "fig4_tv_errors_signed.png", "fig4_tv.csv"})
    EXPECT_GT(std::filesystem::file_size(dir / "out" / name), 100u) << name;
  const cv::Mat results = cv::imread((dir / "out" / "fig4_tv_results.png").string());
  EXPECT_EQ(results.rows, 96);
  EXPECT_EQ(results.cols, 4 * 96 + 3 * 4);
}

}  // namespace
}  // namespace crfcal
