#include "crfcal/response_model.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/ggcm.hpp"

namespace crfcal {
namespace {

double interpolateSamples(std::span<const double> samples, double x) {
  const double position = std::clamp(x, 0.0, 1.0) * static_cast<double>(samples.size() - 1);
  const size_t i = std::min(static_cast<size_t>(position), samples.size() - 2);
  const double t = position - static_cast<double>(i);
  return samples[i] + t * (samples[i + 1] - samples[i]);
}

double evaluateEmor(const EmorModel& model, double x) {
  const double position = std::clamp(x, 0.0, 1.0) * (emor::kSamples - 1);
  const int i = std::min(static_cast<int>(position), emor::kSamples - 2);
  const double t = position - i;
  auto lerp = [&](std::span<const double, emor::kSamples> curve) {
    return curve[i] + t * (curve[i + 1] - curve[i]);
  };
  double value = lerp(emor::inverseMean());
  for (size_t k = 0; k < model.coefficients.size(); ++k)
    value += model.coefficients[k] * lerp(emor::inverseBasis(static_cast<int>(k) + 1));
  return value;
}

std::vector<double> parseNumbers(const std::string& text, const std::string& spec) {
  std::vector<double> values;
  std::stringstream stream(text);
  std::string item;
  while (std::getline(stream, item, ',')) {
    try {
      size_t used = 0;
      values.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw InvalidInput("response spec '" + spec + "': '" + item + "' is not a number");
    }
  }
  if (values.empty()) throw InvalidInput("response spec '" + spec + "' has no parameters");
  return values;
}

}  // namespace

double evaluateInverse(const ResponseModel& model, double x) {
  x = std::clamp(x, 0.0, 1.0);
  return std::visit(
      [x](const auto& m) -> double {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, GammaModel>) return std::pow(x, m.gamma);
        if constexpr (std::is_same_v<T, GgcmModel>) return ggcm::evaluate(m.alpha, x);
        if constexpr (std::is_same_v<T, EmorModel>) return evaluateEmor(m, x);
        if constexpr (std::is_same_v<T, TableModel>) return interpolateSamples(m.samples, x);
      },
      model);
}

std::vector<double> sampleInverse(const ResponseModel& model, int n) {
  std::vector<double> samples(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i) samples[static_cast<size_t>(i)] = evaluateInverse(model, double(i) / (n - 1));
  return samples;
}

std::vector<double> sampleValidTable(const ResponseModel& model, int n) {
  std::vector<double> phi = sampleInverse(model, n);
  phi.front() = 0.0;
  phi.back() = 1.0;
  for (std::size_t i = 1; i < phi.size(); ++i) phi[i] = std::clamp(phi[i], phi[i - 1], 1.0);
  return phi;
}

ModelValidity checkValidity(const ResponseModel& model, int grid, double tolerance) {
  if (const auto* g = std::get_if<GammaModel>(&model); g && !(g->gamma > 0 && std::isfinite(g->gamma)))
    return {false, "gamma must be positive"};
  if (const auto* p = std::get_if<GgcmModel>(&model)) {
    if (p->alpha.empty()) return {false, "GGCM needs at least one coefficient"};
    for (int i = 0; i < grid; ++i) {
      if (!(ggcm::polynomial(p->alpha, double(i) / (grid - 1)) > 0))
        return {false, "GGCM polynomial P(x) is not positive on [0,1]"};
    }
  }
  if (const auto* e = std::get_if<EmorModel>(&model); e && e->coefficients.size() > emor::kMaxTerms)
    return {false, "EMoR has at most 25 basis curves"};
  if (const auto* t = std::get_if<TableModel>(&model); t && t->samples.size() < 2)
    return {false, "a table needs at least 2 samples"};
  const std::vector<double> phi = sampleInverse(model, grid);
  for (double v : phi)
    if (!std::isfinite(v)) return {false, "curve is not finite"};
  if (std::abs(phi.front()) > tolerance) return {false, "phi(0) is not 0"};
  if (std::abs(phi.back() - 1.0) > tolerance) return {false, "phi(1) is not 1"};
  for (size_t i = 1; i < phi.size(); ++i) {
    if (phi[i] < phi[i - 1] - tolerance) {
      std::ostringstream why;
      why << "curve decreases near x = " << double(i) / (grid - 1);
      return {false, why.str()};
    }
  }
  return {};
}

std::string modelKind(const ResponseModel& model) {
  static const char* names[] = {"gamma", "ggcm", "emor", "table"};
  return names[model.index()];
}

std::string describe(const ResponseModel& model) {
  std::ostringstream out;
  out.precision(17);
  out << modelKind(model) << ':';
  auto list = [&](const std::vector<double>& values) {
    for (size_t i = 0; i < values.size(); ++i) out << (i ? "," : "") << values[i];
  };
  std::visit(
      [&](const auto& m) {
        using T = std::decay_t<decltype(m)>;
        if constexpr (std::is_same_v<T, GammaModel>) out << m.gamma;
        if constexpr (std::is_same_v<T, GgcmModel>) list(m.alpha);
        if constexpr (std::is_same_v<T, EmorModel>) list(m.coefficients);
        if constexpr (std::is_same_v<T, TableModel>) out << "<" << m.samples.size() << " samples>";
      },
      model);
  return out.str();
}

ResponseModel parseResponseSpec(const std::string& spec) {
  const auto colon = spec.find(':');
  if (colon == std::string::npos)
    throw InvalidInput("response spec '" + spec + "' must look like gamma:2.2, ggcm:a0,a1,..., emor:c1,... or table:FILE");
  const std::string kind = spec.substr(0, colon);
  const std::string rest = spec.substr(colon + 1);
  ResponseModel model;
  if (kind == "gamma") {
    const auto v = parseNumbers(rest, spec);
    if (v.size() != 1) throw InvalidInput("response spec '" + spec + "': gamma takes one number");
    model = GammaModel{v[0]};
  } else if (kind == "ggcm") {
    model = GgcmModel{parseNumbers(rest, spec)};
  } else if (kind == "emor") {
    model = EmorModel{parseNumbers(rest, spec)};
  } else if (kind == "table") {
    throw InvalidInput("response spec '" + spec + "': table:FILE must be read by crfcal::io::parseResponseSpec");
  } else {
    throw InvalidInput("response spec '" + spec + "': unknown model '" + kind + "' (gamma, ggcm, emor, table)");
  }
  if (auto validity = checkValidity(model); !validity)
    throw InvalidInput("response spec '" + spec + "': " + validity.reason);
  return model;
}

double curveRmse(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size() || a.empty()) throw InvalidInput("curveRmse: curves differ in length");
  double sum = 0;
  for (size_t i = 0; i < a.size(); ++i) sum += (a[i] - b[i]) * (a[i] - b[i]);
  return std::sqrt(sum / static_cast<double>(a.size()));
}

double curveRmse(const ResponseModel& a, const ResponseModel& b, int n) {
  return curveRmse(sampleInverse(a, n), sampleInverse(b, n));
}

}  // namespace crfcal
