#include "gram_products.hpp"

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

namespace {

template <typename Scalar>
void addLowerGramBaseline(const Scalar* a, int rows, int cols, int lda, Scalar* g) {
  using Matrix = Eigen::Matrix<Scalar, Eigen::Dynamic, Eigen::Dynamic>;
  const Eigen::Map<const Matrix, 0, Eigen::OuterStride<>> A(a, rows, cols, Eigen::OuterStride<>(lda));
  Eigen::Map<Matrix> G(g, cols, cols);
  G.template selfadjointView<Eigen::Lower>().rankUpdate(A.transpose());
}

template <typename Scalar>
void addLowerGramOn(const Scalar* a, int rows, int cols, int lda, Scalar* g, VectorUnits units) {
#if defined(CRFCAL_AVX2_GRAM)
  if (units == VectorUnits::avx2_fma && widestVectorUnits() == VectorUnits::avx2_fma) {
    addLowerGramAvx2Fma(a, rows, cols, lda, g);
    return;
  }
#else
  (void)units;
#endif
  addLowerGramBaseline(a, rows, cols, lda, g);
}

}  // namespace

void addLowerGram(const float* a, int rows, int cols, int lda, float* g, VectorUnits units) {
  addLowerGramOn(a, rows, cols, lda, g, units);
}

void addLowerGram(const double* a, int rows, int cols, int lda, double* g, VectorUnits units) {
  addLowerGramOn(a, rows, cols, lda, g, units);
}

}  // namespace crfcal::detail
