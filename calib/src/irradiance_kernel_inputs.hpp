#pragma once
// Internal (not installed): the inputs of a blur kernel estimated in the irradiance domain, φ(I) against φ(B), where
// Eq. 4 is linear — shared by the pipeline's kernel↔φ rounds (pair_stage_rounds.cpp, pair_canvas.cpp) and a spatially
// varying blur's per-tile kernels (effect_refit.cpp).
#include <opencv2/core.hpp>

#include "crfcal/response_curve.hpp"

namespace crfcal::detail {

// The sharp image is the noisy (high-ISO) one; noise in ∂I biases the gradient-domain kernel regression (errors in
// variables: the kernel shrinks and spreads). As in [27], it is denoised first — an edge-preserving bilateral filter
// scaled to the estimated noise level — for kernel estimation only (the φ fit uses the raw I). Unit CV_64F in and out.
cv::Mat denoiseForKernel(const cv::Mat& image);

// Weights of the irradiance-domain kernel equations: 1 / φ'(B). The pixels' errors (noise, JPEG, the chroma of 4:2:0
// edges) are intensity errors, which φ multiplies by its slope; unweighted, the bright edges, where a convex φ is
// steepest, would dominate the regression with their amplified errors. φ' is a central difference over ±5 levels of 8
// bits (the fitted φ is smooth; the step only has to see past quantisation), floored at 1/50 of φ's mean slope (which
// is 1: φ(0) = 0, φ(1) = 1) so that the flat dark toe of a convex φ cannot take all the weight.
cv::Mat intensityScaleWeights(const ResponseCurve& curve, const cv::Mat& blurred);

}  // namespace crfcal::detail
