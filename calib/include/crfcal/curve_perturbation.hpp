#pragma once
// A response off by a chosen amount: for measuring what an estimation error of φ costs downstream (deblurring,
// `crfcal bench deblur`). φ_a = φ^a keeps φ(0) = 0, φ(1) = 1 and monotonicity, and bends the curve the way an error
// of a GGCM/gamma exponent does.
#include "crfcal/response_curve.hpp"

namespace crfcal {

// φ^a with a chosen so that the RMSE of φ^a − φ over [0,1] (1024 samples) is `target_rmse`; a > 1 (`steeper`) or
// a < 1. Throws InvalidInput when target_rmse is not in (0, 0.2] or cannot be reached.
ResponseCurve powerPerturbedCurve(const ResponseCurve& curve, double target_rmse, bool steeper = true);

// RMSE of φ_a − φ_b over [0,1] (1024 samples).
double curveRmse(const ResponseCurve& a, const ResponseCurve& b);

}  // namespace crfcal
