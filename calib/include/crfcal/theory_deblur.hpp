#pragma once
// Sec. 3.2 of the seed (Chen et al., ECCV 2012), made measurable: what the blur inconsistency does to deblurring.
//   Fig. 3: a step edge. The camera records B = ψ(φ(I) ⊗ K) = B̂ + P with B̂ = I ⊗ K and P = Γ (Eq. 17), so
//     deconvolving B with K gives B ⊗ K⁻¹ = I + P ⊗ K⁻¹ (Eq. 18): the artefact P ⊗ K⁻¹ rings around the edge.
//     K⁻¹ is applied as a Wiener filter (a box kernel has spectral zeros); the same filter on φ(B), mapped back by ψ,
//     shows the irradiance domain.
//   Fig. 4: TV deconvolution (deconvolution.hpp) of B and of B̂ of a photo: results and error maps against I.
// Pure computation on blur_model.hpp and deconvolution.hpp.
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_model.hpp"

namespace crfcal::theory {

struct StepEdgeOptions {
  double low = 0.1, high = 0.9;     // the step I: low on the left half, high on the right (Imax − Imin = 0.8)
  int width = 256, height = 32;     // image size; the step at column width / 2
  int kernel_length = 21;           // horizontal box kernel K (px)
  ResponseModel model = GammaModel{2.2};  // φ
  double wiener_nsr = 1e-2;         // regulariser of K⁻¹ (the box kernel's spectrum has zeros)
  void check() const;               // throws InvalidInput
};

// Profiles along the middle row.
struct StepEdgeResult {
  std::vector<double> sharp;                  // I
  std::vector<double> blurred;                // B = ψ(φ(I) ⊗ K)
  std::vector<double> intensity_blurred;      // B̂ = I ⊗ K
  std::vector<double> artefact;               // P = B − B̂
  std::vector<double> deconvolved;            // B ⊗ K⁻¹ = I + P ⊗ K⁻¹ (Eq. 18)
  std::vector<double> artefact_deconvolved;   // P ⊗ K⁻¹
  std::vector<double> irradiance_deconvolved; // ψ(φ(B) ⊗ K⁻¹)
  double max_ringing = 0;             // max |B ⊗ K⁻¹ − I| at ≥ 3 px from the step
  double max_irradiance_error = 0;    // max |ψ(φ(B) ⊗ K⁻¹) − I| at ≥ 3 px from the step
  std::string summary() const;
};

StepEdgeResult stepEdgeDeconvolution(const StepEdgeOptions& options = {});

struct TvComparisonOptions {
  ResponseModel model = GammaModel{2.2};  // φ of the simulated camera
  int border = 0;                         // px left out of the scores
};

struct TvComparison {
  cv::Mat sharp;                 // I
  cv::Mat blurred;               // B = ψ(φ(I) ⊗ K), 8-bit levels
  cv::Mat intensity_blurred;     // B̂ = I ⊗ K, 8-bit levels
  cv::Mat tv_blurred;            // TV deconvolution of B (intensity domain: the seed's failing case)
  cv::Mat tv_intensity_blurred;  // TV deconvolution of B̂ (no blur inconsistency)
  cv::Mat tv_irradiance;         // ψ(TV of φ(B)) (the irradiance domain)
  double psnr_tv_blurred = 0, psnr_tv_intensity_blurred = 0, psnr_tv_irradiance = 0;
  double ssim_tv_blurred = 0, ssim_tv_intensity_blurred = 0, ssim_tv_irradiance = 0;
  std::string summary() const;
};

// Fig. 4 on `sharp` (grey, [0,1]) blurred by `kernel`.
TvComparison tvComparison(const cv::Mat& sharp, const cv::Mat& kernel, const TvComparisonOptions& options = {});

}  // namespace crfcal::theory
