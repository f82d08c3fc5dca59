#include "crfcal/colour_mixing.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <nlopt.hpp>

#include "crfcal/error.hpp"

namespace crfcal {

const char* toString(ColourModelKind kind) {
  switch (kind) {
    case ColourModelKind::pointwise: return "pointwise";
    case ColourModelKind::mix: return "mix3x3";
    case ColourModelKind::mix_clip: return "mix3x3+clip";
    case ColourModelKind::mix_clip_post: return "mix3x3+clip+post";
  }
  return "?";
}

std::vector<ColourModelKind> allColourModelKinds() {
  return {ColourModelKind::pointwise, ColourModelKind::mix, ColourModelKind::mix_clip,
          ColourModelKind::mix_clip_post};
}

void ColourFitOptions::check() const {
  if (knots < 2 || knots > 64) throw InvalidInput("colour fit: knots must be in [2, 64]");
  if (!(smoothness >= 0)) throw InvalidInput("colour fit: smoothness must be >= 0");
  if (max_evaluations < 10) throw InvalidInput("colour fit: max_evaluations must be >= 10");
}

double ColourModel::curveValue(int channel, double x) const {
  const auto& v = curve[static_cast<size_t>(channel)];
  const size_t n = knots.size();
  const bool extrapolate = kind == ColourModelKind::mix;
  if (x <= knots[0]) {
    if (!extrapolate) return v[0];
    return v[0] + (v[1] - v[0]) / (knots[1] - knots[0]) * (x - knots[0]);
  }
  if (x >= knots[n - 1]) {
    if (!extrapolate) return v[n - 1];
    return v[n - 1] + (v[n - 1] - v[n - 2]) / (knots[n - 1] - knots[n - 2]) * (x - knots[n - 1]);
  }
  const auto it = std::upper_bound(knots.begin(), knots.end(), x);
  const size_t k = static_cast<size_t>(it - knots.begin()) - 1;
  const double t = (x - knots[k]) / (knots[k + 1] - knots[k]);
  return v[k] + t * (v[k + 1] - v[k]);
}

std::array<double, 3> ColourModel::predict(const std::array<double, 3>& raw) const {
  const Eigen::Vector3d r(raw[0], raw[1], raw[2]);
  Eigen::Vector3d m = mix * r;
  const bool clip = kind == ColourModelKind::mix_clip || kind == ColourModelKind::mix_clip_post;
  Eigen::Vector3d f;
  for (int c = 0; c < 3; ++c) f[c] = curveValue(c, clip ? std::clamp(m[c], 0.0, 1.0) : m[c]);
  if (kind == ColourModelKind::mix_clip_post) f = post * f;
  return {std::clamp(f[0], 0.0, 1.0), std::clamp(f[1], 0.0, 1.0), std::clamp(f[2], 0.0, 1.0)};
}

double colourRmse(const ColourModel& model, const std::vector<ColourSample>& samples) {
  double sum = 0, weight = 0;
  for (const auto& s : samples) {
    const auto p = model.predict(s.raw);
    for (int c = 0; c < 3; ++c) {
      const double d = p[static_cast<size_t>(c)] - s.jpeg[static_cast<size_t>(c)];
      sum += s.weight * d * d;
    }
    weight += 3 * s.weight;
  }
  return weight > 0 ? std::sqrt(sum / weight) : 0.0;
}

std::string ColourFitResult::summary() const {
  std::ostringstream s;
  s << toString(model.kind) << ": train RMSE " << train_rmse * 255 << " (8-bit), " << evaluations << " evaluations";
  return s.str();
}

namespace {

// Parameter layout: [mix: 3 (diag) or 9] [post: 9 if mix_clip_post] [per channel: b, δ_1..δ_K].
struct Layout {
  ColourModelKind kind;
  int knots;
  int mixCount() const { return kind == ColourModelKind::pointwise ? 3 : 9; }
  int postCount() const { return kind == ColourModelKind::mix_clip_post ? 9 : 0; }
  int curveStart() const { return mixCount() + postCount(); }
  int size() const { return curveStart() + 3 * (knots + 1); }
};

std::vector<double> makeKnots(int k) {
  std::vector<double> t(static_cast<size_t>(k + 1));
  for (int i = 0; i <= k; ++i) t[static_cast<size_t>(i)] = std::pow(double(i) / k, 2.0);
  return t;
}

ColourModel unpack(const Layout& layout, const std::vector<double>& knots, const double* p) {
  ColourModel m;
  m.kind = layout.kind;
  m.knots = knots;
  if (layout.kind == ColourModelKind::pointwise) {
    m.mix = Eigen::Matrix3d::Zero();
    for (int c = 0; c < 3; ++c) m.mix(c, c) = p[c];
  } else {
    for (int i = 0; i < 9; ++i) m.mix(i / 3, i % 3) = p[i];
  }
  if (layout.postCount() > 0)
    for (int i = 0; i < 9; ++i) m.post(i / 3, i % 3) = p[layout.mixCount() + i];
  for (int c = 0; c < 3; ++c) {
    const double* q = p + layout.curveStart() + c * (layout.knots + 1);
    auto& v = m.curve[static_cast<size_t>(c)];
    v.resize(static_cast<size_t>(layout.knots + 1));
    v[0] = q[0];
    for (int k = 1; k <= layout.knots; ++k) v[static_cast<size_t>(k)] = v[static_cast<size_t>(k - 1)] + q[k];
  }
  return m;
}

std::vector<double> pack(const Layout& layout, const ColourModel& m) {
  std::vector<double> p(static_cast<size_t>(layout.size()));
  if (layout.kind == ColourModelKind::pointwise) {
    for (int c = 0; c < 3; ++c) p[static_cast<size_t>(c)] = m.mix(c, c);
  } else {
    for (int i = 0; i < 9; ++i) p[static_cast<size_t>(i)] = m.mix(i / 3, i % 3);
  }
  if (layout.postCount() > 0)
    for (int i = 0; i < 9; ++i) p[static_cast<size_t>(layout.mixCount() + i)] = m.post(i / 3, i % 3);
  for (int c = 0; c < 3; ++c) {
    const auto& v = m.curve[static_cast<size_t>(c)];
    double* q = p.data() + layout.curveStart() + c * (layout.knots + 1);
    q[0] = v[0];
    for (int k = 1; k <= layout.knots; ++k) q[k] = std::max(0.0, v[static_cast<size_t>(k)] - v[static_cast<size_t>(k - 1)]);
  }
  return p;
}

struct Problem {
  Layout layout;
  std::vector<double> knots;
  const std::vector<ColourSample>* samples;
  double weight_sum;
  double smoothness;
  int evaluations = 0;

  // Cost and (if grad) its analytic gradient. The model is piecewise linear: derivatives are one-sided at knots.
  double cost(const double* p, double* grad) const {
    const ColourModel m = unpack(layout, knots, p);
    const int n = layout.size();
    if (grad) std::fill(grad, grad + n, 0.0);
    const bool clip = layout.kind == ColourModelKind::mix_clip || layout.kind == ColourModelKind::mix_clip_post;
    const bool extrapolate = layout.kind == ColourModelKind::mix;
    const bool post = layout.kind == ColourModelKind::mix_clip_post;
    const int K = layout.knots;
    double sum = 0;
    for (const auto& s : *samples) {
      const Eigen::Vector3d r(s.raw[0], s.raw[1], s.raw[2]);
      const Eigen::Vector3d u0 = m.mix * r;
      Eigen::Vector3d u, f, slope;
      std::array<bool, 3> clipped{};
      for (int d = 0; d < 3; ++d) {
        u[d] = u0[d];
        if (clip && (u[d] < 0 || u[d] > 1)) {
          u[d] = std::clamp(u[d], 0.0, 1.0);
          clipped[static_cast<size_t>(d)] = true;
        }
        f[d] = m.curveValue(d, u[d]);
        // slope of f at u (0 on flat extensions)
        const auto& v = m.curve[static_cast<size_t>(d)];
        size_t k;
        if (u[d] <= knots[0]) {
          k = 1;
          slope[d] = extrapolate ? (v[1] - v[0]) / (knots[1] - knots[0]) : 0.0;
        } else if (u[d] >= knots.back()) {
          k = static_cast<size_t>(K);
          slope[d] = extrapolate ? (v[k] - v[k - 1]) / (knots[k] - knots[k - 1]) : 0.0;
        } else {
          k = static_cast<size_t>(std::upper_bound(knots.begin(), knots.end(), u[d]) - knots.begin());
          slope[d] = (v[k] - v[k - 1]) / (knots[k] - knots[k - 1]);
        }
      }
      const Eigen::Vector3d out = post ? Eigen::Vector3d(m.post * f) : f;
      for (int c = 0; c < 3; ++c) {
        const double pred = std::clamp(out[c], 0.0, 1.0);
        const double e = pred - s.jpeg[static_cast<size_t>(c)];
        sum += s.weight * e * e;
        if (!grad || out[c] < 0 || out[c] > 1) continue;
        const double g = 2 * s.weight * e / weight_sum;
        for (int d = 0; d < 3; ++d) {
          const double ncd = post ? m.post(c, d) : (c == d ? 1.0 : 0.0);
          if (ncd == 0.0) continue;
          if (post) grad[layout.mixCount() + 3 * c + d] += g * f[d];
          double* gc = grad + layout.curveStart() + d * (K + 1);
          gc[0] += g * ncd;
          for (int k = 1; k <= K; ++k) {
            const double t0 = knots[static_cast<size_t>(k - 1)], t1 = knots[static_cast<size_t>(k)];
            double ramp = (u[d] - t0) / (t1 - t0);
            const bool open_low = extrapolate && k == 1, open_high = extrapolate && k == K;
            if (!open_low) ramp = std::max(ramp, 0.0);
            if (!open_high) ramp = std::min(ramp, 1.0);
            gc[k] += g * ncd * ramp;
          }
          if (clipped[static_cast<size_t>(d)] || slope[d] == 0.0) continue;
          const double gu = g * ncd * slope[d];
          if (layout.kind == ColourModelKind::pointwise) {
            grad[d] += gu * r[d];
          } else {
            for (int e2 = 0; e2 < 3; ++e2) grad[3 * d + e2] += gu * r[e2];
          }
        }
      }
    }
    double rough = 0;
    const double norm = smoothness * 1e-2 / (K * K);
    for (int c = 0; c < 3; ++c) {
      const double* q = p + layout.curveStart() + c * (K + 1);
      for (int k = 1; k < K; ++k) {
        const double w0 = 1 / (knots[static_cast<size_t>(k)] - knots[static_cast<size_t>(k - 1)]);
        const double w1 = 1 / (knots[static_cast<size_t>(k + 1)] - knots[static_cast<size_t>(k)]);
        const double d = q[k + 1] * w1 - q[k] * w0;
        rough += d * d;
        if (grad) {
          double* gc = grad + layout.curveStart() + c * (K + 1);
          gc[k + 1] += norm * 2 * d * w1;
          gc[k] -= norm * 2 * d * w0;
        }
      }
    }
    return sum / weight_sum + norm * rough;
  }
};

double objective(unsigned, const double* x, double* grad, void* data) {
  auto* problem = static_cast<Problem*>(data);
  ++problem->evaluations;
  return problem->cost(x, grad);
}

ColourFitResult runFit(const std::vector<ColourSample>& samples, const ColourModel& start, ColourModelKind kind,
                       const ColourFitOptions& options) {
  Layout layout{kind, options.knots};
  ColourModel init = start;
  init.kind = kind;
  Problem problem{layout, start.knots, &samples, 0, options.smoothness};
  for (const auto& s : samples) problem.weight_sum += 3 * s.weight;
  std::vector<double> p = pack(layout, init);
  const auto n = static_cast<unsigned>(p.size());
  std::vector<double> lower(n, -HUGE_VAL), upper(n, HUGE_VAL);
  if (kind == ColourModelKind::pointwise)
    for (int c = 0; c < 3; ++c) lower[static_cast<size_t>(c)] = 1e-6;
  for (int c = 0; c < 3; ++c) {
    const size_t base = static_cast<size_t>(layout.curveStart() + c * (layout.knots + 1));
    lower[base] = -0.5;
    upper[base] = 0.5;
    for (int k = 1; k <= layout.knots; ++k) {
      lower[base + static_cast<size_t>(k)] = 0.0;
      upper[base + static_cast<size_t>(k)] = 2.0;
    }
  }
  for (unsigned i = 0; i < n; ++i) p[i] = std::clamp(p[i], lower[i], upper[i]);
  nlopt::opt opt(nlopt::LD_LBFGS, n);
  opt.set_lower_bounds(lower);
  opt.set_upper_bounds(upper);
  opt.set_min_objective(objective, &problem);
  opt.set_maxeval(options.max_evaluations);
  opt.set_ftol_rel(1e-10);
  double value = 0;
  try {
    opt.optimize(p, value);
  } catch (const nlopt::roundoff_limited&) {
  } catch (const std::runtime_error&) {
  }
  ColourFitResult result;
  result.model = unpack(layout, problem.knots, p.data());
  result.train_rmse = colourRmse(result.model, samples);
  result.evaluations = problem.evaluations;
  return result;
}

void validate(const std::vector<ColourSample>& samples) {
  if (samples.size() < 8) throw InvalidInput("colour fit: need at least 8 samples");
  for (const auto& s : samples)
    for (size_t c = 0; c < 3; ++c)
      if (!std::isfinite(s.raw[c]) || !std::isfinite(s.jpeg[c]) || !(s.weight >= 0))
        throw InvalidInput("colour fit: non-finite sample");
}

ColourModel initialModel(const std::vector<ColourSample>& samples, int knots) {
  ColourModel m;
  m.kind = ColourModelKind::pointwise;
  m.knots = makeKnots(knots);
  m.mix = Eigen::Matrix3d::Zero();
  for (size_t c = 0; c < 3; ++c) {
    std::vector<double> v;
    for (const auto& s : samples) v.push_back(s.raw[c]);
    std::sort(v.begin(), v.end());
    const double q = v[std::min(v.size() - 1, static_cast<size_t>(0.98 * double(v.size())))];
    m.mix(static_cast<int>(c), static_cast<int>(c)) = q > 1e-6 ? 1.0 / q : 1.0;
    // start from a gamma-2.2-like display curve
    auto& cv = m.curve[c];
    for (double t : m.knots) cv.push_back(std::pow(t, 1 / 2.2));
  }
  return m;
}

}  // namespace

std::vector<ColourFitResult> fitColourModels(const std::vector<ColourSample>& samples, const ColourFitOptions& options) {
  options.check();
  validate(samples);
  std::vector<ColourFitResult> results;
  ColourModel start = initialModel(samples, options.knots);
  for (const auto kind : allColourModelKinds()) {
    results.push_back(runFit(samples, start, kind, options));
    start = results.back().model;
  }
  return results;
}

namespace {
struct WbProblem {
  const ColourModel* model;
  const std::vector<ColourSample>* samples;
};
double wbObjective(unsigned, const double* x, double*, void* data) {
  const auto* p = static_cast<const WbProblem*>(data);
  ColourModel m = *p->model;
  m.mix = p->model->mix * Eigen::Vector3d(std::exp(x[0]), std::exp(x[1]), std::exp(x[2])).asDiagonal();
  const double e = colourRmse(m, *p->samples);
  return e * e;
}
}  // namespace

ColourModel adaptWhiteBalance(const ColourModel& model, const std::vector<ColourSample>& samples) {
  if (samples.size() < 2) throw InvalidInput("white balance: need at least 2 samples");
  validate(samples);
  WbProblem problem{&model, &samples};
  nlopt::opt opt(nlopt::LN_BOBYQA, 3);
  opt.set_lower_bounds(std::vector<double>(3, -2.0));
  opt.set_upper_bounds(std::vector<double>(3, 2.0));
  opt.set_min_objective(wbObjective, &problem);
  opt.set_maxeval(600);
  opt.set_xtol_abs(1e-6);
  std::vector<double> x(3, 0.0);
  double value = 0;
  try {
    opt.optimize(x, value);
  } catch (const nlopt::roundoff_limited&) {
  } catch (const std::runtime_error&) {
  }
  ColourModel out = model;
  out.mix = model.mix * Eigen::Vector3d(std::exp(x[0]), std::exp(x[1]), std::exp(x[2])).asDiagonal();
  return out;
}

ColourFitResult fitColourModel(const std::vector<ColourSample>& samples, ColourModelKind kind,
                               const ColourFitOptions& options) {
  options.check();
  validate(samples);
  ColourModel start = initialModel(samples, options.knots);
  ColourFitResult result;
  for (const auto k : allColourModelKinds()) {
    result = runFit(samples, start, k, options);
    if (k == kind) break;
    start = result.model;
  }
  return result;
}

}  // namespace crfcal
