#include "crf_curve.hpp"

#include <algorithm>
#include <cmath>

#include "crfcal/emor.hpp"
#include "crfcal/ggcm.hpp"

namespace crfcal::crf_fit {

bool isValid(const ResponseModel& model) { return static_cast<bool>(checkValidity(model, 4096, 1e-6)); }

bool monotone(const std::vector<double>& f) {
  for (std::size_t i = 1; i < f.size(); ++i)
    if (f[i] < f[i - 1]) return false;
  return true;
}

std::vector<double> onLevelGrid(std::span<const double> table, int L) {
  std::vector<double> f(L);
  const int n = static_cast<int>(table.size());
  for (int v = 0; v < L; ++v) {
    const double x = double(v) / (L - 1) * (n - 1);
    const int i = std::min(static_cast<int>(x), n - 2);
    f[v] = table[i] + (x - i) * (table[i + 1] - table[i]);
  }
  return f;
}

Curve::Curve(Kind kind, int levels, int size) : kind_(kind), levels_(levels), dims_(kind == kGgcm ? size + 1 : size) {
  if (kind_ == kGgcm) {
    ggcm_levels_ = ggcmNodes(levels_, dims_);
    ggcm_grid_ = ggcmNodes(kGrid, dims_);
    return;
  }
  basis_levels_.assign(static_cast<std::size_t>(dims_ + 1) * levels_, 0.0);
  basis_grid_.assign(static_cast<std::size_t>(dims_ + 1) * kGrid, 0.0);
  for (int k = 0; k <= dims_; ++k) {
    auto table = k == 0 ? emor::inverseMean() : emor::inverseBasis(k);
    for (int i = 0; i < kGrid; ++i) basis_grid_[k * kGrid + i] = table[i];
    for (int v = 0; v < levels_; ++v) {
      const double s = double(v) / (levels_ - 1) * (kGrid - 1);
      const int i = std::min(kGrid - 2, static_cast<int>(s));
      const double t = s - i;
      basis_levels_[k * levels_ + v] = (1 - t) * table[i] + t * table[i + 1];
    }
  }
}

ResponseModel Curve::model(const std::vector<double>& x) const {
  if (kind_ == kGgcm) return GgcmModel{x};
  return EmorModel{x};
}

Curve::GgcmNodes Curve::ggcmNodes(int n, int dims) {
  GgcmNodes nodes;
  nodes.log_x.assign(n, 0.0);
  nodes.powers.assign(static_cast<std::size_t>(n) * dims, 0.0);
  for (int v = 0; v < n; ++v) {
    const double xv = double(v) / (n - 1);
    if (xv > 0 && xv < 1) nodes.log_x[v] = std::log(xv);
    double power = 1;
    for (int j = 0; j < dims; ++j, power *= xv) nodes.powers[static_cast<std::size_t>(v) * dims + j] = power;
  }
  return nodes;
}

// ggcm::evaluate and ggcm::gradient at every node in one pass, the same operations in the same order (so the same
// bits), without their repeated polynomial, log and exp: P(x) once per node, log x and x^j from the table. The
// moment fits sample GGCM at every residual evaluation (a tenth of a vivo pair's CPU before).
bool Curve::sampleGgcm(const double* alpha, int n, const GgcmNodes& nodes, std::vector<double>& f,
                       std::vector<double>* jac) const {
  const std::span<const double> a(alpha, dims_);
  for (int v = 0; v < n; ++v) {
    const double xv = double(v) / (n - 1);
    const double p = ggcm::polynomial(a, xv);
    if (!(p > 1e-3)) return false;
    if (xv <= 0 || xv >= 1) {  // φ(0) = 0, φ(1) = 1, zero gradient (ggcm::evaluate, ggcm::gradient)
      f[v] = xv <= 0 ? 0.0 : 1.0;
      continue;
    }
    const double lx = nodes.log_x[v];
    const double phi = std::exp(lx / p);
    f[v] = phi;
    if (!std::isfinite(phi)) return false;
    if (!jac) continue;
    const double* power = nodes.powers.data() + static_cast<std::size_t>(v) * dims_;
    for (int j = 0; j < dims_; ++j) (*jac)[j * n + v] = -phi * lx / (p * p) * power[j];
  }
  return true;
}

bool Curve::sample(const double* x, int n, const std::vector<double>* basis, std::vector<double>& f,
                   std::vector<double>* jac) const {
  f.assign(n, 0.0);
  if (jac) jac->assign(static_cast<std::size_t>(dims_) * n, 0.0);
  if (kind_ == kGgcm) return sampleGgcm(x, n, n == levels_ ? ggcm_levels_ : ggcm_grid_, f, jac);
  const std::vector<double>& b = *basis;
  for (int v = 0; v < n; ++v) f[v] = b[v];
  for (int k = 1; k <= dims_; ++k) {
    const double c = x[k - 1];
    for (int v = 0; v < n; ++v) f[v] += c * b[k * n + v];
    if (jac)
      for (int v = 0; v < n; ++v) (*jac)[(k - 1) * n + v] = b[k * n + v];
  }
  return true;
}

}  // namespace crfcal::crf_fit
