// MomentResiduals with an EMoR curve forms H E and N E once (φ is linear in the EMoR coefficients): its data rows
// and their Jacobian must equal the direct products H φ, N φ at every point, to rounding. With a GGCM curve it
// multiplies by H and N's non-zeros when they are sparse: the same check.
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "../calib/src/crf_curve.hpp"
#include "../calib/src/crf_objective.hpp"
#include "crfcal/ggcm.hpp"

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

// The data rows and their Jacobian (coefficients and log r) against the direct products and their central
// differences, at `points` parameter vectors; returns how many points lay in the curve's domain.
int compareWithDirectProducts(const Curve& curve, const MomentSystem& sys, const std::vector<Eigen::VectorXd>& points) {
  const int rows = static_cast<int>(sys.h.rows()), dims = curve.dims();
  const MomentResiduals residuals(curve, sys, 2.0, true, false);
  int compared = 0;
  for (const Eigen::VectorXd& p : points) {
    Eigen::VectorXd res;
    Eigen::MatrixXd jac;
    if (!residuals(p, res, &jac)) continue;
    ++compared;
    const Eigen::VectorXd direct = directRows(curve, sys, p, std::exp(p[dims]));
    EXPECT_LE((res.head(rows) - direct).cwiseAbs().maxCoeff(), 1e-12 * (1 + direct.cwiseAbs().maxCoeff()));
    for (int j = 0; j <= dims; ++j) {
      const double h = 1e-6;
      Eigen::VectorXd up = p, down = p;
      up[j] += h;
      down[j] -= h;
      const Eigen::VectorXd numeric = (directRows(curve, sys, up, std::exp(up[dims])) -
                                       directRows(curve, sys, down, std::exp(down[dims]))) / (2 * h);
      EXPECT_LE((jac.col(j).head(rows) - numeric).cwiseAbs().maxCoeff(), 1e-5 * (1 + numeric.cwiseAbs().maxCoeff()))
          << "parameter " << j;
    }
  }
  return compared;
}

TEST(MomentResiduals, EmorRowsFromPrecomputedProductsEqualTheDirectProductsAndTheirJacobianTheDifferences) {
  std::mt19937 rng(7);
  const int levels = 256, rows = 60, terms = 5;
  const MomentSystem sys = randomSystem(rows, levels, rng);
  const Curve curve(Curve::kEmor, levels, terms);
  std::normal_distribution<double> coefficient(0.0, 0.15);
  std::vector<Eigen::VectorXd> points;
  for (int trial = 0; trial < 5; ++trial) {
    Eigen::VectorXd p(terms + 1);
    for (int k = 0; k < terms; ++k) p[k] = coefficient(rng);
    p[terms] = std::log(1.5 + 0.5 * trial);
    points.push_back(p);
  }
  // the points must mostly lie in EMoR's monotone domain, or the test says nothing
  EXPECT_GE(compareWithDirectProducts(curve, sys, points), 3);
}

TEST(MomentResiduals, GgcmRowsFromSparseAndDenseProductsEqualTheDirectProductsAndTheirJacobianTheDifferences) {
  std::mt19937 rng(11);
  const int levels = 256, rows = 60, degree = 4;
  const Curve curve(Curve::kGgcm, levels, degree);
  std::vector<Eigen::VectorXd> points;
  std::normal_distribution<double> jitter(0.0, 0.02);
  for (double gamma : {1.8, 2.2, 2.6}) {
    const std::vector<double> alpha = ggcm::fromGamma(gamma, degree).alpha;
    Eigen::VectorXd p(curve.dims() + 1);
    for (int k = 0; k < curve.dims(); ++k) p[k] = alpha[static_cast<std::size_t>(k)] + jitter(rng);
    p[curve.dims()] = std::log(gamma);
    points.push_back(p);
  }
  // 13 of 256 levels per row of H, one of N: stored by their non-zeros.
  const MomentSystem sparse = randomSystem(rows, levels, rng);
  EXPECT_EQ(compareWithDirectProducts(curve, sparse, points), 3);
  // Every level of H filled: multiplied densely.
  MomentSystem dense = sparse;
  std::uniform_real_distribution<double> u(0.0, 0.01);
  for (int i = 0; i < rows; ++i)
    for (int v = 0; v < levels; ++v) dense.h(i, v) += u(rng);
  EXPECT_EQ(compareWithDirectProducts(curve, dense, points), 3);
}

}  // namespace
}  // namespace crfcal::crf_fit
