#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the saturated pixels of B as censored observations
// (CrfFitOptions::censored_weight; issue 19).
//
// With ΣK = 1, φ → bφ leaves Eq. 4 unchanged, so the data fix φ on the covered levels only up to a factor, and
// φ(1) = 1 is reached by extrapolation from the top of the data. Where B clips, Eq. 4 still says something:
// ψ(r · (φ(I) ⊗ K)) ≥ s (s = saturation_high), i.e. z_p = r · (φ(I) ⊗ K)(p) ≥ φ(s). At r > 1 the sharp shot under B's clipped pixels lies inside I's range, so these
// inequalities tie φ near 1 to φ at I's levels: the extrapolation that is otherwise guessed.
//
// Each clipped pixel p on the rim of a clipped region adds the censored-Gaussian negative log-likelihood
// −log Φ((z_p − φ(s)) / (φ'_top σ_p) + κ), κ a margin in σ (CrfFitOptions::censored_margin), as the row √λ · norm · σ_p · √(2 · nll): for a clear violation δ in B's
// intensity units it costs δ², the same as a data pixel misfit by δ (the moment rows are bin sums of per-pixel
// intensity residuals), and a pixel within its noise of the clip costs little either way. σ_p is the intensity
// noise of ψ(z_p): I's noise through the kernel (Σ_q K_q² φ'(I_q)², with the EMoR mean curve standing in for φ) and
// a floor for B (its noise, JPEG, resampling). Pixels whose support touches I's highlights (I clipped too says
// nothing: φ(I) ⊗ K would be biased low), B's black or the frame's border are not censored observations.
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>
#include <opencv2/core.hpp>

#include "crfcal/crf_fitter.hpp"

namespace crfcal::crf_fit {

struct Prepared;

// Picks the censored pixels (clipped B within the kernel's support of an unclipped pixel) into
// prep.censored_pixels / censored_side (+1; the rows also take −1, "below the clip", measured harmful and not
// selected); deterministic subsample to options.max_censored_pixels. Count: acc.censored_clipped. Nothing when
// options.censored_weight is 0.
void selectCensoredPixels(Prepared& prep, const cv::Rect& inside, const cv::Mat& unmodelled,
                          const CrfFitOptions& options, CrfPixelAccounting& acc);

// The censored pixels on the level grid: per pixel the kernel masses of I's levels (m_p = h_p · φ), its side, σ_p
// and its cross-validation fold.
struct CensoredRows {
  Eigen::SparseMatrix<double, Eigen::RowMajor> h;  // pixels × levels
  std::vector<double> side;                        // +1: B clipped; −1: B below the clip next to one
  std::vector<double> sigma;                       // σ_p of ψ(z_p), intensity units
  std::vector<int> fold;                           // 16×16 checkerboard tile, as the moments' folds
  double weight = 0;                               // λ (CrfFitOptions::censored_weight)
  double margin = 0;                               // κ (CrfFitOptions::censored_margin), in σ_p
  double sat_level = 0;                            // s · (L − 1): the clip on the level grid
  int slope_v0 = 0, slope_v1 = 0;                  // φ's secant over [v0, v1]: irradiance → B's intensity

  int rows() const { return static_cast<int>(h.rows()); }
  // The rows of fold f (0, 1), or all (−1).
  CensoredRows select(int f) const;
};

CensoredRows buildCensoredRows(const Prepared& prep, const CrfFitOptions& options);

// The censored rows appended to the moment residuals (MomentResiduals). norm: the data rows' 1/√(Σω).
class CensoredResiduals {
 public:
  CensoredResiduals(const CensoredRows& rows, double norm) : rows_(rows), norm_(norm) {}
  int count() const { return rows_.weight > 0 ? rows_.rows() : 0; }
  // res[offset .. offset + count()); false when φ's slope at the top is not positive.
  bool residuals(const std::vector<double>& f, double r, Eigen::VectorXd& res, int offset) const;
  // jm: d × L Jacobian of f (row-major); column d of jac is log r when fit_ratio.
  void jacobian(const std::vector<double>& f, const Eigen::MatrixXd& jm, double r, bool fit_ratio,
                const Eigen::VectorXd& res, int offset, Eigen::MatrixXd& jac) const;

 private:
  struct Terms {
    Eigen::VectorXd z;  // r · h φ
    double f_sat = 0, slope = 0;
  };
  bool terms(const std::vector<double>& f, double r, Terms& t) const;

  const CensoredRows& rows_;
  double norm_;
};

// −log Φ(t) and d/dt of it, accurate in both tails.
double negativeLogNormalCdf(double t);
double negativeLogNormalCdfDerivative(double t);

}  // namespace crfcal::crf_fit
