#include "crfcal/exposure_fit.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <sstream>

#include <nlopt.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"

namespace crfcal {

void ExposureRatioOptions::check() const {
  if (!(low >= 0 && high <= 1 && low < high)) throw InvalidInput("exposure ratio: need 0 <= low < high <= 1");
  if (min_pixels < 1) throw InvalidInput("exposure ratio: min_pixels must be positive");
}

void BracketFitOptions::check() const {
  if (terms < 1 || terms > emor::kMaxTerms) throw InvalidInput("bracket fit: terms must be in [1, 25]");
  if (!(low >= 0 && high <= 1 && low < high)) throw InvalidInput("bracket fit: need 0 <= low < high <= 1");
  if (samples < 100) throw InvalidInput("bracket fit: samples must be >= 100");
  if (max_evaluations < 100) throw InvalidInput("bracket fit: max_evaluations must be >= 100");
}

namespace {

double median(std::vector<double> v) {
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

double relativeSpread(const std::vector<double>& v, double m) {
  std::vector<double> d;
  d.reserve(v.size());
  for (double x : v) d.push_back(std::abs(x - m));
  return 1.4826 * median(d) / m;
}

double interp(const std::vector<double>& table, double z) {
  const double t = std::clamp(z, 0.0, 1.0) * double(table.size() - 1);
  const auto i = std::min(static_cast<size_t>(t), table.size() - 2);
  const double f = t - double(i);
  return table[i] + f * (table[i + 1] - table[i]);
}

}  // namespace

ExposureRatioEstimate estimateExposureRatio(const cv::Mat& first, const cv::Mat& second, const ResponseCurve& curve,
                                            const ExposureRatioOptions& options) {
  options.check();
  const cv::Mat a = toUnitGray(first), b = toUnitGray(second);
  ExposureRatioEstimate est;
  std::vector<double> ratios;
  if (options.registered) {
    if (a.size() != b.size()) throw InvalidInput("exposure ratio: registered frames must have the same size");
    for (int y = 0; y < a.rows; ++y)
      for (int x = 0; x < a.cols; ++x) {
        const double za = a.at<double>(y, x), zb = b.at<double>(y, x);
        if (za < options.low || za > options.high || zb < options.low || zb > options.high) continue;
        const double pa = curve.inverse(za);
        if (pa <= 0) continue;
        ratios.push_back(curve.inverse(zb) / pa);
      }
    est.pixels = static_cast<int>(ratios.size());
  } else {
    std::vector<double> va(a.begin<double>(), a.end<double>()), vb(b.begin<double>(), b.end<double>());
    std::sort(va.begin(), va.end());
    std::sort(vb.begin(), vb.end());
    for (int q = 1; q < 200; ++q) {
      const double za = va[static_cast<size_t>(q / 200.0 * double(va.size() - 1))];
      const double zb = vb[static_cast<size_t>(q / 200.0 * double(vb.size() - 1))];
      if (za < options.low || za > options.high || zb < options.low || zb > options.high) continue;
      const double pa = curve.inverse(za);
      if (pa > 0) ratios.push_back(curve.inverse(zb) / pa);
    }
    est.pixels = static_cast<int>(ratios.size()) * (a.rows * a.cols / 200);
  }
  if (ratios.size() < 5 || (options.registered && est.pixels < options.min_pixels))
    throw InvalidInput("exposure ratio: too few well-exposed pixels in both frames");
  est.ratio = median(ratios);
  est.spread = relativeSpread(ratios, est.ratio);
  return est;
}

std::string BracketFitResult::summary() const {
  std::ostringstream s;
  s << "bracket fit: " << step_ratio.size() << " steps, log-residual RMS " << rms_residual << ", " << pairs_used
    << " pixel pairs; steps:";
  for (double r : step_ratio) s << ' ' << r;
  return s.str();
}

namespace {

struct BracketProblem {
  int terms = 0;
  int frames = 0;
  double span = 0;  // e_last
  struct Obs {
    double z1, z2;
    int step;
  };
  std::vector<Obs> obs;
  int evaluations = 0;

  std::vector<double> curve(const double* c) const {
    std::vector<double> phi(emor::kSamples);
    const auto g0 = emor::inverseMean();
    for (int i = 0; i < emor::kSamples; ++i) phi[static_cast<size_t>(i)] = g0[static_cast<size_t>(i)];
    for (int k = 1; k <= terms; ++k) {
      const auto h = emor::inverseBasis(k);
      for (int i = 0; i < emor::kSamples; ++i) phi[static_cast<size_t>(i)] += c[k - 1] * h[static_cast<size_t>(i)];
    }
    return phi;
  }
  std::vector<double> fixed;  // non-empty: the log exposures are fixed at these
  std::vector<double> exposures(const double* p) const {
    if (!fixed.empty()) return fixed;
    std::vector<double> e(static_cast<size_t>(frames), 0.0);
    for (int j = 1; j < frames - 1; ++j) e[static_cast<size_t>(j)] = p[terms + j - 1];
    e[static_cast<size_t>(frames - 1)] = span;
    return e;
  }
  double cost(const double* p, double* rms = nullptr) const {
    const auto phi = curve(p);
    double penalty = 0;
    for (size_t i = 1; i < phi.size(); ++i) {
      const double d = phi[i - 1] - phi[i];
      if (d > 0) penalty += d * d;
    }
    const auto e = exposures(p);
    double sum = 0;
    for (const auto& o : obs) {
      const double a = std::max(interp(phi, o.z1), 1e-4), b = std::max(interp(phi, o.z2), 1e-4);
      const double r = std::log(b) - std::log(a) - (e[static_cast<size_t>(o.step + 1)] - e[static_cast<size_t>(o.step)]);
      sum += r * r;
    }
    const double mean = sum / double(std::max<size_t>(obs.size(), 1));
    if (rms) *rms = std::sqrt(mean);
    return mean + 1e4 * penalty;
  }
};

double bracketObjective(unsigned, const double* x, double*, void* data) {
  auto* p = static_cast<BracketProblem*>(data);
  ++p->evaluations;
  return p->cost(x);
}

}  // namespace

BracketFitResult fitBracket(const std::vector<cv::Mat>& frames_in, const std::vector<double>& nominal,
                            const BracketFitOptions& options) {
  options.check();
  if (frames_in.size() < 2 || frames_in.size() != nominal.size())
    throw InvalidInput("bracket fit: need >= 2 frames and one nominal exposure per frame");
  for (size_t j = 0; j < nominal.size(); ++j)
    if (!(nominal[j] > 0) || (j > 0 && !(nominal[j] > nominal[j - 1])))
      throw InvalidInput("bracket fit: nominal exposures must be positive and increasing");
  std::vector<cv::Mat> frames;
  for (const auto& f : frames_in) {
    frames.push_back(toUnitGray(f));
    if (frames.back().size() != frames.front().size()) throw InvalidInput("bracket fit: frames differ in size");
  }
  BracketProblem problem;
  problem.terms = options.terms;
  problem.frames = static_cast<int>(frames.size());
  problem.span = std::log(nominal.back() / nominal.front());
  const cv::Rect area = options.region.area() > 0 ? options.region & cv::Rect(0, 0, frames[0].cols, frames[0].rows)
                                                  : cv::Rect(0, 0, frames[0].cols, frames[0].rows);
  if (area.area() == 0) throw InvalidInput("bracket fit: the region lies outside the frames");
  std::mt19937_64 rng(options.seed);
  std::uniform_int_distribution<int> ry(area.y, area.y + area.height - 1), rx(area.x, area.x + area.width - 1);
  for (int s = 0; s < options.samples; ++s) {
    const int y = ry(rng), x = rx(rng);
    for (int j = 0; j + 1 < problem.frames; ++j) {
      const double z1 = frames[static_cast<size_t>(j)].at<double>(y, x);
      const double z2 = frames[static_cast<size_t>(j + 1)].at<double>(y, x);
      if (z1 < options.low || z1 > options.high || z2 < options.low || z2 > options.high) continue;
      problem.obs.push_back({z1, z2, j});
    }
  }
  if (problem.obs.size() < 50) throw InvalidInput("bracket fit: too few pixels well exposed in consecutive frames");
  if (options.fixed_exposures)
    for (double v : nominal) problem.fixed.push_back(std::log(v / nominal.front()));
  const int n = options.terms + (options.fixed_exposures ? 0 : problem.frames - 2);
  std::vector<double> p(static_cast<size_t>(n), 0.0), lower(static_cast<size_t>(n)), upper(static_cast<size_t>(n));
  for (int k = 0; k < options.terms; ++k) {
    lower[static_cast<size_t>(k)] = -5;
    upper[static_cast<size_t>(k)] = 5;
  }
  for (int j = 1; j < problem.frames - 1 && !options.fixed_exposures; ++j) {
    const size_t i = static_cast<size_t>(options.terms + j - 1);
    p[i] = std::log(nominal[static_cast<size_t>(j)] / nominal.front());
    lower[i] = p[i] - 1.0;
    upper[i] = p[i] + 1.0;
  }
  nlopt::opt opt(nlopt::LN_BOBYQA, static_cast<unsigned>(n));
  opt.set_lower_bounds(lower);
  opt.set_upper_bounds(upper);
  opt.set_min_objective(bracketObjective, &problem);
  opt.set_maxeval(options.max_evaluations);
  opt.set_xtol_rel(1e-7);
  std::vector<double> step(static_cast<size_t>(n), 0.05);
  opt.set_initial_step(step);
  double value = 0;
  try {
    opt.optimize(p, value);
  } catch (const nlopt::roundoff_limited&) {
  } catch (const std::runtime_error&) {
  }
  BracketFitResult result;
  result.model.coefficients.assign(p.begin(), p.begin() + options.terms);
  result.inverse_crf = problem.curve(p.data());
  result.log_exposure = problem.exposures(p.data());
  for (size_t j = 0; j + 1 < result.log_exposure.size(); ++j)
    result.step_ratio.push_back(std::exp(result.log_exposure[j + 1] - result.log_exposure[j]));
  problem.cost(p.data(), &result.rms_residual);
  result.pairs_used = static_cast<int>(problem.obs.size());
  return result;
}

std::vector<double> bracketPredictionRmse(const std::vector<cv::Mat>& frames_in, const BracketFitResult& fit,
                                          const cv::Rect& region, double low, double high) {
  if (frames_in.size() < 2 || fit.step_ratio.size() + 1 != frames_in.size())
    throw InvalidInput("bracket prediction: one step ratio per consecutive pair of frames needed");
  std::vector<cv::Mat> frames;
  for (const auto& f : frames_in) frames.push_back(toUnitGray(f));
  const cv::Rect area = region.area() > 0 ? region & cv::Rect(0, 0, frames[0].cols, frames[0].rows)
                                          : cv::Rect(0, 0, frames[0].cols, frames[0].rows);
  const ResponseCurve curve = ResponseCurve::fromSamples([&] {
    std::vector<double> phi = fit.inverse_crf;
    phi.front() = 0;
    phi.back() = 1;
    for (size_t i = 1; i < phi.size(); ++i) phi[i] = std::clamp(phi[i], phi[i - 1], 1.0);
    return phi;
  }());
  std::vector<double> out;
  double total = 0;
  long count_all = 0;
  for (size_t j = 0; j + 1 < frames.size(); ++j) {
    double sum = 0;
    long count = 0;
    for (int y = area.y; y < area.y + area.height; ++y)
      for (int x = area.x; x < area.x + area.width; ++x) {
        const double z1 = frames[j].at<double>(y, x), z2 = frames[j + 1].at<double>(y, x);
        if (z1 < low || z1 > high || z2 < low || z2 > high) continue;
        const double predicted = curve.forward(std::min(1.0, fit.step_ratio[j] * curve.inverse(z1)));
        sum += (predicted - z2) * (predicted - z2);
        ++count;
      }
    out.push_back(count > 0 ? std::sqrt(sum / count) : 0.0);
    total += sum;
    count_all += count;
  }
  out.push_back(count_all > 0 ? std::sqrt(total / count_all) : 0.0);
  return out;
}

}  // namespace crfcal
