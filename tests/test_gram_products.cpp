// calib/src/gram_products.hpp: Gram matrices AᵀA of blocks of rows added into a lower triangle, built for the x86-64
// baseline and for AVX2 + FMA. Both builds, in float and in double, add the exact AᵀA to rounding, into the lower
// triangle only, honouring a leading dimension larger than the rows (a partly filled block); asking for units the
// CPU lacks falls back.
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "../calib/src/gram_products.hpp"

namespace crfcal::detail {
namespace {

// A partly filled block: `rows` of `lda` rows used; the unused rows hold values that must not enter the product.
template <typename Scalar>
struct Block {
  int rows = 700, lda = 1024, cols = 83;
  std::vector<Scalar> a;
  Block() : a(static_cast<std::size_t>(lda) * cols) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> value(-1.0, 1.0);
    for (int j = 0; j < cols; ++j)
      for (int i = 0; i < lda; ++i)
        a[static_cast<std::size_t>(j) * lda + i] = i < rows ? static_cast<Scalar>(value(rng)) : Scalar(1e6);
  }
  long double exact(int p, int q) const {
    long double sum = 0;
    for (int i = 0; i < rows; ++i)
      sum += static_cast<long double>(a[static_cast<std::size_t>(p) * lda + i]) * a[static_cast<std::size_t>(q) * lda + i];
    return sum;
  }
};

// g starts at 2 everywhere: the lower triangle must become 2 + AᵀA, the upper one stay 2.
template <typename Scalar>
void expectAddedLowerGram(VectorUnits units, double tolerance) {
  const Block<Scalar> block;
  std::vector<Scalar> g(static_cast<std::size_t>(block.cols) * block.cols, Scalar(2));
  addLowerGram(block.a.data(), block.rows, block.cols, block.lda, g.data(), units);
  double worst = 0;
  for (int q = 0; q < block.cols; ++q)
    for (int p = 0; p < block.cols; ++p) {
      const Scalar got = g[static_cast<std::size_t>(q) * block.cols + p];
      if (p < q) {
        ASSERT_EQ(got, Scalar(2)) << "above the diagonal at (" << p << ", " << q << ")";
      } else {
        worst = std::max(worst, static_cast<double>(std::abs(got - (2 + block.exact(p, q)))));
      }
    }
  EXPECT_LT(worst, tolerance);
}

// Each entry sums 700 products of magnitude ≤ 1 (|sum| ≤ 700): a few ulps of 700 per step at most.
constexpr double kFloatTolerance = 1e-3, kDoubleTolerance = 1e-11;

TEST(GramProducts, BaselineBuildAddsTheLowerGramOfTheUsedRowsToRounding) {
  expectAddedLowerGram<float>(VectorUnits::baseline, kFloatTolerance);
  expectAddedLowerGram<double>(VectorUnits::baseline, kDoubleTolerance);
}

TEST(GramProducts, WidestBuildThisCpuHasAddsTheSameGramAndAbsentUnitsFallBack) {
  // Without AVX2 + FMA (in the build or the CPU) the widest units are the baseline: the same checks on that build.
  expectAddedLowerGram<float>(widestVectorUnits(), kFloatTolerance);
  expectAddedLowerGram<double>(widestVectorUnits(), kDoubleTolerance);
  expectAddedLowerGram<float>(VectorUnits::avx2_fma, kFloatTolerance);
  expectAddedLowerGram<double>(VectorUnits::avx2_fma, kDoubleTolerance);
}

}  // namespace
}  // namespace crfcal::detail
