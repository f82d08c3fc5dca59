#include "crfcal/noise_debias.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>

#include "crfcal/error.hpp"

namespace crfcal {

void NoiseDebiasOptions::check() const {
  if (levels < 2 || levels > 4096) throw InvalidInput("noise debias: levels must be in [2, 4096]");
  if (!(sigma >= 0 && sigma < 1)) throw InvalidInput("noise debias: sigma must be in [0, 1)");
  if (!(regularization > 0)) throw InvalidInput("noise debias: regularization must be positive");
  if (!sigma_per_level.empty()) {
    if (static_cast<int>(sigma_per_level.size()) != levels)
      throw InvalidInput("noise debias: sigma_per_level must have one entry per level");
    for (double s : sigma_per_level)
      if (!(s >= 0 && s < 1)) throw InvalidInput("noise debias: sigma_per_level entries must be in [0, 1)");
  }
}

NoiseDebias::NoiseDebias(const NoiseDebiasOptions& options) {
  options.check();
  levels_ = options.levels;
  const int n = levels_;
  std::vector<double> sig(n, options.sigma);
  if (!options.sigma_per_level.empty()) sig = options.sigma_per_level;
  double mean = 0, largest = 0;
  for (double s : sig) {
    mean += s / n;
    largest = std::max(largest, s);
  }
  sigma_ = mean;
  identity_ = largest * (n - 1) < 0.05;  // below 1/20 of a level the bias is negligible
  if (identity_) {
    r_ = Eigen::MatrixXd::Identity(n, n);
    t_ = r_;
    return;
  }
  const double step = 1.0 / (n - 1);
  auto cdf = [&](double z) { return 0.5 * std::erfc(-z / std::sqrt(2.0)); };
  t_.resize(n, n);
  for (int c = 0; c < n; ++c) {
    const double x = c * step;
    const double sc = std::max(sig[c], 1e-3 * step);
    for (int v = 0; v < n; ++v) {
      const double lo = v == 0 ? -1e9 : (v - 0.5) * step;
      const double hi = v == n - 1 ? 1e9 : (v + 0.5) * step;
      t_(c, v) = cdf((hi - x) / sc) - cdf((lo - x) / sc);
    }
  }
  Eigen::MatrixXd d2 = Eigen::MatrixXd::Zero(n - 2, n);
  for (int i = 0; i < n - 2; ++i) {
    d2(i, i) = 1;
    d2(i, i + 1) = -2;
    d2(i, i + 2) = 1;
  }
  const Eigen::MatrixXd tt = t_.transpose() * t_;
  const double lambda = options.regularization * tt.trace() / n;
  // (the smoothness product in its original order: the default operator stays bit-identical)
  const Eigen::MatrixXd a = options.regularizer == DebiasRegularizer::ridge
                                ? Eigen::MatrixXd(tt + lambda * Eigen::MatrixXd::Identity(n, n))
                                : Eigen::MatrixXd(tt + lambda * (d2.transpose() * d2) * static_cast<double>((n - 1)) * (n - 1));
  r_ = a.ldlt().solve(t_.transpose());
}

void NoiseDebias::apply(std::span<const double> f, std::span<double> g) const {
  if (static_cast<int>(f.size()) != levels_ || static_cast<int>(g.size()) != levels_)
    throw InvalidInput("noise debias: size mismatch");
  if (identity_) {
    std::copy(f.begin(), f.end(), g.begin());
    return;
  }
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), levels_);
  Eigen::Map<Eigen::VectorXd> gv(g.data(), levels_);
  gv = r_ * fv;
}

std::vector<double> NoiseDebias::apply(std::span<const double> f) const {
  std::vector<double> g(f.size());
  apply(f, g);
  return g;
}

}  // namespace crfcal
