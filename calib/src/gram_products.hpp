// Gram matrices AᵀA of blocks of rows, added into a lower triangle: the kernel's normal equations
// (kernel_estimation.cpp, single precision, about a fifth of a real pair's CPU time) and the spatially varying blur
// test's (effect_spatially_varying_blur.cpp, double). Eigen's product compiled twice, for the x86-64 baseline (SSE2)
// and, where the compiler and the CPU have them, for AVX2 + FMA (gram_products_avx2.cpp: 3–4× faster on a
// 1024 × 600 float block), chosen at run time. The two agree to rounding (FMA rounds a product and its sum once),
// not to the bit.
#pragma once

namespace crfcal::detail {

enum class VectorUnits { baseline, avx2_fma };

// The widest units both this build and this CPU have.
VectorUnits widestVectorUnits();

// g (cols × cols, column-major, leading dimension cols) += AᵀA in the lower triangle (the upper one is not touched),
// for A rows × cols, column-major with leading dimension lda ≥ rows. `units` beyond what the build and the CPU have
// fall back to the baseline.
void addLowerGram(const float* a, int rows, int cols, int lda, float* g, VectorUnits units);
void addLowerGram(const double* a, int rows, int cols, int lda, double* g, VectorUnits units);

// The AVX2 + FMA builds (gram_products_avx2.cpp); only called when widestVectorUnits() says so.
void addLowerGramAvx2Fma(const float* a, int rows, int cols, int lda, float* g);
void addLowerGramAvx2Fma(const double* a, int rows, int cols, int lda, double* g);

}  // namespace crfcal::detail
