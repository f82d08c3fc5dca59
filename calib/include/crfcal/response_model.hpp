#pragma once
// Parametric models of the inverse camera response φ: [0,1] → [0,1] (φ = ψ⁻¹, ψ the CRF).
// All models satisfy φ(0) = 0 and φ(1) = 1 when valid, and must be monotonically increasing (Sec. 3).
#include <string>
#include <variant>
#include <vector>

namespace crfcal {

// φ(x) = x^γ. γ > 1 gives a convex φ (Theorem 1), γ = 2.2 is the curve of the seed's Fig. 1.
struct GammaModel {
  double gamma = 2.2;
};

// Generalized Gamma Curve Model, Eq. 19: φ(x) = x^(1/P(x)), P(x) = Σ_{i=0..n} α_i x^i (n = 4 in the seed).
// Valid when P > 0 on [0,1] and φ is monotone.
struct GgcmModel {
  std::vector<double> alpha;  // α_0 … α_n
};

// EMoR / PCA inverse model (Grossberg & Nayar 2004): φ(x) = g0(x) + Σ_k c_k hinv_k(x), k = 1..K ≤ 25.
// g0 and hinv_k are the 1024-sample tables of invemor.txt (linear interpolation between samples).
struct EmorModel {
  std::vector<double> coefficients;  // c_1 … c_K
};

// A monotone curve given by samples φ(i/(n−1)), i = 0..n−1 (n ≥ 2), linear between samples.
struct TableModel {
  std::vector<double> samples;
};

using ResponseModel = std::variant<GammaModel, GgcmModel, EmorModel, TableModel>;

// Number of samples crfcal uses wherever a curve is exchanged (reports, truth files): x = i/1023.
inline constexpr int kCurveSamples = 1024;

// φ(x) for x in [0,1] (x is clamped).
double evaluateInverse(const ResponseModel& model, double x);

// φ at x = i/(n−1), i = 0..n−1.
std::vector<double> sampleInverse(const ResponseModel& model, int n = kCurveSamples);

// The same, made an exact table of a valid φ: φ(0) = 0, φ(1) = 1, non-decreasing (running maximum, clamped to 1).
// A model valid on a fine grid may still dip by rounding-level amounts near a flat shoulder that add up between
// two coarser samples; this is the table crfcal returns and writes.
std::vector<double> sampleValidTable(const ResponseModel& model, int n = kCurveSamples);

struct ModelValidity {
  bool valid = true;
  std::string reason;  // empty when valid
  explicit operator bool() const { return valid; }
};

// Whether the parameters give a usable φ: finite, φ(0) = 0 and φ(1) = 1 within `tolerance`, and
// non-decreasing on a grid of `grid` points (strictly: no step down larger than `tolerance`).
ModelValidity checkValidity(const ResponseModel& model, int grid = 4096, double tolerance = 1e-6);

// The command-line spelling of a model: "gamma:2.2", "ggcm:a0,a1,...", "emor:c1,...", "table:<n samples>".
std::string describe(const ResponseModel& model);

// Short kind name: "gamma", "ggcm", "emor", "table".
std::string modelKind(const ResponseModel& model);

// Parses "gamma:G", "ggcm:a0,a1,…", "emor:c1,c2,…" (the forms that need no file). Throws InvalidInput.
// "table:FILE" is handled by crfcal::io, which reads the file.
ResponseModel parseResponseSpec(const std::string& spec);

// Root-mean-square difference of two curves over n points of [0,1] (the benchmark's error, Sec. 5).
double curveRmse(const ResponseModel& a, const ResponseModel& b, int n = kCurveSamples);
double curveRmse(const std::vector<double>& a, const std::vector<double>& b);

}  // namespace crfcal
