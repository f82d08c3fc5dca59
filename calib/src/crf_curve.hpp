#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the response models it fits, as parameter vectors sampled on a
// level grid with their Jacobians — GGCM (seed Eq. 19) and EMoR (Grossberg & Nayar's PCA basis).
#include <limits>
#include <span>
#include <vector>

#include "crfcal/response_model.hpp"

namespace crfcal::crf_fit {

constexpr int kGrid = 1024;  // validity grid (the EMoR nodes)
constexpr double kInf = std::numeric_limits<double>::infinity();

// Monotone, φ(0) = 0, φ(1) = 1 (checked on 4096 samples).
bool isValid(const ResponseModel& model);
bool monotone(const std::vector<double>& f);

// A curve sampled at x = i/(n−1) (n ≥ 2), linearly interpolated onto the L-level grid x = v/(L−1).
std::vector<double> onLevelGrid(std::span<const double> table, int L);

// Curve parameterisations: values on a grid (+ Jacobian).
class Curve {
 public:
  enum Kind { kGgcm, kEmor };
  // size: the GGCM degree n (n + 1 parameters) or the number of EMoR terms.
  Curve(Kind kind, int levels, int size);
  Kind kind() const { return kind_; }
  int dims() const { return dims_; }
  int levels() const { return levels_; }
  const char* name() const { return kind_ == kGgcm ? "ggcm" : "emor"; }

  // f on the levels (jac: dims × levels, row-major). False when the parameters are outside the model's domain.
  bool values(const double* x, std::vector<double>& f, std::vector<double>* jac) const {
    return sample(x, levels_, kind_ == kEmor ? &basis_levels_ : nullptr, f, jac);
  }
  // f on the kGrid validity grid.
  bool gridValues(const double* x, std::vector<double>& f, std::vector<double>* jac) const {
    return sample(x, kGrid, kind_ == kEmor ? &basis_grid_ : nullptr, f, jac);
  }
  ResponseModel model(const std::vector<double>& x) const;
  // EMoR only: the mean curve and the dims() basis functions on the levels, (dims() + 1) × levels, row-major (φ is
  // linear in the coefficients: f = row 0 + Σ_k x_k · row k).
  const std::vector<double>& emorBasisOnLevels() const { return basis_levels_; }
  // EMoR only: the same on the kGrid validity grid, (dims() + 1) × kGrid.
  const std::vector<double>& emorBasisOnGrid() const { return basis_grid_; }

 private:
  // GGCM's nodes x = v/(n−1) with what does not depend on α: log x and the powers x^j (the Jacobian's factors).
  struct GgcmNodes {
    std::vector<double> log_x;   // n (0 where x is 0 or 1: φ is pinned there)
    std::vector<double> powers;  // n × dims, row-major: x^0, x^1, … as ggcm::gradient forms them
  };
  static GgcmNodes ggcmNodes(int n, int dims);
  bool sample(const double* x, int n, const std::vector<double>* basis, std::vector<double>& f,
              std::vector<double>* jac) const;
  bool sampleGgcm(const double* alpha, int n, const GgcmNodes& nodes, std::vector<double>& f,
                  std::vector<double>* jac) const;

  Kind kind_;
  int levels_;
  int dims_;
  std::vector<double> basis_levels_, basis_grid_;
  GgcmNodes ggcm_levels_, ggcm_grid_;
};

}  // namespace crfcal::crf_fit
