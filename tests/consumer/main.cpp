// Uses the installed library: builds a GGCM curve, checks its exact inverse, prints "ok".
#include <cmath>
#include <cstdio>

#include "crfcal/ggcm.hpp"
#include "crfcal/io/response_io.hpp"
#include "crfcal/response_curve.hpp"

int main() {
  const crfcal::ResponseCurve curve(crfcal::ggcm::fromGamma(2.2));
  const double x = 0.37;
  if (std::abs(curve.forward(curve.inverse(x)) - x) > 1e-12) return 1;
  const auto model = crfcal::io::parseResponseSpec("gamma:2.2");
  std::printf("ok %s\n", crfcal::describe(model).c_str());
  return 0;
}
