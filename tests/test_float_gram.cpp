// calib/src/float_gram.hpp: the kernel's Gram matrices AᵀA from single-precision blocks, built for the x86-64
// baseline and for AVX2 + FMA. Both builds give the double-precision AᵀA to float rounding, in the lower triangle,
// with zeros above; a leading dimension larger than the rows (a partly filled block) is honoured.
#include <random>
#include <vector>

#include <Eigen/Core>
#include <gtest/gtest.h>

#include "../calib/src/float_gram.hpp"

namespace crfcal::detail {
namespace {

// A partly filled block: `rows` of `lda` rows used; the unused rows hold values that must not enter the product.
struct Block {
  int rows = 700, lda = 1024, cols = 83;
  std::vector<float> a;
  Block() : a(static_cast<std::size_t>(lda) * cols) {
    std::mt19937 rng(7);
    std::uniform_real_distribution<float> value(-1.0f, 1.0f);
    for (int j = 0; j < cols; ++j)
      for (int i = 0; i < lda; ++i) a[static_cast<std::size_t>(j) * lda + i] = i < rows ? value(rng) : 1e6f;
  }
  double reference(int p, int q) const {
    double sum = 0;
    for (int i = 0; i < rows; ++i)
      sum += double(a[static_cast<std::size_t>(p) * lda + i]) * double(a[static_cast<std::size_t>(q) * lda + i]);
    return sum;
  }
};

void expectLowerGram(const Block& block, VectorUnits units) {
  std::vector<float> g(static_cast<std::size_t>(block.cols) * block.cols, -5.0f);
  lowerGram(block.a.data(), block.rows, block.cols, block.lda, g.data(), units);
  double worst = 0;
  for (int q = 0; q < block.cols; ++q)
    for (int p = 0; p < block.cols; ++p) {
      const float got = g[static_cast<std::size_t>(q) * block.cols + p];
      if (p < q) {
        ASSERT_EQ(got, 0.0f) << "above the diagonal at (" << p << ", " << q << ")";
      } else {
        worst = std::max(worst, std::abs(got - block.reference(p, q)));
      }
    }
  // Each entry sums 700 products of magnitude ≤ 1 in float: a few ulps of the sum (≤ 700) each step.
  EXPECT_LT(worst, 1e-3);
}

TEST(FloatGram, BaselineBuildGivesTheLowerGramOfTheUsedRowsToFloatRounding) {
  expectLowerGram(Block{}, VectorUnits::baseline);
}

TEST(FloatGram, WidestBuildThisCpuHasGivesTheSameGramToFloatRounding) {
  // On a CPU or a build without AVX2 + FMA the widest units are the baseline: the same check, on that build.
  expectLowerGram(Block{}, widestVectorUnits());
  // Asking for AVX2 where it is absent falls back rather than running instructions the CPU lacks.
  expectLowerGram(Block{}, VectorUnits::avx2_fma);
}

}  // namespace
}  // namespace crfcal::detail
