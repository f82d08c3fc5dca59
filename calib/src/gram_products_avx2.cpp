// addLowerGram (gram_products.hpp) compiled with -mavx2 -mfma (calib/CMakeLists.txt sets them on this file alone, on
// x86-64). Eigen's namespace is renamed in this file: its templates compiled for AVX2 must not be merged by the
// linker with the baseline copies the rest of crfcal instantiates under the same names, or a CPU without AVX2 could
// run them. For the same reason this file includes nothing but Eigen/Core and gram_products.hpp (no std templates
// of its own to merge; `nm -C` on its object lists weak symbols in the renamed namespace only).
#include "gram_products.hpp"

#if defined(CRFCAL_AVX2_GRAM) && defined(__AVX2__) && defined(__FMA__)
#define Eigen crfcal_eigen_avx2_fma
#include <Eigen/Core>

namespace crfcal::detail {
namespace {

template <typename Scalar>
void addLowerGramWide(const Scalar* a, int rows, int cols, int lda, Scalar* g) {
  using namespace crfcal_eigen_avx2_fma;
  using Mat = Matrix<Scalar, Dynamic, Dynamic>;
  const Map<const Mat, 0, OuterStride<>> A(a, rows, cols, OuterStride<>(lda));
  Map<Mat> G(g, cols, cols);
  G.template selfadjointView<Lower>().rankUpdate(A.transpose());
}

}  // namespace

void addLowerGramAvx2Fma(const float* a, int rows, int cols, int lda, float* g) {
  addLowerGramWide(a, rows, cols, lda, g);
}

void addLowerGramAvx2Fma(const double* a, int rows, int cols, int lda, double* g) {
  addLowerGramWide(a, rows, cols, lda, g);
}

}  // namespace crfcal::detail
#undef Eigen
#endif
