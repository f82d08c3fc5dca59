#include "float_gram.hpp"

#include <Eigen/Core>

namespace crfcal::detail {

VectorUnits widestVectorUnits() {
#if defined(CRFCAL_AVX2_GRAM) && (defined(__GNUC__) || defined(__clang__))
  static const VectorUnits units = [] {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") ? VectorUnits::avx2_fma
                                                                           : VectorUnits::baseline;
  }();
  return units;
#else
  return VectorUnits::baseline;
#endif
}

void lowerGram(const float* a, int rows, int cols, int lda, float* g, VectorUnits units) {
#if defined(CRFCAL_AVX2_GRAM)
  if (units == VectorUnits::avx2_fma && widestVectorUnits() == VectorUnits::avx2_fma) {
    lowerGramAvx2Fma(a, rows, cols, lda, g);
    return;
  }
#else
  (void)units;
#endif
  const Eigen::Map<const Eigen::MatrixXf, 0, Eigen::OuterStride<>> A(a, rows, cols, Eigen::OuterStride<>(lda));
  Eigen::Map<Eigen::MatrixXf> G(g, cols, cols);
  G.setZero();
  G.selfadjointView<Eigen::Lower>().rankUpdate(A.transpose());
}

}  // namespace crfcal::detail
