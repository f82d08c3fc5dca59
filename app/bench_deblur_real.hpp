#pragma once
// `crfcal bench deblur --real DIR --reports CALDIR`: the phone triplets (DIR/noisy_N.jpg sharp, blurred_N.jpg blurred,
// g_truth_N.jpg a brighter, steadier reference) deblurred with their own calibration (CALDIR/N/report.json, from
// `crfcal calibrate DIR/noisy_N.jpg DIR/blurred_N.jpg -o CALDIR/N`) and scored against the reference.
#include <filesystem>

#include "crfcal/residual_deconvolution.hpp"

namespace crfcal::app {

int runRealDeblurBench(const std::filesystem::path& data, const std::filesystem::path& reports,
                       const ResidualDeconvolutionOptions& options);

}  // namespace crfcal::app
