// lowerGram (float_gram.hpp) compiled with -mavx2 -mfma (calib/CMakeLists.txt sets them on this file alone, on
// x86-64). Eigen's namespace is renamed in this file: its templates compiled for AVX2 must not be merged by the
// linker with the baseline copies the rest of crfcal instantiates under the same names, or a CPU without AVX2 could
// run them. For the same reason this file includes nothing but Eigen/Core and float_gram.hpp (no std templates
// of its own to merge).
#include "float_gram.hpp"

#if defined(CRFCAL_AVX2_GRAM) && defined(__AVX2__) && defined(__FMA__)
#define Eigen crfcal_eigen_avx2_fma
#include <Eigen/Core>

namespace crfcal::detail {

void lowerGramAvx2Fma(const float* a, int rows, int cols, int lda, float* g) {
  using namespace crfcal_eigen_avx2_fma;
  const Map<const MatrixXf, 0, OuterStride<>> A(a, rows, cols, OuterStride<>(lda));
  Map<MatrixXf> G(g, cols, cols);
  G.setZero();
  G.selfadjointView<Lower>().rankUpdate(A.transpose());
}

}  // namespace crfcal::detail
#undef Eigen
#endif
