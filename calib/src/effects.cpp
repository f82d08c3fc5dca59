#include "crfcal/effects.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <span>
#include <sstream>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_debias.hpp"
#include "crfcal/noise_estimation.hpp"
#include "crfcal/response_curve.hpp"

namespace crfcal {

const std::vector<std::string>& effectNames() {
  static const std::vector<std::string> names{"exposure_ratio_mismatch", "channel_mixing",  "signal_dependent_noise",
                                              "clipping",                "vignetting",      "spatially_varying_blur",
                                              "black_level_offset"};
  return names;
}

void EffectOptions::check() const {
  if (!(min_gain >= 0 && min_gain < 1)) throw InvalidInput("effect options: min_gain must be in [0, 1)");
  if (!(min_z >= 0)) throw InvalidInput("effect options: min_z must be >= 0");
  if (!(min_noise_contrast >= 1)) throw InvalidInput("effect options: min_noise_contrast must be >= 1");
  if (noise_bins < 2 || noise_bins > 32) throw InvalidInput("effect options: noise_bins must be in 2..32");
  if (!(ratio_tolerance >= 0)) throw InvalidInput("effect options: ratio_tolerance must be >= 0");
  if (block < 8) throw InvalidInput("effect options: block must be >= 8");
  if (max_samples < 1000) throw InvalidInput("effect options: max_samples must be >= 1000");
  if (grid < 0 || grid > 6) throw InvalidInput("effect options: grid must be in 0..6");
  if (!(min_derivative > 0)) throw InvalidInput("effect options: min_derivative must be > 0");
  if (phi_terms < 0 || phi_terms > 10) throw InvalidInput("effect options: phi_terms must be in 0..10");
  if (refit_rounds < 1 || refit_rounds > 10) throw InvalidInput("effect options: refit_rounds must be in 1..10");
}

std::vector<std::string> EffectReport::detected() const {
  std::vector<std::string> out;
  for (const auto& e : entries)
    if (e.detected) out.push_back(e.name);
  return out;
}

const EffectEntry* EffectReport::find(const std::string& name) const {
  for (const auto& e : entries)
    if (e.name == name) return &e;
  return nullptr;
}

std::string EffectReport::summary() const {
  std::ostringstream s;
  s << "effects (" << samples << " samples/channel, " << seconds << " s):";
  for (const auto& e : entries) {
    char buffer[600];
    if (!e.tested)
      std::snprintf(buffer, sizeof buffer, "\n  %-24s not tested (%s)", e.name.c_str(), e.detail.c_str());
    else {
      const auto phi = e.parameters.find("phi_change");
      char change[64] = "";
      if (phi != e.parameters.end()) std::snprintf(change, sizeof change, "  dphi %.4f", phi->second);
      std::snprintf(buffer, sizeof buffer, "\n  %-24s %s  gain %.4f (>= %.3f)  z %.2f (>= %.1f)%s  %s", e.name.c_str(),
                    e.detected ? "DETECTED" : "no      ", e.gain, e.gain_threshold, e.statistic, e.threshold, change,
                    e.detail.c_str());
    }
    s << buffer;
  }
  if (!fits.empty()) s << "\n  phi refitted with the extended model";
  return s.str();
}

namespace {

using Clock = std::chrono::steady_clock;

double fullScale(const cv::Mat& m) { return m.depth() == CV_16U ? 65535.0 : m.depth() == CV_8U ? 255.0 : 1.0; }

cv::Mat unit(const cv::Mat& m) {
  cv::Mat out;
  m.convertTo(out, CV_64F, 1.0 / fullScale(m));
  return out;
}

// Back to the input's storage (so that the refit sees the same level grid as the base fit).
cv::Mat store(const cv::Mat& unit_image, int depth) {
  cv::Mat clamped = cv::max(cv::min(unit_image, 1.0), 0.0), out;
  if (depth == CV_8U || depth == CV_16U) {
    const double top = depth == CV_8U ? 255.0 : 65535.0;
    clamped.convertTo(out, depth, top);
  } else {
    out = clamped;
  }
  return out;
}

cv::Mat dilateBy(const cv::Mat& mask, int n) {
  cv::Mat out;
  cv::dilate(mask, out, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(n, n)));
  return out;
}

std::string fmt(const char* format, double a, double b = 0, double c = 0) {
  char buffer[240];
  std::snprintf(buffer, sizeof buffer, format, a, b, c);
  return buffer;
}

struct Curve {
  ResponseCurve curve;
  std::vector<double> phi;  // 1024 samples
  double derivative(double b) const {
    const int n = static_cast<int>(phi.size());
    const double s = std::clamp(b, 0.0, 1.0) * (n - 1);
    const int i = std::clamp(static_cast<int>(s), 1, n - 2);
    return (phi[i + 1] - phi[i - 1]) * (n - 1) / 2.0;
  }
};

// A tabulated φ made valid (φ(0) = 0, φ(1) = 1, non-decreasing): fits can carry rounding-level dips at the ends.
Curve makeCurve(std::vector<double> phi) {
  phi.front() = 0;
  phi.back() = 1;
  for (std::size_t i = 1; i < phi.size(); ++i) phi[i] = std::clamp(phi[i], phi[i - 1], 1.0);
  return Curve{ResponseCurve::fromSamples(phi), phi};
}

// φ̂ + Σ α_k h_k on the 1024-grid, made a valid inverse response (φ(0) = 0, φ(1) = 1, non-decreasing).
std::vector<double> adjustedPhi(const std::vector<double>& phi, const std::vector<double>& alpha) {
  std::vector<double> out = phi;
  for (std::size_t k = 0; k < alpha.size(); ++k) {
    const auto h = emor::inverseBasis(static_cast<int>(k) + 1);
    for (int i = 0; i < emor::kSamples; ++i) out[i] += alpha[k] * h[i];
  }
  out.front() = 0;
  out.back() = 1;
  for (std::size_t i = 1; i < out.size(); ++i) out[i] = std::clamp(out[i], out[i - 1], 1.0);
  return out;
}

// Folds: grid × grid tiles over the window, each split in two halves along its longer side.
struct Layout {
  int grid = 2;
  std::vector<cv::Rect> tiles;
  std::vector<std::array<cv::Rect, 2>> halves;
  cv::Mat tile_map, half_map;  // CV_32S tile index, CV_8U half index
  int fold(int tile, int half) const {
    const int tx = tile % grid, ty = tile / grid;
    return half ^ ((tx + ty) & 1);
  }
  int foldAt(int x, int y) const { return fold(tile_map.at<int>(y, x), half_map.at<uchar>(y, x)); }
};

Layout makeLayout(cv::Size size, int grid) {
  Layout l;
  l.grid = grid;
  l.tile_map = cv::Mat(size, CV_32S);
  l.half_map = cv::Mat(size, CV_8U);
  for (int ty = 0; ty < grid; ++ty)
    for (int tx = 0; tx < grid; ++tx) {
      const int x0 = tx * size.width / grid, x1 = (tx + 1) * size.width / grid;
      const int y0 = ty * size.height / grid, y1 = (ty + 1) * size.height / grid;
      const cv::Rect t(x0, y0, x1 - x0, y1 - y0);
      std::array<cv::Rect, 2> h;
      if (t.width >= t.height) {
        h[0] = cv::Rect(t.x, t.y, t.width / 2, t.height);
        h[1] = cv::Rect(t.x + t.width / 2, t.y, t.width - t.width / 2, t.height);
      } else {
        h[0] = cv::Rect(t.x, t.y, t.width, t.height / 2);
        h[1] = cv::Rect(t.x, t.y + t.height / 2, t.width, t.height - t.height / 2);
      }
      const int index = static_cast<int>(l.tiles.size());
      l.tiles.push_back(t);
      l.halves.push_back(h);
      l.tile_map(t).setTo(index);
      l.half_map(h[0]).setTo(0);
      l.half_map(h[1]).setTo(1);
    }
  return l;
}

// Residual samples of one channel.
struct Samples {
  std::vector<int> block, fine, fold;  // 32×32 block, 16×16 block, fold
  std::vector<double> d;      // φ̂'(B): irradiance → intensity scale of the residual
  std::vector<std::vector<double>> Dh;  // h_k'(B): the slope of the φ re-fit (the scale follows φ, see weight())
  std::vector<std::vector<double>> Hb;  // h_k(B)
  std::vector<double> phi;              // φ̂ on the 1024-grid (the clip level's irradiance)
  std::vector<double> Y;      // φ(B)
  std::vector<double> rho2;   // (r / R)²
  std::vector<double> level;  // B intensity
  std::vector<std::vector<double>> X;  // per channel index: a-free prediction φ_d(I_d) ⊗ K
  std::vector<std::vector<double>> P;  // φ columns a₀ K⊗h_k(I) − h_k(B) (EMoR basis h_k)
  std::vector<std::vector<double>> KH; // K⊗h_k(I): how this channel's X moves with its φ re-fit (mixing)
  std::vector<cv::Point> pos;
  std::size_t size() const { return Y.size(); }
};

struct Spec {
  bool vignetting = false, offset = false, mixing = false, clipping = false;
  bool fixed_scale = false;
  double scale = 1;
};

struct ChannelFit {
  Eigen::VectorXd theta;       // coefficients of the columns
  double clip = 0;             // clipping level (irradiance); 0: none
  bool ok = false;
};

struct Evaluation {
  std::vector<double> block_error;  // held-out Σ e² per block (all channels)
  std::vector<double> fine_error;   // the same per half-size block
  std::vector<std::vector<double>> residual;  // held-out e per channel and sample (0 where no fold fit)
  double total = 0;
  long count = 0;
  std::vector<ChannelFit> full;     // fitted on all samples (parameters for reporting/correction)
  std::array<std::vector<ChannelFit>, 2> folds;  // fitted on each fold (warm starts of nested models)
  Spec spec;
};

class Problem {
 public:
  Problem(std::vector<Samples> samples, int blocks, int fine_blocks, double min_derivative)
      : s_(std::move(samples)), blocks_(blocks), fine_blocks_(fine_blocks), min_derivative_(min_derivative) {}
  std::vector<Samples>& samples() { return s_; }
  const std::vector<Samples>& samples() const { return s_; }

  // Columns of the linear part. Column 0 is the scale column unless the scale is fixed.
  int row(const Samples& s, std::size_t i, const Spec& spec, double* out, double& target) const {
    const double x = s.X[self(s)][i];
    int k = 0;
    target = s.Y[i];
    if (spec.fixed_scale) target -= spec.scale * x;
    else out[k++] = x;
    if (spec.vignetting) {
      out[k++] = x * s.rho2[i];
      out[k++] = x * s.rho2[i] * s.rho2[i];
    }
    if (spec.offset) out[k++] = 1.0;
    if (spec.mixing)  // Ŷ_c = a X_c + Σ_{d≠c} m_cd (X_d − X_c): a = the row sum, the exposure ratio of a grey
      for (int d = 0; d < static_cast<int>(s.X.size()); ++d)
        if (d != self(s)) out[k++] = (coupled_ ? (*coupled_)[d][i] : s.X[d][i]) - x;
    for (const auto& column : s.P) out[k++] = column[i];  // φ re-fitted with every model (nested, fair)
    return k;
  }

  // 1 / φ'(B) of the re-fitted φ = φ̂ + Σ α_k h_k (α: the last coefficients): the residual stays in intensity units
  // whatever the re-fit does to φ's scale (else shrinking φ over the data's range would "explain" everything).
  double weight(const Samples& s, std::size_t i, const Eigen::VectorXd* theta) const {
    double d = s.d[i];
    if (theta && !s.Dh.empty()) {
      const Eigen::Index first = theta->size() - static_cast<Eigen::Index>(s.Dh.size());
      for (std::size_t k = 0; k < s.Dh.size(); ++k) d += (*theta)(first + static_cast<Eigen::Index>(k)) * s.Dh[k][i];
    }
    return 1.0 / std::max(d, min_derivative_);
  }

  // Least squares of the intensity-scaled residuals r_i = w_i(θ) (t_i − c_i·θ), Levenberg–Marquardt (w depends on
  // the φ re-fit; without φ terms one linear solve). Samples on B's plateau (clip level `clip`, B intensity) are
  // censored: they do not enter the fit.
  ChannelFit fitLevel(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx, double clip,
                      const Eigen::VectorXd* start = nullptr) const {
    double buffer[48], t;
    const int cols = row(s, idx[0], spec, buffer, t);
    const int terms = static_cast<int>(s.Dh.size());
    std::vector<std::size_t> use;
    for (auto i : idx)
      if (!(clip > 0 && s.level[i] >= clip)) use.push_back(i);  // clip > 1: none
    ChannelFit f;
    if (use.size() < 20) return f;
    // Start: the given one, else the linear solution without the φ terms (weights of φ̂).
    Eigen::VectorXd theta = Eigen::VectorXd::Zero(cols);
    if (start && start->size() == cols && start->allFinite()) {
      theta = *start;
    } else {
      const int lin = cols - terms;
      Eigen::MatrixXd A = Eigen::MatrixXd::Zero(lin, lin);
      Eigen::VectorXd b = Eigen::VectorXd::Zero(lin);
      for (auto i : use) {
        row(s, i, spec, buffer, t);
        const double w = weight(s, i, nullptr), w2 = w * w;
        for (int a = 0; a < lin; ++a) {
          b(a) += w2 * buffer[a] * t;
          for (int c = 0; c <= a; ++c) A(a, c) += w2 * buffer[a] * buffer[c];
        }
      }
      for (int a = 0; a < lin; ++a)
        for (int c = a + 1; c < lin; ++c) A(a, c) = A(c, a);
      if (lin > 0) {
        A.diagonal().array() += 1e-12 * (A.diagonal().array().abs().maxCoeff() + 1e-30);
        theta.head(lin) = A.ldlt().solve(b);
      }
      if (!theta.allFinite()) return f;
    }
    auto cost = [&](const Eigen::VectorXd& th) {
      double sum = 0;
      for (auto i : use) {
        row(s, i, spec, buffer, t);
        double pr = 0;
        for (int a = 0; a < cols; ++a) pr += th(a) * buffer[a];
        const double r = weight(s, i, &th) * (t - pr);
        sum += r * r;
      }
      return sum;
    };
    if (terms > 0) {
      double mu = 1e-3, current = cost(theta);
      for (int iteration = 0; iteration < 40; ++iteration) {
        Eigen::MatrixXd JtJ = Eigen::MatrixXd::Zero(cols, cols);
        Eigen::VectorXd Jtr = Eigen::VectorXd::Zero(cols);
        Eigen::VectorXd J(cols);
        const Eigen::Index first = cols - terms;
        for (auto i : use) {
          row(s, i, spec, buffer, t);
          double pr = 0;
          for (int a = 0; a < cols; ++a) pr += theta(a) * buffer[a];
          double d = s.d[i];
          for (int k = 0; k < terms; ++k) d += theta(first + k) * s.Dh[k][i];
          const bool floored = d < min_derivative_;
          const double w = 1.0 / std::max(d, min_derivative_), r = w * (t - pr);
          for (int a = 0; a < cols; ++a) J(a) = -w * buffer[a];
          if (!floored)
            for (int k = 0; k < terms; ++k) J(first + k) -= r * w * s.Dh[k][i];
          JtJ.selfadjointView<Eigen::Lower>().rankUpdate(J);
          Jtr += J * r;
        }
        JtJ = JtJ.selfadjointView<Eigen::Lower>();
        bool improved = false;
        for (int attempt = 0; attempt < 6 && !improved; ++attempt) {
          Eigen::MatrixXd H = JtJ;
          H.diagonal() += mu * JtJ.diagonal().cwiseMax(1e-30);
          const Eigen::VectorXd step = H.ldlt().solve(-Jtr);
          if (!step.allFinite()) break;
          const Eigen::VectorXd next = theta + step;
          const double c = cost(next);
          if (c < current) {
            improved = true;
            const double drop = (current - c) / std::max(current, 1e-300);
            theta = next;
            current = c;
            mu = std::max(mu / 3, 1e-9);
            if (drop < 1e-9) iteration = 1000;
          } else {
            mu *= 4;
          }
        }
        if (!improved) break;
      }
    }
    f.theta = theta;
    f.clip = clip;
    f.ok = theta.allFinite();
    return f;
  }

  ChannelFit fit(const Samples& s, const Spec& spec, int fold, const Eigen::VectorXd* start = nullptr) const {
    std::vector<std::size_t> idx;
    for (std::size_t i = 0; i < s.size(); ++i)
      if (fold < 0 || s.fold[i] == fold) idx.push_back(i);
    ChannelFit best;
    if (idx.size() < 20) return best;
    if (!spec.clipping) return fitLevel(s, spec, idx, 0, start);
    // Plateau level of B on a grid of its upper quantiles; the best (lowest in-sample error) is kept.
    std::vector<double> y;
    for (auto i : idx) y.push_back(s.level[i]);
    std::sort(y.begin(), y.end());
    std::vector<double> clips{2.0};  // 2: no plateau (the base model, nested)
    for (double q : {1.0, 0.999, 0.995, 0.99, 0.98, 0.97, 0.95, 0.93, 0.9, 0.85, 0.8})
      clips.push_back(y[static_cast<std::size_t>(q * (y.size() - 1))]);
    clips.erase(std::unique(clips.begin(), clips.end()), clips.end());
    double best_error = std::numeric_limits<double>::infinity();
    for (double clip : clips) {
      if (!(clip > 0)) continue;
      const ChannelFit f = fitLevel(s, spec, idx, clip, start);
      if (!f.ok) continue;
      double error = 0;
      for (auto i : idx) {
        const double e = residual(s, i, spec, f);
        error += e * e;
      }
      if (error < best_error) {
        best_error = error;
        best = f;
      }
    }
    return best;
  }

  // Residual φ(B) − Ŷ in intensity units. Clipping: Ŷ = min(prediction, c), c = φ(clip) the plateau's irradiance
  // (φ re-fitted like everything else), for every sample — two-sided, so a plateau that is not there costs.
  double residual(const Samples& s, std::size_t i, const Spec& spec, const ChannelFit& f) const {
    double buffer[48], t;
    const int cols = row(s, i, spec, buffer, t);
    double p = 0;
    for (int a = 0; a < cols; ++a) p += f.theta(a) * buffer[a];
    const double w = weight(s, i, &f.theta);
    if (!(f.clip > 0 && f.clip <= 1)) return w * (t - p);
    const int terms = static_cast<int>(s.Dh.size());
    const Eigen::Index first = f.theta.size() - terms;
    const int ci = std::clamp(static_cast<int>(f.clip * 1023 + 0.5), 0, 1023);
    double u = s.Y[i], c = s.phi[ci];
    for (int k = 0; k < terms; ++k) {
      u += f.theta(first + k) * s.Hb[k][i];
      c += f.theta(first + k) * emor::inverseBasis(k + 1)[ci];
    }
    const double predicted = u - (t - p);  // the model's irradiance before the clip
    return w * (u - std::min(predicted, c));
  }

  // Fits of every channel on one fold (−1: all samples). With mixing, the channels' fits are coupled: the other
  // channels' X_d follow their own φ re-fits (X_d + Σ α_dk K⊗h_k(I_d)), alternated three times.
  std::vector<ChannelFit> fitAll(const Spec& spec, int fold, std::vector<std::vector<double>>& xs,
                                 const std::vector<Eigen::VectorXd>& starts) const {
    std::vector<ChannelFit> fits(s_.size());
    const int rounds = spec.mixing && !s_.empty() && !s_[0].KH.empty() ? 3 : 1;
    xs.assign(s_.size(), {});
    for (std::size_t d = 0; d < s_.size(); ++d) xs[d] = s_[d].X[d];
    for (int round = 0; round < rounds; ++round) {
      coupled_ = spec.mixing ? &xs : nullptr;
      for (const auto& s : s_) {
        const int c = self(s);
        const Eigen::VectorXd* start = round == 0 && c < static_cast<int>(starts.size()) && starts[c].size() > 0
                                           ? &starts[c]
                                           : (round > 0 && fits[c].ok ? &fits[c].theta : nullptr);
        fits[c] = fit(s, spec, fold, start);
      }
      coupled_ = nullptr;
      if (round + 1 == rounds) break;
      for (std::size_t d = 0; d < s_.size(); ++d) {
        const Samples& s = s_[d];
        if (!fits[d].ok) continue;
        const Eigen::Index first = fits[d].theta.size() - static_cast<Eigen::Index>(s.KH.size());
        for (std::size_t i = 0; i < s.size(); ++i) {
          double x = s.X[d][i];
          for (std::size_t k = 0; k < s.KH.size(); ++k) x += fits[d].theta(first + static_cast<Eigen::Index>(k)) * s.KH[k][i];
          xs[d][i] = x;
        }
      }
    }
    return fits;
  }

  // warm: a nested smaller model's evaluation; its per-fold fits start the LM of this one (new parameters at 0),
  // so that the comparison reflects the added parameters, not where the optimiser stopped.
  Evaluation evaluate(const Spec& spec, bool heldout = true, const Evaluation* warm = nullptr) const {
    Evaluation ev;
    ev.block_error.assign(blocks_, 0.0);
    ev.fine_error.assign(fine_blocks_, 0.0);
    ev.residual.resize(s_.size());
    for (const auto& s : s_) ev.residual[self(s)].assign(s.size(), 0.0);
    if (heldout) {
      std::array<std::vector<ChannelFit>, 2> f;
      std::array<std::vector<std::vector<double>>, 2> xs;
      for (int fold = 0; fold < 2; ++fold) {
        f[fold] = fitAll(spec, fold, xs[fold], warmStarts(warm, fold, spec));
        ev.folds[fold] = f[fold];
      }
      for (const auto& s : s_) {
        const int c = self(s);
        for (std::size_t i = 0; i < s.size(); ++i) {
          const int held = 1 - s.fold[i];  // parameters from the other fold
          if (!f[held][c].ok) continue;
          coupled_ = spec.mixing ? &xs[held] : nullptr;
          const double e = residual(s, i, spec, f[held][c]);
          coupled_ = nullptr;
          ev.block_error[s.block[i]] += e * e;
          ev.fine_error[s.fine[i]] += e * e;
          ev.residual[c][i] = e;
          ev.total += e * e;
          ++ev.count;
        }
      }
    }
    std::vector<std::vector<double>> xs;
    ev.full = fitAll(spec, -1, xs, warmStarts(warm, -1, spec));
    ev.spec = spec;
    return ev;
  }

  // Column layout of a spec: [scale][v1 v2][offset][mix…][φ terms]; a nested model's θ mapped into a larger one.
  Eigen::VectorXd expand(const Spec& from, const Eigen::VectorXd& t, const Spec& to, int nc, int terms) const {
    auto count = [&](const Spec& sp, int block) {
      switch (block) {
        case 0: return sp.fixed_scale ? 0 : 1;
        case 1: return sp.vignetting ? 2 : 0;
        case 2: return sp.offset ? 1 : 0;
        case 3: return sp.mixing ? nc - 1 : 0;
        default: return terms;
      }
    };
    int cols = 0;
    for (int b = 0; b < 5; ++b) cols += count(to, b);
    Eigen::VectorXd out = Eigen::VectorXd::Zero(cols);
    int i = 0, j = 0;
    for (int b = 0; b < 5; ++b) {
      const int nf = count(from, b), nt = count(to, b);
      if (nf == nt)
        for (int k = 0; k < nt; ++k) out(j + k) = t(i + k);
      else if (b == 0 && nt == 1 && nf == 0)
        out(j) = from.scale;  // a fixed scale becomes the start of the free one
      i += nf;
      j += nt;
    }
    return out;
  }

  std::vector<Eigen::VectorXd> warmStarts(const Evaluation* warm, int fold, const Spec& spec) const {
    std::vector<Eigen::VectorXd> out(s_.size());
    if (!warm) return out;
    const auto& fits = fold < 0 ? warm->full : warm->folds[fold];
    for (std::size_t c = 0; c < s_.size() && c < fits.size(); ++c)
      if (fits[c].ok)
        out[c] = expand(warm->spec, fits[c].theta, spec, static_cast<int>(s_.size()),
                        static_cast<int>(s_[c].Dh.size()));
    return out;
  }

  int self(const Samples& s) const { return static_cast<int>(&s - s_.data()); }

 private:
  std::vector<Samples> s_;
  int blocks_, fine_blocks_;
  mutable const std::vector<std::vector<double>>* coupled_ = nullptr;  // mixing: the other channels' re-fitted X
  double min_derivative_;
};

struct Comparison {
  double gain = 0, z = 0;
};

// Paired one-sided test over blocks: d_b = base_b − ext_b.
Comparison compare(const std::vector<double>& base, const std::vector<double>& ext, double base_total,
                   const std::vector<char>& used) {
  std::vector<double> d;
  double sum = 0;
  for (std::size_t b = 0; b < base.size(); ++b)
    if (used[b]) {
      d.push_back(base[b] - ext[b]);
      sum += d.back();
    }
  Comparison c;
  if (d.size() < 4 || !(base_total > 0)) return c;
  const double n = static_cast<double>(d.size()), mean = sum / n;
  double var = 0;
  for (double v : d) var += (v - mean) * (v - mean);
  var /= (n - 1);
  c.gain = sum / base_total;
  const double t = var > 0 ? mean / std::sqrt(var / n) : (mean > 0 ? 1e9 : 0);
  // Student's t with n − 1 degrees of freedom as the normal deviate of the same tail probability (Wallace's
  // approximation z = t (1 − 1/(4ν)) / sqrt(1 + t²/(2ν))): few blocks need a larger t.
  const double nu = n - 1;
  c.z = t * (1 - 1 / (4 * nu)) / std::sqrt(1 + t * t / (2 * nu));
  return c;
}

// Localised effects (the clip acts on a few regions): the held-out drop Σ d_i over the affected samples against
// what noise alone would give for the same change of prediction δ_i = e_base,i − e_ext,i: under "no effect"
// Var(Σ d_i) ≈ 4 σ² A Σ δ_i², σ² the base model's held-out residual variance and A the residuals' design effect
// (variance inflation of block sums: A = Σ_b (Σ_{i∈b} e_i)² / Σ e_i², 1 for independent residuals).
// z = Σ d / (2 σ sqrt(A Σ δ²)); `gain` returns Σ d (the caller normalises).
Comparison scoreTest(const std::vector<Samples>& samples, const Evaluation& base, const Evaluation& ext,
                     const std::vector<char>& affected, int blocks) {
  Comparison c;
  double e2 = 0, sum_d = 0, sum_delta2 = 0;
  long n = 0;
  std::vector<double> block_sum(blocks, 0.0);
  for (std::size_t ch = 0; ch < samples.size(); ++ch) {
    const Samples& s = samples[ch];
    for (std::size_t i = 0; i < s.size(); ++i) {
      const double eb = base.residual[ch][i], ee = ext.residual[ch][i];
      e2 += eb * eb;
      ++n;
      block_sum[s.block[i]] += eb;
      if (!affected[s.fine[i]]) continue;
      sum_d += eb * eb - ee * ee;
      sum_delta2 += (eb - ee) * (eb - ee);
    }
  }
  if (n == 0 || !(e2 > 0) || !(sum_delta2 > 0)) return c;
  double A = 0;
  for (double v : block_sum) A += v * v;
  A = std::max(1.0, A / e2);
  const double sigma2 = e2 / n;
  c.gain = sum_d;
  c.z = sum_d / (2 * std::sqrt(sigma2 * A * sum_delta2));
  return c;
}

struct Prepared {
  std::vector<cv::Mat> I, B;        // unit CV_64F per channel (original)
  std::vector<int> depth;
  std::vector<int> levels;          // level grid of I (256 for 8-bit data, else 1024)
  std::vector<NoiseDebias> debias;  // per channel (identity when I is not noisy)
  cv::Mat usable;                   // CV_8U
  cv::Mat rho2;                     // CV_64F
};

cv::Mat applyTable(const cv::Mat& image, const std::vector<double>& table) {
  cv::Mat out(image.size(), CV_64F);
  const int n = static_cast<int>(table.size());
  for (int y = 0; y < image.rows; ++y) {
    const double* a = image.ptr<double>(y);
    double* o = out.ptr<double>(y);
    for (int x = 0; x < image.cols; ++x) {
      const double s = std::clamp(a[x], 0.0, 1.0) * (n - 1);
      const int i = std::min(n - 2, static_cast<int>(s));
      o[x] = table[i] + (s - i) * (table[i + 1] - table[i]);
    }
  }
  return out;
}

// f on the 1024-grid resampled to `levels` values f(v / (levels − 1)).
std::vector<double> onLevels(std::span<const double> f, int levels) {
  std::vector<double> out(levels);
  const int n = static_cast<int>(f.size());
  for (int v = 0; v < levels; ++v) {
    const double s = static_cast<double>(v) / (levels - 1) * (n - 1);
    const int i = std::min(n - 2, static_cast<int>(s));
    out[v] = f[i] + (s - i) * (f[i + 1] - f[i]);
  }
  return out;
}

std::vector<Samples> collect(const Prepared& p, const std::vector<Curve>& curves, const std::vector<double>& ratios,
                             const cv::Mat& K, const Layout& layout, const EffectOptions& options,
                             std::vector<cv::Mat>* phiI_out) {
  const int nc = static_cast<int>(p.I.size());
  std::vector<cv::Mat> phiI(nc), phiB(nc), X(nc);
  std::vector<std::vector<cv::Mat>> P(nc), KH(nc);
  for (int c = 0; c < nc; ++c) {
    phiI[c] = curves[c].curve.inverse(p.I[c]);
    phiB[c] = curves[c].curve.inverse(p.B[c]);
    // The noisy I: its level functions debiased (noise_debias.hpp, E[g(I) | clean c] = f(c)), so that Jensen's
    // bias of φ(I) and the clip of the noise at 0 and 1 do not pose as an effect (e.g. as an offset in the darks).
    const NoiseDebias& debias = p.debias[c];
    auto levelFunction = [&](std::span<const double> f) {
      std::vector<double> g = onLevels(f, p.levels[c]);
      if (!debias.identity()) g = debias.apply(g);
      return applyTable(p.I[c], g);
    };
    X[c] = convolve(levelFunction(curves[c].phi), K);
    for (int k = 1; k <= options.phi_terms; ++k) {
      const auto span = emor::inverseBasis(k);
      const std::vector<double> h(span.begin(), span.end());
      KH[c].push_back(convolve(levelFunction(span), K));
      P[c].push_back(ratios[c] * KH[c].back() - applyTable(p.B[c], h));
    }
  }
  if (phiI_out) *phiI_out = phiI;
  const int usable = cv::countNonZero(p.usable);
  const int stride =
      std::max(1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(usable) / options.max_samples))));
  const int bx = (p.usable.cols + options.block - 1) / options.block;
  const int fine = std::max(1, options.block / 2), fbx = (p.usable.cols + fine - 1) / fine;
  std::vector<Samples> out(nc);
  for (int c = 0; c < nc; ++c) {
    out[c].X.resize(nc);
    out[c].P.resize(P[c].size());
    out[c].Dh.resize(P[c].size());
    out[c].Hb.resize(P[c].size());
    out[c].KH.resize(P[c].size());
    out[c].phi = curves[c].phi;
  }
  std::vector<std::vector<double>> slope(options.phi_terms, std::vector<double>(emor::kSamples));
  for (int k = 0; k < options.phi_terms; ++k) {
    const auto h = emor::inverseBasis(k + 1);
    for (int i = 0; i < emor::kSamples; ++i) {
      const int lo = std::max(0, i - 1), hi = std::min(emor::kSamples - 1, i + 1);
      slope[k][i] = (h[hi] - h[lo]) * (emor::kSamples - 1) / (hi - lo);
    }
  }
  for (int y = 0; y < p.usable.rows; y += stride) {
    const uchar* m = p.usable.ptr<uchar>(y);
    for (int x = (y / stride) % 2 == 0 ? 0 : stride / 2; x < p.usable.cols; x += stride) {
      if (!m[x]) continue;
      const int tile = layout.tile_map.at<int>(y, x), half = layout.half_map.at<uchar>(y, x);
      for (int c = 0; c < nc; ++c) {
        Samples& s = out[c];
        const double b = p.B[c].at<double>(y, x);
        s.block.push_back((y / options.block) * bx + x / options.block);
        s.fine.push_back((y / fine) * fbx + x / fine);
        s.fold.push_back(layout.fold(tile, half));
        s.d.push_back(curves[c].derivative(b));
        const int bi = std::clamp(static_cast<int>(b * 1023 + 0.5), 0, 1023);
        for (std::size_t k = 0; k < P[c].size(); ++k) {
          s.Dh[k].push_back(slope[k][bi]);
          s.Hb[k].push_back(emor::inverseBasis(static_cast<int>(k) + 1)[bi]);
        }
        s.Y.push_back(phiB[c].at<double>(y, x));
        s.rho2.push_back(p.rho2.at<double>(y, x));
        s.level.push_back(b);
        s.pos.emplace_back(x, y);
        for (int d = 0; d < nc; ++d) s.X[d].push_back(X[d].at<double>(y, x));
        for (std::size_t k = 0; k < P[c].size(); ++k) {
          s.P[k].push_back(P[c][k].at<double>(y, x));
          s.KH[k].push_back(KH[c][k].at<double>(y, x));
        }
      }
    }
  }
  return out;
}

// ---- spatially varying blur: a kernel linear in the position -------------------------------------------------
// Handheld blur varies across the frame mostly through the camera's roll: the path of a point at p is the
// translation plus θ(t)·R90·(p − c), so to first order in p the kernel is K(p) = K₀ + u K_x + v K_y (u, v the
// position relative to the centre, over the half-diagonal). Base: one kernel K₀; extended: (K₀, K_x, K_y); both
// estimated by least squares in the irradiance domain on the same fold (support: the global kernel's, dilated
// by one pixel) from Y = φ(B) and the debiased φ(I), residuals weighted 1/φ'(B) like every other test.
struct BlurTest {
  bool ok = false;
  std::string problem;
  Comparison cmp;
  double variation = 0;             // (‖K_x‖ + ‖K_y‖) / ‖K₀‖: relative kernel change from the centre to a corner
  cv::Mat K0, Kx, Ky;               // fitted on all samples (unnormalised: the scale carries r)
};

BlurTest spatialBlurTest(const Samples& s, const cv::Mat& g, const cv::Mat& K, cv::Point2d centre, double radius,
                         int blocks, double min_derivative, int max_samples) {
  BlurTest bt;
  double kmax = 0;
  cv::minMaxLoc(K, nullptr, &kmax);
  cv::Mat support = K > 0.01 * kmax;
  cv::dilate(support, support, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(3, 3)));
  std::vector<cv::Point> q;
  for (int y = 0; y < K.rows; ++y)
    for (int x = 0; x < K.cols; ++x)
      if (support.at<uchar>(y, x)) q.emplace_back(x, y);
  const int m = static_cast<int>(q.size());
  if (m > 500) {
    bt.problem = "kernel support too large for the first-order model (" + std::to_string(m) + " entries)";
    return bt;
  }
  const int cx = K.cols / 2, cy = K.rows / 2;
  // A regular subsample of the samples (every k-th keeps both folds and all regions).
  const std::size_t step = std::max<std::size_t>(1, s.size() / static_cast<std::size_t>(max_samples));
  std::vector<std::size_t> idx;
  for (std::size_t i = 0; i < s.size(); i += step) {
    const cv::Point p = s.pos[i];
    if (p.x - (K.cols - 1 - cx) < 0 || p.y - (K.rows - 1 - cy) < 0 || p.x + cx >= g.cols || p.y + cy >= g.rows) continue;
    idx.push_back(i);
  }
  const int n = static_cast<int>(idx.size());
  if (n < 6 * m) {
    bt.problem = "too few samples for " + std::to_string(3 * m) + " kernel entries";
    return bt;
  }
  Eigen::MatrixXd D(n, 3 * m);
  Eigen::VectorXd t(n), w(n);
  std::vector<int> fold(n);
  for (int r = 0; r < n; ++r) {
    const std::size_t i = idx[r];
    const cv::Point p = s.pos[i];
    const double u = (p.x - centre.x) / radius, v = (p.y - centre.y) / radius;
    w(r) = 1.0 / std::max(s.d[i], min_derivative);
    t(r) = w(r) * s.Y[i];
    fold[r] = s.fold[i];
    for (int j = 0; j < m; ++j) {
      // convolve(): out(p) = Σ_j K(j) in(p − (j − c))
      const double a = w(r) * g.at<double>(p.y - (q[j].y - cy), p.x - (q[j].x - cx));
      D(r, j) = a;
      D(r, m + j) = u * a;
      D(r, 2 * m + j) = v * a;
    }
  }
  auto solve = [&](int f, int cols) {
    std::vector<int> rows;
    for (int r = 0; r < n; ++r)
      if (f < 0 || fold[r] == f) rows.push_back(r);
    Eigen::MatrixXd Df(rows.size(), cols);
    Eigen::VectorXd tf(rows.size());
    for (std::size_t k = 0; k < rows.size(); ++k) {
      Df.row(static_cast<Eigen::Index>(k)) = D.row(rows[k]).head(cols);
      tf(static_cast<Eigen::Index>(k)) = t(rows[k]);
    }
    Eigen::MatrixXd A = Df.transpose() * Df;
    A.diagonal().array() += 1e-9 * A.diagonal().mean() + 1e-300;
    return Eigen::VectorXd(A.ldlt().solve(Df.transpose() * tf));
  };
  std::array<Eigen::VectorXd, 2> base, ext;
  for (int f = 0; f < 2; ++f) {
    base[f] = solve(f, m);
    ext[f] = solve(f, 3 * m);
    if (!base[f].allFinite() || !ext[f].allFinite()) {
      bt.problem = "kernel fit failed";
      return bt;
    }
  }
  // Held-out residuals and the score test of the drop (see scoreTest).
  double e2 = 0, sum_d = 0, sum_delta2 = 0, total = 0;
  std::vector<double> block_sum(blocks, 0.0);
  for (int r = 0; r < n; ++r) {
    const int held = 1 - fold[r];
    const double eb = t(r) - D.row(r).head(m).dot(base[held]);
    const double ee = t(r) - D.row(r).dot(ext[held]);
    e2 += eb * eb;
    sum_d += eb * eb - ee * ee;
    sum_delta2 += (eb - ee) * (eb - ee);
    block_sum[s.block[idx[r]]] += eb;
  }
  total = e2;
  if (!(e2 > 0) || !(sum_delta2 > 0)) {
    bt.problem = "no residual";
    return bt;
  }
  double A = 0;
  for (double v : block_sum) A += v * v;
  A = std::max(1.0, A / e2);
  bt.cmp.gain = sum_d / total;
  bt.cmp.z = sum_d / (2 * std::sqrt(e2 / n * A * sum_delta2));
  const Eigen::VectorXd all = solve(-1, 3 * m);
  bt.K0 = cv::Mat::zeros(K.size(), CV_64F);
  bt.Kx = cv::Mat::zeros(K.size(), CV_64F);
  bt.Ky = cv::Mat::zeros(K.size(), CV_64F);
  for (int j = 0; j < m; ++j) {
    bt.K0.at<double>(q[j]) = all(j);
    bt.Kx.at<double>(q[j]) = all(m + j);
    bt.Ky.at<double>(q[j]) = all(2 * m + j);
  }
  const double n0 = cv::norm(bt.K0);
  bt.variation = n0 > 0 ? (cv::norm(bt.Kx) + cv::norm(bt.Ky)) / n0 : 0;
  bt.ok = true;
  return bt;
}

// The first-order kernel at a point: K₀ + u K_x + v K_y, non-negative, normalised.
cv::Mat kernelAt(const BlurTest& bt, double u, double v) {
  cv::Mat k = bt.K0 + u * bt.Kx + v * bt.Ky;
  k = cv::max(k, 0.0);
  const double sum = cv::sum(k)[0];
  if (!(sum > 0)) return normalizeKernel(bt.K0.clone() + 1e-12);
  return k / sum;
}

// ---- signal-dependent noise, measured on I itself --------------------------------------------------------------
struct NoiseTest {
  bool ok = false;
  std::string problem;
  std::vector<double> block_nll_base, block_nll_ext;
  double total_base = 0, total_ext = 0;
  long count = 0;
  double contrast = 1;                 // variance ratio between levels 0.1 and 0.9 of the log-linear trend (worst channel)
  std::vector<std::vector<double>> level, sigma;  // per channel: bin mean level, robust σ (all samples)
};

double robustSigma(std::vector<double> a) {
  if (a.empty()) return 0;
  for (auto& v : a) v = std::abs(v);
  std::nth_element(a.begin(), a.begin() + static_cast<std::ptrdiff_t>(a.size() / 2), a.end());
  return 1.4826 * a[a.size() / 2];
}

// Huber negative log-likelihood (scale σ, k = 2): log σ + ρ(e/σ); a Gaussian core that tolerates texture leaks.
double huberNll(double e, double sigma) {
  const double u = std::abs(e) / sigma, k = 2.0;
  return std::log(sigma) + (u <= k ? 0.5 * u * u : k * u - 0.5 * k * k);
}

NoiseTest noiseTest(const std::vector<cv::Mat>& I, const cv::Mat& valid, const Layout& layout, int block, int bins,
                    int blocks) {
  NoiseTest nt;
  nt.block_nll_base.assign(blocks, 0.0);
  nt.block_nll_ext.assign(blocks, 0.0);
  const cv::Mat op = (cv::Mat_<double>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1) / 6.0;
  const int bx = (I[0].cols + block - 1) / block;
  for (const auto& image : I) {
    const double sigma0 = estimateNoiseSigma(image).sigma;
    cv::Mat residual, mean, local;
    cv::filter2D(image, residual, CV_64F, op, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
    cv::blur(image, mean, cv::Size(5, 5), cv::Point(-1, -1), cv::BORDER_REFLECT);
    cv::blur(residual.mul(residual), local, cv::Size(7, 7), cv::Point(-1, -1), cv::BORDER_REFLECT);
    // Clipped values (0 or 1) truncate the noise: exclude their neighbourhoods and levels within 3σ of the ends.
    const cv::Mat clipped = dilateBy((image <= 0.5 / 255.0) | (image >= 254.5 / 255.0), 7);
    const double margin = std::max(3 * sigma0, 2.0 / 255.0);
    struct Item {
      double level, local, e;
      int x, y;
    };
    std::vector<Item> items;
    for (int y = 3; y < image.rows - 3; ++y)
      for (int x = 3; x < image.cols - 3; ++x) {
        if (clipped.at<uchar>(y, x) || (!valid.empty() && !valid.at<uchar>(y, x))) continue;
        const double m = mean.at<double>(y, x);
        if (m < margin || m > 1 - margin) continue;
        items.push_back({m, local.at<double>(y, x), residual.at<double>(y, x), x, y});
      }
    if (static_cast<int>(items.size()) < 200 * bins) {
      nt.problem = "too few unclipped pixels in I";
      return nt;
    }
    // Equal-count level bins. In each, the pixels whose 7×7 residual energy is in the lowest 30 %: texture only
    // adds energy, so these are noise (the same fraction in every bin keeps the σ ratios between bins).
    std::sort(items.begin(), items.end(), [](const Item& a, const Item& b) { return a.level < b.level; });
    std::vector<std::vector<Item>> binned(bins);
    for (std::size_t i = 0; i < items.size(); ++i) binned[i * bins / items.size()].push_back(items[i]);
    std::vector<double> level(bins), sig(bins), count(bins);
    std::array<std::vector<std::vector<double>>, 2> fold_e;  // per fold, per bin
    for (auto& f : fold_e) f.assign(bins, {});
    std::vector<const Item*> kept;
    std::vector<int> kept_bin;
    for (int b = 0; b < bins; ++b) {
      auto& v = binned[b];
      std::sort(v.begin(), v.end(), [](const Item& a, const Item& c) { return a.local < c.local; });
      v.resize(std::max<std::size_t>(1, v.size() * 3 / 10));
      double msum = 0;
      std::vector<double> all;
      for (const auto& it : v) {
        msum += it.level;
        all.push_back(it.e);
        fold_e[layout.foldAt(it.x, it.y)][b].push_back(it.e);
        kept.push_back(&it);
        kept_bin.push_back(b);
      }
      level[b] = msum / static_cast<double>(v.size());
      sig[b] = robustSigma(all);
      count[b] = static_cast<double>(v.size());
    }
    // Per fold: one robust σ (base) and one per bin (extended).
    std::array<double, 2> base{};
    std::array<std::vector<double>, 2> ext;
    for (int f = 0; f < 2; ++f) {
      std::vector<double> all;
      ext[f].assign(bins, 0.0);
      for (int b = 0; b < bins; ++b) {
        all.insert(all.end(), fold_e[f][b].begin(), fold_e[f][b].end());
        ext[f][b] = robustSigma(fold_e[f][b]);
      }
      base[f] = robustSigma(all);
      if (!(base[f] > 0)) {
        nt.problem = "no noise measurable in I";
        return nt;
      }
      for (int b = 0; b < bins; ++b)
        if (!(ext[f][b] > 0)) ext[f][b] = base[f];
    }
    for (std::size_t i = 0; i < kept.size(); ++i) {
      const Item& it = *kept[i];
      const int held = 1 - layout.foldAt(it.x, it.y);  // parameters from the other fold
      const double n0 = huberNll(it.e, base[held]), n1 = huberNll(it.e, ext[held][kept_bin[i]]);
      const int blk = (it.y / block) * bx + it.x / block;
      nt.block_nll_base[blk] += n0;
      nt.block_nll_ext[blk] += n1;
      nt.total_base += n0;
      nt.total_ext += n1;
      ++nt.count;
    }
    // Size of the level dependence: the log-variance trend over the bins, as a contrast between levels 0.1 and 0.9
    // (a property of the camera, whatever levels this image happens to cover).
    double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
    for (int b = 0; b < bins; ++b) {
      if (!(sig[b] > 0)) continue;
      const double w = count[b], x = level[b], y = std::log(sig[b] * sig[b]);
      sw += w, sx += w * x, sy += w * y, sxx += w * x * x, sxy += w * x * y;
    }
    const double det = sw * sxx - sx * sx;
    const double slope = det > 1e-12 ? (sw * sxy - sx * sy) / det : 0.0;
    nt.contrast = std::max(nt.contrast, std::exp(std::abs(slope) * 0.8));
    nt.level.push_back(level);
    nt.sigma.push_back(sig);
  }
  nt.ok = nt.count > 0;
  return nt;
}

// Index of the "scale" coefficient and the others in a fitted spec.
struct Coefficients {
  double scale = 1, v1 = 0, v2 = 0, offset = 0;
  std::vector<double> mix;    // per channel index (own = scale)
  std::vector<double> alpha;  // φ re-fit along the EMoR basis
};

Coefficients coefficients(const Spec& spec, const ChannelFit& f, int self, int nc, int terms) {
  Coefficients c;
  int k = 0;
  if (spec.fixed_scale) c.scale = spec.scale;
  else c.scale = f.theta(k++);
  if (spec.vignetting) {
    c.v1 = f.theta(k++) / c.scale;
    c.v2 = f.theta(k++) / c.scale;
  }
  if (spec.offset) c.offset = f.theta(k++);
  c.mix.assign(nc, 0.0);
  c.mix[self] = c.scale;
  if (spec.mixing)
    for (int d = 0; d < nc; ++d)
      if (d != self) {
        c.mix[d] = f.theta(k++);
        c.mix[self] -= c.mix[d];
      }
  for (int t = 0; t < terms; ++t) c.alpha.push_back(f.theta(k++));
  return c;
}

// An extended model explains the residuals only with physical parameters: a positive, finite exposure scale, an
// offset and a corner gain within the frame's range. A runaway fit (r → 10⁷, r < 0, an offset of 10⁶ full scales)
// can lower the held-out error by a fluke of the linearisation, and must not be reported as the camera's.
bool physical(const Spec& spec, const Evaluation& ev, int nc, int terms) {
  for (int c = 0; c < nc; ++c) {
    if (!ev.full[c].ok) continue;
    if (!ev.full[c].theta.allFinite()) return false;
    const Coefficients k = coefficients(spec, ev.full[c], c, nc, terms);
    if (!(k.scale > 0 && std::isfinite(k.scale))) return false;
    if (!(std::abs(k.offset) < 1)) return false;
    const double corner = 1 + k.v1 + k.v2;
    if (spec.vignetting && !(corner > 0.1 && corner < 10)) return false;
  }
  return true;
}

CrfFitResult averageFits(const std::vector<CrfFitResult>& fits) {
  CrfFitResult out = fits.front();
  std::vector<double> phi(kCurveSamples, 0.0);
  double total = 0, ratio = 0;
  int used = 0;
  for (const auto& f : fits) {
    const double w = std::max(1, f.pixels.used);
    for (int i = 0; i < kCurveSamples; ++i) phi[i] += w * f.inverse_crf[i];
    ratio += w * f.ratio;
    total += w;
    used += f.pixels.used;
  }
  for (auto& v : phi) v /= total;
  phi.front() = 0;
  phi.back() = 1;
  for (int i = 1; i < kCurveSamples; ++i) phi[i] = std::max(phi[i], phi[i - 1]);
  out.inverse_crf = phi;
  out.model = TableModel{phi};
  out.ratio = ratio / total;
  out.pixels.used = used;
  out.chosen = "table";
  out.choice_reason = "weighted mean of " + std::to_string(fits.size()) + " per-tile fits (per-tile kernels)";
  return out;
}

}  // namespace

EffectReport diagnoseEffects(const EffectInputs& in, const EffectOptions& options) {
  options.check();
  const auto start = Clock::now();
  EffectReport report;
  for (const auto& name : effectNames()) {
    EffectEntry e;
    e.name = name;
    e.threshold = options.min_z;
    e.gain_threshold = name == "signal_dependent_noise" ? options.min_noise_contrast : options.min_gain;
    report.entries.push_back(e);
  }
  auto entry = [&](const std::string& name) -> EffectEntry& {
    for (auto& e : report.entries)
      if (e.name == name) return e;
    throw Error("unknown effect " + name);
  };
  if (!options.enabled) {
    for (auto& e : report.entries) e.detail = "diagnostics disabled";
    return report;
  }
  if (in.channels.empty() || in.kernel.empty()) throw InvalidInput("effects: no channels or no kernel");
  const int nc = static_cast<int>(in.channels.size());
  const cv::Mat K = normalizeKernel(in.kernel);
  const int n = std::max(K.rows, K.cols);
  const int terms = options.phi_terms;

  // Inputs.
  Prepared p;
  std::vector<Curve> curves;
  for (const auto& name : in.channels) {
    if (!in.sharp.count(name) || !in.blurred.count(name) || !in.fits.count(name))
      throw InvalidInput("effects: channel " + name + " missing");
    p.I.push_back(unit(in.sharp.at(name)));
    p.B.push_back(unit(in.blurred.at(name)));
    p.depth.push_back(in.blurred.at(name).depth());
    curves.push_back(makeCurve(in.fits.at(name).inverse_crf));
    const int L = in.sharp.at(name).depth() == CV_8U ? 256 : 1024;
    p.levels.push_back(L);
    const double sigma = estimateNoiseSigma(p.I.back()).sigma;
    NoiseDebiasOptions dopt;
    dopt.levels = L;
    dopt.sigma = sigma * (L - 1) > 0.25 ? std::min(sigma, 0.5) : 0.0;  // below a quarter level: no bias to remove
    p.debias.emplace_back(dopt);
  }
  const cv::Size size = p.B[0].size();
  for (int c = 0; c < nc; ++c)
    if (p.I[c].size() != size || p.B[c].size() != size) throw InvalidInput("effects: channel sizes differ");
  {
    cv::Mat bad = cv::Mat::zeros(size, CV_8U);
    for (int c = 0; c < nc; ++c) {
      bad |= (p.B[c] >= in.fit.saturation_high) | (p.B[c] <= in.fit.saturation_low);
      // A noisy I touches 0 and 1 by noise alone (the debiased level functions model that clip, as in the fitter):
      // only regions whose local median is saturated are saturated — the darkest regions pin an offset.
      cv::Mat level = p.I[c];
      if (!p.debias[c].identity()) {
        cv::Mat f32, median;
        p.I[c].convertTo(f32, CV_32F);
        cv::medianBlur(f32, median, 5);
        level = cv::Mat();
        median.convertTo(level, CV_64F);
      }
      bad |= (level >= in.fit.saturation_high) | (level <= in.fit.saturation_low);
    }
    p.usable = ~dilateBy(bad, n);
    if (!in.valid.empty()) p.usable &= in.valid;
    const int m = n / 2 + 1;
    cv::Mat inner = cv::Mat::zeros(size, CV_8U);
    if (size.width > 2 * m && size.height > 2 * m)
      inner(cv::Rect(m, m, size.width - 2 * m, size.height - 2 * m)).setTo(255);
    p.usable &= inner;
  }
  const cv::Point2d centre =
      in.centre.x >= 0 ? in.centre : cv::Point2d((size.width - 1) / 2.0, (size.height - 1) / 2.0);
  const double radius = in.corner_radius > 0 ? in.corner_radius : 0.5 * std::hypot(size.width, size.height);
  p.rho2 = cv::Mat(size, CV_64F);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const double dx = (x - centre.x) / radius, dy = (y - centre.y) / radius;
      p.rho2.at<double>(y, x) = dx * dx + dy * dy;
    }
  const int grid = options.grid > 0 ? options.grid : (std::min(size.width, size.height) < 600 ? 2 : 3);
  const Layout layout = makeLayout(size, grid);
  const int blocks =
      ((size.width + options.block - 1) / options.block) * ((size.height + options.block - 1) / options.block);
  const int fine_side = std::max(1, options.block / 2);
  const int fine_blocks = ((size.width + fine_side - 1) / fine_side) * ((size.height + fine_side - 1) / fine_side);
  if (cv::countNonZero(p.usable) < 2000) {
    for (auto& e : report.entries) e.detail = "too few usable pixels";
    return report;
  }

  std::vector<cv::Mat> phiI;
  std::vector<double> ratios;
  for (const auto& name : in.channels) ratios.push_back(in.fits.at(name).ratio);
  Problem problem(collect(p, curves, ratios, K, layout, options, &phiI), blocks, fine_blocks, options.min_derivative);
  report.samples = static_cast<int>(problem.samples()[0].size());
  std::vector<char> used_fine(fine_blocks, 0);
  for (int b : problem.samples()[0].fine) used_fine[b] = 1;

  // Spatially varying blur: held-out per-tile kernels (kernels estimated in the irradiance domain of φ_G).
  const int g_index = [&] {
    for (int c = 0; c < nc; ++c)
      if (in.channels[c] == "G") return c;
    return 0;
  }();
  const bool spatial = options.test_spatial_blur && in.kernel_estimated;
  if (!spatial)
    entry("spatially_varying_blur").detail = in.kernel_estimated ? "disabled" : "kernel given (not estimated)";

  // One correction + refit with the extended model `spec`: the jointly re-fitted φ_ext = φ + Σ α_k h_k and the
  // parameters correct the pair, fitInverseCrf refits φ (same options; r fixed when fixed_ratio > 0). Empty on
  // failure.
  BlurTest blur;
  std::vector<std::vector<double>> noise_level, noise_sigma;  // per channel: σ(v) bins of I (noise test)
  auto refitOnce = [&](const Spec& spec, const std::vector<Curve>& cur, const std::vector<Coefficients>& cf,
                       const std::vector<ChannelFit>& ff, bool with_blur, bool with_noise, double fixed_ratio) {
    // φ_ext: the jointly re-fitted φ of the extended model; the corrections use it.
    std::vector<Curve> ext(nc);
    std::vector<cv::Mat> Y(nc);
    for (int c = 0; c < nc; ++c) {
      ext[c] = ff[c].ok ? makeCurve(adjustedPhi(cur[c].phi, cf[c].alpha)) : cur[c];
      Y[c] = ext[c].curve.inverse(p.B[c]);
      if (spec.vignetting) {
        cv::Mat g = 1.0 + cf[c].v1 * p.rho2 + cf[c].v2 * p.rho2.mul(p.rho2);
        g = cv::max(g, 0.05);
        cv::divide(Y[c], g, Y[c]);
      }
      if (spec.offset) Y[c] = Y[c] - cf[c].offset;
    }
    // Mixing: channel c's row of the mix applied to I's irradiances, so that B_c = ψ_c(a_c K ⊗ φ_c(I'_c)) holds:
    // I'_c = ψ_c(φ_c(I_c) + Σ_{d≠c} (m_cd / a_c) (φ_d(I_d) − φ_c(I_c))) — only the channel's own row is needed.
    std::vector<cv::Mat> mixedI(nc);
    if (spec.mixing) {
      std::vector<cv::Mat> phiI(nc);
      for (int d = 0; d < nc; ++d) phiI[d] = ext[d].curve.inverse(p.I[d]);
      for (int c = 0; c < nc; ++c) {
        cv::Mat e = phiI[c].clone();
        for (int d = 0; d < nc; ++d)
          if (d != c && cf[c].scale > 0) e += (cf[c].mix[d] / cf[c].scale) * (phiI[d] - phiI[c]);
        cv::Mat i = ext[c].curve.forward(cv::max(cv::min(e, 1.0), 0.0));
        i.setTo(0, p.I[c] <= 0);  // no data stays no data
        mixedI[c] = store(i, in.sharp.at(in.channels[c]).depth());
      }
    }
    std::map<std::string, CrfFitResult> fits;
    for (int c = 0; c < nc; ++c) {
      const cv::Mat Bc = store(ext[c].curve.forward(cv::max(cv::min(Y[c], 1.0), 0.0)), p.depth[c]);
      const cv::Mat& Ic = spec.mixing ? mixedI[c] : in.sharp.at(in.channels[c]);
      CrfFitOptions fo = in.fit;
      fo.progress = nullptr;
      if (ff[c].ok && cf[c].scale > 0) fo.nominal_ratio = cf[c].scale;  // the extended model's r as the start
      if (fixed_ratio > 0) {
        fo.nominal_ratio = fixed_ratio;
        fo.fit_ratio = false;
      }
      if (spec.clipping && ff[c].ok && ff[c].clip > 0 && ff[c].clip <= 1) {  // the plateau is treated like saturation
        const double level = ff[c].clip - 0.5 / fullScale(in.blurred.at(in.channels[c]));
        fo.saturation_high = std::max(fo.saturation_low + 0.1, std::min(fo.saturation_high, level));
      }
      if (with_noise) {
        const int L = std::max(naturalLevels(Ic), naturalLevels(Bc));  // the fitter's level grid
        fo.noise_sigma_per_level = noiseSigmaPerLevel(noise_level[c], noise_sigma[c], L);
      }
      try {
        if (with_blur) {
          // Per-tile fits, each with the first-order kernel at its centre, averaged.
          std::vector<CrfFitResult> tile_fits;
          for (const auto& t : layout.tiles) {
            const cv::Point2d tc(t.x + t.width / 2.0, t.y + t.height / 2.0);
            const cv::Mat kt = kernelAt(blur, (tc.x - centre.x) / radius, (tc.y - centre.y) / radius);
            const int m = std::max(kt.rows, kt.cols) / 2 + 1;
            const cv::Rect big = cv::Rect(t.x - m, t.y - m, t.width + 2 * m, t.height + 2 * m) &
                                 cv::Rect(0, 0, size.width, size.height);
            CrfFitOptions to = fo;
            to.min_pixels = std::min(fo.min_pixels, 100);
            try {
              tile_fits.push_back(fitInverseCrf(Ic(big), Bc(big), kt, to));
            } catch (const InvalidInput&) {
              // a tile without edges: skipped
            }
          }
          if (tile_fits.empty()) throw InvalidInput("no tile could be fitted");
          fits[in.channels[c]] = averageFits(tile_fits);
        } else {
          fits[in.channels[c]] = fitInverseCrf(Ic, Bc, K, fo);
        }
      } catch (const InvalidInput&) {
        fits.clear();
        break;
      }
    }
    return fits;
  };

  // Greedy forward selection of the level/blur effects.
  Spec current;
  Evaluation current_eval = problem.evaluate(current);
  report.base_error = current_eval.count > 0 ? current_eval.total / current_eval.count : 0;
  std::vector<std::string> candidates{"vignetting", "black_level_offset", "clipping"};
  if (nc == 3) candidates.push_back("channel_mixing");
  else entry("channel_mixing").detail = "needs three channels (--channels rgb)";
  std::vector<std::string> selected;
  auto extend = [](Spec s, const std::string& name) {
    if (name == "vignetting") s.vignetting = true;
    if (name == "black_level_offset") s.offset = true;
    if (name == "clipping") s.clipping = true;
    if (name == "channel_mixing") s.mixing = true;
    return s;
  };
  // The held-out test of one effect: `without` the model lacking it, `with` the model having it.
  // A plateau acts only where B reaches it: the paired test (and the relative gain) runs over the half-size
  // blocks that contain plateau samples — chosen from B alone, so the selection does not favour the extended
  // model (a localised effect touches too few full blocks for a test over blocks).
  auto effectTest = [&](const std::string& name, const Evaluation& without, const Evaluation& with) {
    Comparison cmp;
    if (name == "clipping") {
      std::vector<char> plateau(fine_blocks, 0);
      for (const auto& smp : problem.samples()) {
        const int c = static_cast<int>(&smp - problem.samples().data());
        const double clip = with.full[c].ok ? with.full[c].clip : 2.0;
        for (std::size_t i = 0; i < smp.size(); ++i)
          if (smp.level[i] >= clip) plateau[smp.fine[i]] = 1;
      }
      double base_total = 0;
      for (int b = 0; b < fine_blocks; ++b)
        if (plateau[b]) base_total += without.fine_error[b];
      cmp = scoreTest(problem.samples(), without, with, plateau, blocks);
      cmp.gain = base_total > 0 ? cmp.gain / base_total : 0;
    } else {
      cmp = scoreTest(problem.samples(), without, with, used_fine, blocks);
      cmp.gain = without.total > 0 ? cmp.gain / without.total : 0;
    }
    return cmp;
  };
  while (true) {
    std::string best;
    double best_gain = 0;
    Evaluation best_eval;
    for (const auto& name : candidates) {
      if (std::find(selected.begin(), selected.end(), name) != selected.end()) continue;
      const Evaluation& be = current_eval;
      const Evaluation ee = problem.evaluate(extend(current, name), true, &current_eval);
      const Comparison cmp = effectTest(name, be, ee);
      // Reported: how far the extended model moves φ (its re-fit vs the grown model's, both on all samples; RMSE over
      // [0, 1], clipping: below the plateau, above it nothing is measured; worst channel). A linearised first step:
      // the refit rounds move φ further.
      double phi_change = 0;
      for (int c = 0; c < nc; ++c) {
        if (!be.full[c].ok || !ee.full[c].ok) continue;
        const auto pb = adjustedPhi(curves[c].phi, coefficients(current, be.full[c], c, nc, terms).alpha);
        const auto pe = adjustedPhi(curves[c].phi, coefficients(extend(current, name), ee.full[c], c, nc, terms).alpha);
        std::size_t top = pb.size();
        if (name == "clipping" && ee.full[c].clip > 0 && ee.full[c].clip <= 1)
          top = static_cast<std::size_t>(ee.full[c].clip * (pb.size() - 1)) + 1;
        phi_change = std::max(phi_change, curveRmse(std::vector<double>(pb.begin(), pb.begin() + top),
                                                    std::vector<double>(pe.begin(), pe.begin() + top)));
      }
      EffectEntry& e = entry(name);
      e.tested = true;
      e.gain = cmp.gain;
      e.statistic = cmp.z;
      e.parameters["phi_change"] = phi_change;
      const bool plausible = physical(extend(current, name), ee, nc, terms);
      if (!plausible) e.detail = "the extended model's parameters are not physical (runaway fit): not considered";
      if (plausible && cmp.gain >= options.min_gain && cmp.z >= options.min_z && cmp.gain > best_gain) {
        best = name;
        best_gain = cmp.gain;
        best_eval = ee;
      }
    }
    if (best.empty()) break;
    selected.push_back(best);
    entry(best).detected = true;
    current = extend(current, best);
    current_eval = best_eval;
    // The next effects are tested around the grown model's own φ (the linearised re-fit stays local): the pair is
    // corrected with the grown model and refitted, residuals re-collected and the grown model re-evaluated — until φ
    // settles (refit_rounds at most). One round left structure that a companion effect then "explained": channel
    // mixing was named alone in 1 of 10 planted cases after one round, 8 of 10 after three (docs/RESULTS.md#effects).
    for (int round = 0; round < std::max(1, options.refit_rounds); ++round) {
      bool moved = false;
      double phi_moved = 0;
      {
        std::vector<Coefficients> cc(nc);
        for (int c = 0; c < nc; ++c)
          if (current_eval.full[c].ok) cc[c] = coefficients(current, current_eval.full[c], c, nc, terms);
        const auto fits = options.refit ? refitOnce(current, curves, cc, current_eval.full, false, false, 0.0)
                                        : std::map<std::string, CrfFitResult>{};
        for (int c = 0; c < nc; ++c) {
          if (!current_eval.full[c].ok) continue;
          const std::vector<double> before = curves[c].phi;
          if (!fits.empty()) {
            curves[c] = makeCurve(fits.at(in.channels[c]).inverse_crf);
            ratios[c] = fits.at(in.channels[c]).ratio;
          } else {
            curves[c] = makeCurve(adjustedPhi(curves[c].phi, cc[c].alpha));
            ratios[c] = cc[c].scale;
          }
          phi_moved = std::max(phi_moved, curveRmse(before, curves[c].phi));
          moved = true;
        }
      }
      if (moved) {
        problem = Problem(collect(p, curves, ratios, K, layout, options, &phiI), blocks, fine_blocks, options.min_derivative);
        current_eval = problem.evaluate(current);
      }
      if (!moved || phi_moved < 5e-4) break;  // settled: well below the 0.005 accuracy φ is judged by
    }
  }

  // Backward pass: with two or more effects selected, each must still pass the same test inside the final model
  // (the model without it vs the final one, around the final φ). Greedy forward selection keeps a companion that
  // only absorbed what the first effect's unsettled re-fit left behind (measured on planted channel mixing: an
  // offset, clipping or vignetting named next to it in 6 of 20 pairs).
  auto specWithout = [&](const std::string& dropped) {  // the selected effects except `dropped`
    Spec spec;
    for (const auto& other : selected)
      if (other != dropped) spec = extend(spec, other);
    return spec;
  };
  while (selected.size() >= 2) {
    std::string weakest;
    double weakest_gain = std::numeric_limits<double>::infinity();
    Comparison weakest_cmp;
    for (const auto& name : selected) {
      const Comparison cmp = effectTest(name, problem.evaluate(specWithout(name)), current_eval);
      if (!(cmp.gain >= options.min_gain && cmp.z >= options.min_z) && cmp.gain < weakest_gain) {
        weakest = name;
        weakest_gain = cmp.gain;
        weakest_cmp = cmp;
      }
    }
    if (weakest.empty()) break;
    selected.erase(std::find(selected.begin(), selected.end(), weakest));
    EffectEntry& e = entry(weakest);
    e.detected = false;
    e.gain = weakest_cmp.gain;
    e.statistic = weakest_cmp.z;
    e.parameters["dropped_by_backward_pass"] = true;
    current = specWithout({});
    current_eval = problem.evaluate(current);
  }

  // Parameters of the selected model (fitted on all samples); the other effects' parameters as if added to it.
  std::vector<Coefficients> coef;
  for (int c = 0; c < nc; ++c)
    coef.push_back(current_eval.full[c].ok ? coefficients(current, current_eval.full[c], c, nc, terms)
                                           : Coefficients{});
  const int gi = g_index;
  auto withEffect = [&](const std::string& name, bool has) -> std::pair<Spec, Evaluation> {
    if (has) return {current, current_eval};
    const Spec s = extend(current, name);
    return {s, problem.evaluate(s, false)};
  };
  {
    const auto [s, ev] = withEffect("vignetting", current.vignetting);
    const Coefficients v = ev.full[gi].ok ? coefficients(s, ev.full[gi], gi, nc, terms) : Coefficients{};
    auto& e = entry("vignetting");
    e.parameters["v1"] = v.v1;
    e.parameters["v2"] = v.v2;
    e.parameters["corner_gain"] = 1 + v.v1 + v.v2;
    e.detail = fmt("gain of B relative to I at the corner %.3f (1 + v1 rho^2 + v2 rho^4, v1 %.3f, v2 %.3f)",
                   1 + v.v1 + v.v2, v.v1, v.v2);
  }
  {
    const auto [s, ev] = withEffect("black_level_offset", current.offset);
    const Coefficients c = ev.full[gi].ok ? coefficients(s, ev.full[gi], gi, nc, terms) : Coefficients{};
    auto& e = entry("black_level_offset");
    e.parameters["offset"] = c.offset;
    e.parameters["scale"] = c.scale;
    e.detail = fmt("additive irradiance offset %.4f of full scale ", c.offset) +
               (c.offset >= 0 ? "(B brighter: flare/offset in B, or a negative offset in I)"
                              : "(I brighter: offset in I, or a negative offset in B)");
  }
  {
    const auto [s, ev] = withEffect("clipping", current.clipping);
    const double level = ev.full[gi].ok && ev.full[gi].clip > 0 && ev.full[gi].clip <= 1 ? ev.full[gi].clip : 1.0;
    auto& e = entry("clipping");
    const double irradiance = curves[gi].curve.inverse(level);
    e.parameters["clip_irradiance"] = irradiance;
    e.parameters["clip_intensity"] = level;
    e.detail = fmt("plateau of B at intensity %.3f (irradiance %.3f): pixels there are censored", level, irradiance);
  }
  if (nc == 3) {
    auto& e = entry("channel_mixing");
    const auto [s, ev] = withEffect("channel_mixing", current.mixing);
    double largest = 0;
    for (int c = 0; c < nc; ++c) {
      if (!ev.full[c].ok) continue;
      const Coefficients cc = coefficients(s, ev.full[c], c, nc, terms);
      for (int d = 0; d < nc; ++d) {
        const double m = cc.mix[d] / cc.scale;
        e.parameters["m_" + in.channels[c] + in.channels[d]] = m;
        if (d != c) largest = std::max(largest, std::abs(m));
      }
    }
    e.detail = fmt("largest off-diagonal mix %.3f (relative to the own channel)", largest);
  }
  // Spatially varying blur (first-order kernel), around the selected model's φ.
  if (spatial) {
    auto& e = entry("spatially_varying_blur");
    const cv::Mat g = [&] {
      std::vector<double> f = onLevels(curves[g_index].phi, p.levels[g_index]);
      if (!p.debias[g_index].identity()) f = p.debias[g_index].apply(f);
      return applyTable(p.I[g_index], f);
    }();
    blur = spatialBlurTest(problem.samples()[g_index], g, K, centre, radius, blocks,
                           options.min_derivative, 15000);
    if (!blur.ok) {
      e.detail = blur.problem;
    } else {
      e.tested = true;
      e.gain = blur.cmp.gain;
      e.statistic = blur.cmp.z;
      e.detected = blur.cmp.gain >= options.min_gain && blur.cmp.z >= options.min_z;
      e.parameters = {{"variation", blur.variation},
                      {"corner_kernel_difference", kernelRelativeError(kernelAt(blur, 0.7071, 0.7071), kernelAt(blur, 0, 0))}};
      e.detail = fmt("kernel linear in the position: the kernel changes by %.3f (relative) from the centre to a corner",
                     e.parameters["corner_kernel_difference"]);
    }
  }

  // Exposure ratio: a free vs fixed to EXIF, within the selected model.
  {
    auto& e = entry("exposure_ratio_mismatch");
    if (!(in.exif_ratio > 0)) {
      e.detail = "no EXIF ratio";
    } else {
      Spec fixed = current;
      fixed.fixed_scale = true;
      fixed.scale = in.exif_ratio;
      // The seed's model with r = r_EXIF gets its own best φ (the fitter with r fixed) before the local re-fit:
      // a φ fitted with a free r sits in a different valley (φ^γ trades with r^γ) that the local re-fit
      // cannot leave, so "r fixed" would be judged around the wrong φ.
      Evaluation fe;
      try {
        std::vector<Curve> fixed_curves = curves;
        const bool corrected = current.vignetting || current.offset || current.mixing || current.clipping;
        const auto fixed_fits =
            corrected ? refitOnce(current, curves, coef, current_eval.full, false, false, in.exif_ratio)
                      : std::map<std::string, CrfFitResult>{};
        for (int c = 0; c < nc; ++c) {
          if (corrected) {
            if (fixed_fits.empty()) throw InvalidInput("fixed-ratio refit failed");
            fixed_curves[c] = makeCurve(fixed_fits.at(in.channels[c]).inverse_crf);
            continue;
          }
          CrfFitOptions fo = in.fit;
          fo.progress = nullptr;
          fo.fit_ratio = false;
          fo.nominal_ratio = in.exif_ratio;
          fixed_curves[c] = makeCurve(fitInverseCrf(in.sharp.at(in.channels[c]), in.blurred.at(in.channels[c]), K, fo).inverse_crf);
        }
        const Problem fixed_problem(collect(p, fixed_curves, std::vector<double>(nc, in.exif_ratio), K, layout, options,
                                            nullptr),
                                    blocks, fine_blocks, options.min_derivative);
        fe = fixed_problem.evaluate(fixed);
      } catch (const InvalidInput&) {
        fe = problem.evaluate(fixed);
      }
      Comparison cmp = scoreTest(problem.samples(), fe, current_eval, used_fine, blocks);
      cmp.gain = fe.total > 0 ? cmp.gain / fe.total : 0;
      const double a = coef[gi].scale;
      const double rel = a / in.exif_ratio - 1;
      e.tested = true;
      e.gain = cmp.gain;
      e.statistic = cmp.z;
      // a non-positive or non-finite scale is a runaway fit, not a ratio (see physical())
      e.detected = a > 0 && std::isfinite(a) && cmp.gain >= options.min_gain && cmp.z >= options.min_z &&
                   std::abs(rel) > options.ratio_tolerance;
      e.parameters = {{"fitted_ratio", a}, {"exif_ratio", in.exif_ratio}, {"relative_difference", rel},
                      {"tolerance", options.ratio_tolerance}};
      e.detail = fmt("fitted r %.4f vs EXIF %.4f (%+.1f%%; tolerance of nominal EXIF values ", a, in.exif_ratio,
                     100 * rel) +
                 fmt("%.0f%%); phi from the free-r fit", 100 * options.ratio_tolerance);
    }
  }

  // Signal-dependent noise, on I itself.
  bool noise_detected = false;
  {
    auto& e = entry("signal_dependent_noise");
    cv::Mat valid = in.valid.empty() ? cv::Mat(size, CV_8U, cv::Scalar(255)) : in.valid.clone();
    for (int c = 0; c < nc; ++c) valid &= (p.I[c] > 0);  // sharp 0: no data (outside the registration overlap)
    const NoiseTest nt = noiseTest(p.I, valid, layout, options.block, options.noise_bins, blocks);
    if (!nt.ok) {
      e.detail = nt.problem;
    } else {
      std::vector<char> noise_blocks(blocks, 0);
      for (int b = 0; b < blocks; ++b) noise_blocks[b] = nt.block_nll_base[b] != 0 || nt.block_nll_ext[b] != 0;
      const Comparison cmp = compare(nt.block_nll_base, nt.block_nll_ext, 1.0, noise_blocks);
      e.tested = true;
      e.gain = (nt.total_base - nt.total_ext) / nt.count;
      e.statistic = cmp.z;
      noise_detected = e.gain > 0 && cmp.z >= options.min_z && nt.contrast >= options.min_noise_contrast;
      e.detected = noise_detected;
      e.parameters = {{"contrast", nt.contrast}, {"contrast_threshold", options.min_noise_contrast},
                      {"samples", static_cast<double>(nt.count)}};
      const auto& lv = nt.level[gi];
      const auto& sg = nt.sigma[gi];
      for (std::size_t b = 0; b < lv.size(); ++b) {
        e.parameters["level_" + std::to_string(b)] = lv[b];
        e.parameters["sigma_" + std::to_string(b)] = sg[b];
      }
      noise_level = nt.level;
      noise_sigma = nt.sigma;
      e.detail = fmt("noise std of I from %.1f/255 (level %.2f) ", 255 * sg.front(), lv.front()) +
                 fmt("to %.1f/255 (level %.2f); variance contrast %.2f", 255 * sg.back(), lv.back(), nt.contrast);
      if (noise_detected)
        e.detail += in.fit.experimental.noise == NoiseHandling::none
                        ? "; phi from the base fit (noise handling none: pixels are selected by B alone, so sigma(v) "
                          "would only change the weights)"
                        : "; sigma(v) handed to the refit (noise_sigma_per_level)";
    }
  }

  // φ from the extended model.
  const bool blur_refit = spatial && entry("spatially_varying_blur").detected;
  const bool level_refit = current.vignetting || current.offset || current.mixing || current.clipping || blur_refit;
  const bool noise_refit = noise_detected && in.fit.experimental.noise != NoiseHandling::none;
  // A wrong EXIF ratio can also trap the fitter (it starts from r_EXIF): refit from the diagnostics' ratio.
  bool ratio_refit = false;
  if (entry("exposure_ratio_mismatch").detected)
    for (int c = 0; c < nc; ++c)
      if (current_eval.full[c].ok && std::abs(in.fits.at(in.channels[c]).ratio / coef[c].scale - 1) > 0.02)
        ratio_refit = true;
  if (options.refit && (level_refit || noise_refit || ratio_refit)) {
    std::vector<Curve> cur = curves;
    std::vector<Coefficients> cf = coef;
    std::vector<ChannelFit> ff = current_eval.full;
    for (int round = 0; round < options.refit_rounds; ++round) {
      const auto fits = refitOnce(current, cur, cf, ff, blur_refit, noise_refit, 0.0);
      if (fits.empty()) break;
      report.fits = fits;
      if (round + 1 == options.refit_rounds || !level_refit) break;
      // Re-estimate the parameters (and φ_ext) with the refitted φ.
      for (int c = 0; c < nc; ++c) cur[c] = makeCurve(report.fits.at(in.channels[c]).inverse_crf);
      std::vector<double> rr;
      for (const auto& name : in.channels) rr.push_back(report.fits.at(name).ratio);
      Problem again(collect(p, cur, rr, K, layout, options, nullptr), blocks, fine_blocks, options.min_derivative);
      const Evaluation ev = again.evaluate(current, false);
      for (int c = 0; c < nc; ++c)
        if (ev.full[c].ok) {
          cf[c] = coefficients(current, ev.full[c], c, nc, terms);
          ff[c] = ev.full[c];
        }
    }
  }
  report.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return report;
}

}  // namespace crfcal
