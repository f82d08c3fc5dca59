// The Gram matrix AᵀA of a single-precision block: the kernel's normal equations (kernel_estimation.cpp), about a
// fifth of a real pair's CPU time. Eigen's product compiled twice, for the x86-64 baseline (SSE2) and, where the
// compiler and the CPU have them, for AVX2 + FMA (float_gram_avx2.cpp, 3–4× faster on a 1024 × 600 block), chosen
// at run time. The two agree to float rounding (FMA rounds a product and its sum once), not to the bit.
#pragma once

namespace crfcal::detail {

enum class VectorUnits { baseline, avx2_fma };

// The widest units both this build and this CPU have.
VectorUnits widestVectorUnits();

// g (cols × cols, column-major, leading dimension cols) = AᵀA in the lower triangle and 0 above it, for A rows × cols,
// column-major with leading dimension lda ≥ rows. `units` beyond what the build has fall back to the baseline.
void lowerGram(const float* a, int rows, int cols, int lda, float* g, VectorUnits units);

// The AVX2 + FMA build of lowerGram (float_gram_avx2.cpp); only called when widestVectorUnits() says so.
void lowerGramAvx2Fma(const float* a, int rows, int cols, int lda, float* g);

}  // namespace crfcal::detail
