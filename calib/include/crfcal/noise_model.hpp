#pragma once
// Signal-dependent (Poisson–Gaussian) sensor noise and how it looks after the camera curve.
//
// The seed's Sec. 5 adds homoscedastic Gaussian noise to the intensities I. A sensor's noise lives in the
// irradiance (RAW) domain and grows with the signal: var(x) = a·x + b (x = normalised RAW; a = shot noise / gain,
// b = read noise; darktable's per-camera profiles). Through the camera curve I = ψ(x), first order:
//     σ_I(v) = ψ'(φ(v)) · sqrt(a·φ(v) + b) = sqrt(a·φ(v) + b) / φ'(v)
// (a "gain" g that divides the signal — an underexposed shot brightened by ISO — scales a by 1/g; here a, b
// are given for the signal as recorded). For a convex φ (concave ψ), ψ' is large in the darks and small in the
// highlights, so the intensity-domain noise is far from constant: large in the shadows, small near white.
//
// Also: a measurement of σ as a function of intensity from one image (local residuals binned by the local mean),
// and a pair simulator that adds the noise in the irradiance domain (the seed's simulatePair adds it to I).
#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"
#include "crfcal/simulation.hpp"

namespace crfcal {

struct PoissonGaussianNoise {
  double a = 0;  // variance per unit signal (shot noise)
  double b = 0;  // signal-independent variance (read noise); may be slightly negative in fitted profiles
  double variance(double x) const;  // max(a·x + b, 0)
};

// σ_I(v) at intensity v ∈ [0, 1] for the curve φ (derivative by central differences on the curve's grid).
double intensityNoiseSigma(const ResponseCurve& curve, const PoissonGaussianNoise& noise, double v);

// Irradiance-domain noise: x + N(0, a·x + b), clipped to [0, 1]. CV_64F in and out. Deterministic per seed.
cv::Mat addPoissonGaussianNoise(const cv::Mat& irradiance, const PoissonGaussianNoise& noise, std::uint64_t seed);

struct RealisticSimulationOptions {
  double ratio = 1.0;              // r of Eq. 4
  PoissonGaussianNoise sharp_noise;    // noise of the short (high-ISO) exposure I, irradiance domain
  PoissonGaussianNoise blurred_noise;  // noise of the long exposure B (irradiance domain, after r)
  int bits = 8;
  std::uint64_t seed = 1;
  void check() const;  // throws InvalidInput
};

// Like simulatePair with image_is_irradiance = true, but I = ψ(Ĩ + n_I) and B = ψ(clip(r·(Ĩ ⊗ K)) + n_B), the
// noise signal-dependent in the irradiance domain. sharp_clean = ψ(Ĩ).
SimulationResult simulatePairPoissonGaussian(const cv::Mat& image, const ResponseModel& model, const cv::Mat& kernel,
                                             const RealisticSimulationOptions& options = {});

// ---- measuring noise as a function of intensity --------------------------------------------------------------
struct NoiseLevelOptions {
  int bins = 12;                // equal-width bins of the local mean over [low, high]
  double low = 0.02, high = 0.98;
  int min_samples = 200;        // bins with fewer pixels are dropped
  double flat_quantile = 0.5;   // keep the flattest fraction of pixels in each bin (by local gradient), edges leak
  void check() const;
};

struct NoiseLevelBin {
  double intensity = 0;  // mean of the local means in the bin
  double sigma = 0;      // robust std (1.4826 · MAD of the σ-normalised Laplacian residual)
  int samples = 0;
};

// Local residual: Immerkær's operator (maps white noise of std σ to std σ, cancels locally linear signal);
// local mean: 5×5 box; per bin, the flattest pixels are kept. `image`: single channel, any depth.
std::vector<NoiseLevelBin> measureNoiseLevels(const cv::Mat& image, const NoiseLevelOptions& options = {});

// Weighted least-squares fit of var = a·x + b to (x, σ) pairs (x in the domain the noise is modelled in).
// Throws InvalidInput for fewer than 2 points.
PoissonGaussianNoise fitPoissonGaussian(const std::vector<double>& x, const std::vector<double>& sigma,
                                        const std::vector<double>& weights = {});

// The intensity-domain bins mapped to irradiance (x = φ(v), σ_x = φ'(v)·σ_v) and fitted with var = a·x + b.
PoissonGaussianNoise fitPoissonGaussianThroughCurve(const std::vector<NoiseLevelBin>& bins, const ResponseCurve& curve);

// RMS of log(σ_model / σ_measured) over the bins (a scale-free misfit; 0 = perfect).
double logSigmaMisfit(const std::vector<NoiseLevelBin>& bins, const std::vector<double>& model_sigma);

}  // namespace crfcal
