// The fitter's GGCM sampling (calib/src/crf_curve.*, internal) evaluates φ and its Jacobian at every node in one
// pass with log x and x^j tabulated; it must give the bits of ggcm::evaluate and ggcm::gradient node by node, so
// that every fit and report stays what it was before the one-pass form (stop 32, docs/RESULTS.md#speed-small).
#include <cmath>
#include <vector>

#include <gtest/gtest.h>

#include "../calib/src/crf_curve.hpp"
#include "crfcal/ggcm.hpp"

namespace crfcal {
namespace {

void expectSameBits(const crf_fit::Curve& curve, const std::vector<double>& alpha, int nodes, bool grid) {
  std::vector<double> f, jac;
  const bool ok = grid ? curve.gridValues(alpha.data(), f, &jac) : curve.values(alpha.data(), f, &jac);
  ASSERT_TRUE(ok);
  ASSERT_EQ(static_cast<int>(f.size()), nodes);
  const int dims = static_cast<int>(alpha.size());
  std::vector<double> g(dims);
  for (int v = 0; v < nodes; ++v) {
    const double x = double(v) / (nodes - 1);
    EXPECT_EQ(f[v], ggcm::evaluate(alpha, x)) << "node " << v;
    ggcm::gradient(alpha, x, g);
    for (int j = 0; j < dims; ++j) EXPECT_EQ(jac[j * nodes + v], g[j]) << "node " << v << ", parameter " << j;
  }
}

TEST(CrfCurveSampling, GgcmOnePassGivesTheBitsOfEvaluateAndGradient) {
  const crf_fit::Curve curve(crf_fit::Curve::kGgcm, 256, 4);
  for (const std::vector<double>& alpha : {std::vector<double>{1 / 2.2, 0, 0, 0, 0},
                                           std::vector<double>{0.45, 0.3, -0.2, 0.05, 0.01},
                                           std::vector<double>{1.2, -0.6, 0.4, -0.1, 0.02}}) {
    expectSameBits(curve, alpha, 256, false);
    expectSameBits(curve, alpha, crf_fit::kGrid, true);
  }
}

TEST(CrfCurveSampling, GgcmOutsideItsDomainIsRejected) {
  const crf_fit::Curve curve(crf_fit::Curve::kGgcm, 256, 1);
  std::vector<double> f;
  const std::vector<double> negative_p{-0.5, 0.1};  // P(x) < 1e-3 everywhere: φ = x^(1/P) undefined
  EXPECT_FALSE(curve.values(negative_p.data(), f, nullptr));
}

}  // namespace
}  // namespace crfcal
