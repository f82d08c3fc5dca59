// MomentResiduals with an EMoR curve forms H E and N E once (φ is linear in the EMoR coefficients): its data rows
// and their Jacobian must equal the direct products H φ, N φ at every point, to rounding.
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "../calib/src/crf_curve.hpp"
#include "../calib/src/crf_objective.hpp"

namespace crfcal::crf_fit {
namespace {

// A small random moment system: each row's masses on a few levels of I (H) and of B (N), row-scaled.
MomentSystem randomSystem(int rows, int levels, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  MomentSystem sys;
  sys.h = Eigen::MatrixXd::Zero(rows, levels);
  sys.n = Eigen::MatrixXd::Zero(rows, levels);
  for (int i = 0; i < rows; ++i) {
    const int centre = 20 + i * (levels - 40) / rows;
    for (int k = -6; k <= 6; ++k) sys.h(i, centre + k) = u(rng);
    sys.n(i, centre) = sys.h.row(i).sum();
    sys.v0.push_back(centre - 3);
    sys.v1.push_back(centre + 3);
    sys.row_scale.push_back(1.0);
  }
  sys.weight = rows;
  return sys;
}

// The data rows as the formula states them: norm · (r H φ − N φ) / slope, with φ from the curve.
Eigen::VectorXd directRows(const Curve& curve, const MomentSystem& sys, const Eigen::VectorXd& p, double r) {
  std::vector<double> f;
  EXPECT_TRUE(curve.values(p.data(), f, nullptr));
  Eigen::Map<const Eigen::VectorXd> fv(f.data(), sys.levels());
  const Eigen::VectorXd raw = r * (sys.h * fv) - sys.n * fv;
  const int L = sys.levels();
  Eigen::VectorXd rows(raw.size());
  for (int i = 0; i < raw.size(); ++i) {
    const double slope = (f[sys.v1[i]] - f[sys.v0[i]]) * (L - 1) / double(sys.v1[i] - sys.v0[i]);
    rows[i] = raw[i] / slope / std::sqrt(sys.weight);
  }
  return rows;
}

TEST(MomentResiduals, EmorRowsFromPrecomputedProductsEqualTheDirectProductsAndTheirJacobianTheDifferences) {
  std::mt19937 rng(7);
  const int levels = 256, rows = 60, terms = 5;
  const MomentSystem sys = randomSystem(rows, levels, rng);
  const Curve curve(Curve::kEmor, levels, terms);
  const MomentResiduals residuals(curve, sys, 2.0, true, false);
  std::normal_distribution<double> coefficient(0.0, 0.15);
  int compared = 0;
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::VectorXd p(terms + 1);
    for (int k = 0; k < terms; ++k) p[k] = coefficient(rng);
    p[terms] = std::log(1.5 + 0.5 * trial);
    Eigen::VectorXd res;
    Eigen::MatrixXd jac;
    if (!residuals(p, res, &jac)) continue;  // outside EMoR's monotone domain: nothing to compare
    ++compared;
    const Eigen::VectorXd direct = directRows(curve, sys, p, std::exp(p[terms]));
    ASSERT_GE(res.size(), rows);
    EXPECT_LE((res.head(rows) - direct).cwiseAbs().maxCoeff(), 1e-12 * (1 + direct.cwiseAbs().maxCoeff()));
    // Central differences of the direct rows against the analytic Jacobian (coefficients and log r).
    for (int j = 0; j <= terms; ++j) {
      const double h = 1e-6;
      Eigen::VectorXd up = p, down = p;
      up[j] += h;
      down[j] -= h;
      const Eigen::VectorXd numeric = (directRows(curve, sys, up, std::exp(up[terms])) -
                                       directRows(curve, sys, down, std::exp(down[terms]))) / (2 * h);
      EXPECT_LE((jac.col(j).head(rows) - numeric).cwiseAbs().maxCoeff(), 1e-5 * (1 + numeric.cwiseAbs().maxCoeff()))
          << "parameter " << j;
    }
  }
  EXPECT_GE(compared, 3);  // the points must mostly lie in EMoR's monotone domain, or the test says nothing
}

}  // namespace
}  // namespace crfcal::crf_fit
