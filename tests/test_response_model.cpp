// Response models: endpoints, monotonicity, exact inverse, LUTs, fitting sampled curves.
#include <cmath>

#include <gtest/gtest.h>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"
#include "crfcal/response_curve.hpp"
#include "crfcal/response_model.hpp"

namespace crfcal {
namespace {

TEST(ResponseModel, GammaEndpointsAndValues) {
  const ResponseModel gamma = GammaModel{2.2};
  EXPECT_DOUBLE_EQ(evaluateInverse(gamma, 0.0), 0.0);
  EXPECT_DOUBLE_EQ(evaluateInverse(gamma, 1.0), 1.0);
  EXPECT_NEAR(evaluateInverse(gamma, 0.5), std::pow(0.5, 2.2), 1e-15);
  EXPECT_TRUE(checkValidity(gamma));
}

TEST(ResponseModel, EmorBasisVanishesAtEndsAndMeanIsMonotone) {
  EXPECT_NEAR(emor::inverseMean()[0], 0.0, 1e-12);
  EXPECT_NEAR(emor::inverseMean()[1023], 1.0, 1e-12);
  for (int k = 1; k <= emor::kMaxTerms; ++k) {
    EXPECT_NEAR(emor::inverseBasis(k)[0], 0.0, 1e-9) << k;
    EXPECT_NEAR(emor::inverseBasis(k)[1023], 0.0, 1e-9) << k;
  }
  EXPECT_TRUE(checkValidity(EmorModel{}));
}

TEST(ResponseModel, GgcmOfGammaMatchesGamma) {
  const ResponseModel ggcm = ggcm::fromGamma(2.2);
  EXPECT_LT(curveRmse(ggcm, GammaModel{2.2}), 1e-12);
}

TEST(ResponseModel, InvalidGgcmIsRejected) {
  const ResponseModel negative = GgcmModel{{-0.5, 0, 0, 0, 0}};
  EXPECT_FALSE(checkValidity(negative));
  EXPECT_THROW(parseResponseSpec("ggcm:-0.5,0,0"), InvalidInput);
  // P positive but φ decreasing somewhere: P drops fast enough that x^(1/P) turns down
  const ResponseModel wiggly = GgcmModel{{0.2, 3.0, -6.0, 0.0, 3.0}};
  const auto validity = checkValidity(wiggly);
  EXPECT_FALSE(validity) << "expected non-monotone";
  EXPECT_FALSE(validity.reason.empty());
}

TEST(ResponseModel, SpecRoundTrip) {
  const ResponseModel model = parseResponseSpec("ggcm:0.45,0.1,-0.05,0.02,0.01");
  const ResponseModel again = parseResponseSpec(describe(model));
  EXPECT_LT(curveRmse(model, again), 1e-15);
  EXPECT_THROW(parseResponseSpec("gamma:abc"), InvalidInput);
  EXPECT_THROW(parseResponseSpec("spline:1,2"), InvalidInput);
}

TEST(ResponseCurve, ForwardIsExactInverseOfInverse) {
  const ResponseCurve curve(GammaModel{2.2});
  for (double x = 0; x <= 1.0; x += 1.0 / 997) {
    EXPECT_NEAR(curve.forward(curve.inverse(x)), x, 1e-12);
    EXPECT_NEAR(curve.inverse(x), std::pow(x, 2.2), 2e-8);
  }
  // ψ against the analytic inverse x^(1/2.2), away from the infinite slope at 0
  for (double y = 0.01; y <= 1.0; y += 0.01) EXPECT_NEAR(curve.forward(y), std::pow(y, 1 / 2.2), 1e-6);
}

TEST(ResponseCurve, LookupTablesMatchDirectEvaluation) {
  const ResponseCurve curve(ResponseModel{EmorModel{{0.3, -0.2, 0.05}}});
  for (int bits : {8, 16}) {
    const int top = (1 << bits) - 1;
    const auto& phi = curve.inverseLut(bits);
    const auto& psi = curve.forwardLut(bits);
    for (int v = 0; v <= top; v += bits == 8 ? 1 : 97) {
      EXPECT_DOUBLE_EQ(phi[static_cast<size_t>(v)], curve.inverse(double(v) / top));
      EXPECT_DOUBLE_EQ(psi[static_cast<size_t>(v)], curve.forward(double(v) / top));
    }
  }
  cv::Mat image8(1, 256, CV_8U);
  for (int v = 0; v < 256; ++v) image8.at<uchar>(0, v) = static_cast<uchar>(v);
  const cv::Mat phi = curve.inverse(image8);
  for (int v = 0; v < 256; ++v) EXPECT_DOUBLE_EQ(phi.at<double>(0, v), curve.inverse(v / 255.0));
}

TEST(ResponseCurve, RejectsInvalidSamples) {
  EXPECT_THROW(ResponseCurve::fromSamples({0.0, 0.6, 0.4, 1.0}), InvalidInput);
  EXPECT_THROW(ResponseCurve::fromSamples({0.1, 0.5, 1.0}), InvalidInput);
  EXPECT_NO_THROW(ResponseCurve::fromSamples({0.0, 0.2, 1.0}));
}

// A model valid on the fine validity grid (dips < 1e-6 per 1/4096 step) can dip by more between two of the 1024
// samples crfcal returns; the returned table must still be one that ResponseCurve accepts (a St. Louis pair stopped
// `calibrate` with "invalid response curve: curve decreases near x = 0.98" before sampleValidTable).
TEST(ResponseModel, ValidTableOfAModelWithRoundingDips) {
  std::vector<double> phi(kCurveSamples);
  for (int i = 0; i < kCurveSamples; ++i) phi[i] = double(i) / (kCurveSamples - 1);
  phi[1004] = phi[1003] - 3e-6;  // a dip of 3e-6 over one sample step
  const ResponseModel model = TableModel{phi};
  ASSERT_TRUE(checkValidity(model, 4096, 1e-6));
  EXPECT_THROW(ResponseCurve::fromSamples(sampleInverse(model)), InvalidInput);
  const std::vector<double> table = sampleValidTable(model);
  EXPECT_NO_THROW(ResponseCurve::fromSamples(table));
  EXPECT_EQ(table.front(), 0.0);
  EXPECT_EQ(table.back(), 1.0);
  const std::vector<double> raw = sampleInverse(model);
  for (int i = 1; i < kCurveSamples; ++i) {
    EXPECT_GE(table[i], table[i - 1]);
    EXPECT_NEAR(table[i], raw[i], 3e-6);
  }
}

TEST(CurveFit, GgcmRecoversRepresentableCurve) {
  const GgcmModel truth{{0.42, 0.15, -0.1, 0.05, 0.02}};
  const auto samples = sampleInverse(truth);
  const auto fit = ggcm::fitInverse(samples);
  EXPECT_TRUE(fit.valid);
  EXPECT_LT(fit.rmse, 1e-5);
}

TEST(CurveFit, GgcmFitsEmorMeanCurveClosely) {
  // The EMoR mean curve is a real-camera average; a degree-4 GGCM should follow it to well under 1 %.
  const auto samples = sampleInverse(EmorModel{});
  const auto fit = ggcm::fitInverse(samples);
  EXPECT_TRUE(fit.valid);
  EXPECT_LT(fit.rmse, 0.01);
  EXPECT_TRUE(checkValidity(fit.model));
}

TEST(CurveFit, EmorRecoversItsOwnCoefficients) {
  const EmorModel truth{{0.5, -0.3, 0.1, 0.05}};
  emor::FitOptions options;
  options.terms = 4;
  const auto fit = emor::fitInverse(sampleInverse(truth), options);
  ASSERT_EQ(fit.model.coefficients.size(), 4u);
  for (size_t k = 0; k < 4; ++k) EXPECT_NEAR(fit.model.coefficients[k], truth.coefficients[k], 1e-6);
  EXPECT_LT(fit.rmse, 1e-8);
}

TEST(CurveFit, EmorFitOfGammaIsMonotone) {
  const auto fit = emor::fitInverse(sampleInverse(GammaModel{2.2}), {});
  const auto validity = checkValidity(fit.model, 4096, 1e-9);
  EXPECT_TRUE(validity) << validity.reason;
  EXPECT_TRUE(fit.constrained);
  EXPECT_LT(fit.rmse, 0.01);
}

}  // namespace
}  // namespace crfcal
