#include "crfcal/effects.hpp"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <numeric>
#include <sstream>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "crfcal/blur_model.hpp"
#include "crfcal/emor.hpp"
#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
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
  if (!(min_nll_gain >= 0)) throw InvalidInput("effect options: min_nll_gain must be >= 0");
  if (!(ratio_tolerance >= 0)) throw InvalidInput("effect options: ratio_tolerance must be >= 0");
  if (block < 8) throw InvalidInput("effect options: block must be >= 8");
  if (max_samples < 1000) throw InvalidInput("effect options: max_samples must be >= 1000");
  if (grid < 0 || grid > 6) throw InvalidInput("effect options: grid must be in 0..6");
  if (!(min_derivative > 0)) throw InvalidInput("effect options: min_derivative must be > 0");
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
    char buffer[400];
    if (!e.tested)
      std::snprintf(buffer, sizeof buffer, "\n  %-24s not tested (%s)", e.name.c_str(), e.detail.c_str());
    else
      std::snprintf(buffer, sizeof buffer, "\n  %-24s %s  gain %.4f (>= %.3f)  z %.2f (>= %.1f)  %s", e.name.c_str(),
                    e.detected ? "DETECTED" : "no      ", e.gain, e.gain_threshold, e.statistic, e.threshold,
                    e.detail.c_str());
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

Curve makeCurve(const std::vector<double>& phi) { return Curve{ResponseCurve::fromSamples(phi), phi}; }

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
  std::vector<int> block, fold, tile;
  std::vector<double> w;      // 1 / φ'(B): irradiance → intensity scale
  std::vector<double> Y;      // φ(B)
  std::vector<double> rho2;   // (r / R)²
  std::vector<double> level;  // B intensity
  std::vector<std::vector<double>> X;  // per channel index: a-free prediction φ_d(I_d) ⊗ K
  std::vector<double> Xt_ext, Xt_base; // held-out per-tile / held-out global kernel (spatial test)
  std::vector<std::vector<double>> P;  // φ-perturbation columns a₀ K⊗h_k(I) − h_k(B) (EMoR basis h_k)
  std::vector<double> u, t;            // noise: e-variance per unit σ_I² (u) and per unit β·I (t)
  std::vector<cv::Point> pos;
  std::size_t size() const { return Y.size(); }
};

enum class Source { global, heldout_global, tile };

struct Spec {
  bool vignetting = false, offset = false, mixing = false, clipping = false;
  Source source = Source::global;
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
  double total = 0;
  long count = 0;
  std::vector<std::vector<double>> residual;  // held-out e per channel, per sample
  std::vector<ChannelFit> full;               // fitted on all samples (parameters for reporting/correction)
};

class Problem {
 public:
  Problem(std::vector<Samples> samples, int blocks) : s_(std::move(samples)), blocks_(blocks) {}
  const std::vector<Samples>& samples() const { return s_; }
  std::vector<Samples>& samples() { return s_; }
  int channels() const { return static_cast<int>(s_.size()); }

  double scaleColumn(const Samples& s, std::size_t i, Source source) const {
    switch (source) {
      case Source::global: return s.X[self(s)][i];
      case Source::heldout_global: return s.Xt_base[i];
      case Source::tile: return s.Xt_ext[i];
    }
    return 0;
  }

  // Columns of the linear part. Column 0 is the scale column unless the scale is fixed.
  int row(const Samples& s, std::size_t i, const Spec& spec, double* out, double& target) const {
    const double x = scaleColumn(s, i, spec.source);
    int k = 0;
    target = s.Y[i];
    if (spec.fixed_scale) target -= spec.scale * x;
    else out[k++] = x;
    if (spec.vignetting) {
      out[k++] = x * s.rho2[i];
      out[k++] = x * s.rho2[i] * s.rho2[i];
    }
    if (spec.offset) out[k++] = 1.0;
    if (spec.mixing)
      for (int d = 0; d < static_cast<int>(s.X.size()); ++d)
        if (d != self(s)) out[k++] = s.X[d][i];
    for (const auto& column : s.P) out[k++] = column[i];  // φ re-adjusts with every model (nested, fair)
    return k;
  }

  ChannelFit fit(const Samples& s, const Spec& spec, int fold) const {
    std::vector<std::size_t> idx;
    for (std::size_t i = 0; i < s.size(); ++i)
      if (fold < 0 || s.fold[i] == fold) idx.push_back(i);
    ChannelFit best;
    if (idx.size() < 20) return best;
    std::vector<double> clips{0};
    if (spec.clipping) {
      std::vector<double> y;
      for (auto i : idx) y.push_back(s.Y[i]);
      std::sort(y.begin(), y.end());
      for (double q : {1.0, 0.999, 0.995, 0.99, 0.98, 0.95, 0.9, 0.8})
        clips.push_back(y[static_cast<std::size_t>(q * (y.size() - 1))]);
    }
    double best_error = std::numeric_limits<double>::infinity();
    double buffer[32];
    for (double clip : clips) {
      if (spec.clipping && clip <= 0) continue;
      Eigen::MatrixXd A;
      Eigen::VectorXd b;
      int cols = 0;
      {
        double t;
        cols = row(s, idx[0], spec, buffer, t);
      }
      A = Eigen::MatrixXd::Zero(cols, cols);
      b = Eigen::VectorXd::Zero(cols);
      for (auto i : idx) {
        if (clip > 0 && s.Y[i] >= clip * (1 - 1e-9)) continue;
        double t;
        row(s, i, spec, buffer, t);
        const double w2 = s.w[i] * s.w[i];
        for (int a = 0; a < cols; ++a) {
          b(a) += w2 * buffer[a] * t;
          for (int c = 0; c < cols; ++c) A(a, c) += w2 * buffer[a] * buffer[c];
        }
      }
      Eigen::VectorXd theta = Eigen::VectorXd::Zero(cols);
      if (cols > 0) {
        A.diagonal().array() += 1e-12 * (A.diagonal().array().abs().maxCoeff() + 1e-30);
        theta = A.ldlt().solve(b);
      }
      if (!theta.allFinite()) continue;
      ChannelFit f{theta, clip, true};
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

  double residual(const Samples& s, std::size_t i, const Spec& spec, const ChannelFit& f) const {
    double buffer[32], t;
    const int cols = row(s, i, spec, buffer, t);
    double p = 0;
    for (int a = 0; a < cols; ++a) p += f.theta(a) * buffer[a];
    // p predicts target = Y − fixed part.
    if (f.clip > 0) {
      const double fixed = s.Y[i] - t;
      const double full = std::min(p + fixed, f.clip);
      return s.w[i] * (s.Y[i] - full);
    }
    return s.w[i] * (t - p);
  }

  Evaluation evaluate(const Spec& spec) const {
    Evaluation ev;
    ev.block_error.assign(blocks_, 0.0);
    ev.residual.resize(s_.size());
    for (const auto& s : s_) {
      const int c = static_cast<int>(&s - s_.data());
      ev.residual[c].assign(s.size(), 0.0);
      const ChannelFit f0 = fit(s, spec, 0), f1 = fit(s, spec, 1);
      for (std::size_t i = 0; i < s.size(); ++i) {
        const ChannelFit& f = s.fold[i] == 0 ? f1 : f0;  // held out
        if (!f.ok) continue;
        const double e = residual(s, i, spec, f);
        ev.residual[c][i] = e;
        ev.block_error[s.block[i]] += e * e;
        ev.total += e * e;
        ++ev.count;
      }
      ev.full.push_back(fit(s, spec, -1));
    }
    return ev;
  }

  int self(const Samples& s) const { return static_cast<int>(&s - s_.data()); }
  int blocks() const { return blocks_; }

 private:
  std::vector<Samples> s_;
  int blocks_;
};

struct Comparison {
  double gain = 0, z = 0;
};

Comparison compare(const std::vector<double>& base, const std::vector<double>& ext, double base_total,
                   const std::vector<char>* used = nullptr) {
  std::vector<double> d;
  double sum = 0;
  for (std::size_t b = 0; b < base.size(); ++b)
    if (used ? (*used)[b] != 0 : (base[b] > 0 || ext[b] > 0)) {
      d.push_back(base[b] - ext[b]);
      sum += d.back();
    }
  Comparison c;
  if (d.size() < 4 || !(base_total > 0)) return c;
  const double mean = sum / d.size();
  double var = 0;
  for (double v : d) var += (v - mean) * (v - mean);
  var /= (d.size() - 1);
  c.gain = sum / base_total;
  c.z = var > 0 ? mean / std::sqrt(var / d.size()) : (mean > 0 ? 1e9 : 0);
  return c;
}

cv::Mat denoiseForKernel(const cv::Mat& image) {
  const double sigma = estimateNoiseSigma(image).sigma;
  if (!(sigma > 0.002)) return image;
  cv::Mat f, out;
  image.convertTo(f, CV_32F);
  cv::bilateralFilter(f, out, 7, static_cast<float>(std::max(3 * sigma, 0.02)), 2.0);
  out.convertTo(out, CV_64F);
  return out;
}

// Convolution restricted to `rect` (with a margin so that the values inside rect are exact).
cv::Mat convolveIn(const cv::Mat& image, const cv::Mat& kernel, const cv::Rect& rect) {
  const int m = std::max(kernel.rows, kernel.cols) / 2 + 1;
  const cv::Rect big = cv::Rect(rect.x - m, rect.y - m, rect.width + 2 * m, rect.height + 2 * m) &
                       cv::Rect(0, 0, image.cols, image.rows);
  const cv::Mat c = convolve(image(big), kernel);
  return c(cv::Rect(rect.x - big.x, rect.y - big.y, rect.width, rect.height)).clone();
}

struct Prepared {
  std::vector<cv::Mat> I, B;        // unit CV_64F per channel (original)
  std::vector<int> depth;
  cv::Mat usable;                   // CV_8U
  cv::Mat rho2;                     // CV_64F
  cv::Point2d centre;
  double radius = 1;
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

std::vector<Samples> collect(const Prepared& p, const std::vector<Curve>& curves, const std::vector<double>& ratios,
                             const cv::Mat& K, const Layout& layout, int block, int max_samples, int terms,
                             std::vector<cv::Mat>* phiI_out) {
  const int nc = static_cast<int>(p.I.size());
  std::vector<cv::Mat> phiI(nc), phiB(nc), X(nc), U(nc), T(nc);
  std::vector<std::vector<cv::Mat>> P(nc);
  const cv::Mat K2 = K.mul(K);
  for (int c = 0; c < nc; ++c) {
    phiI[c] = curves[c].curve.inverse(p.I[c]);
    phiB[c] = curves[c].curve.inverse(p.B[c]);
    X[c] = convolve(phiI[c], K);
    std::vector<double> d2(curves[c].phi.size());
    for (std::size_t i = 0; i < d2.size(); ++i) {
      const double d = curves[c].derivative(static_cast<double>(i) / (d2.size() - 1));
      d2[i] = d * d;
    }
    const cv::Mat dI2 = applyTable(p.I[c], d2);
    const double k2 = cv::sum(K2)[0];  // convolve() wants a normalised kernel
    U[c] = convolve(dI2, K2 / k2) * k2;
    T[c] = convolve(dI2.mul(p.I[c]), K2 / k2) * k2;
    for (int k = 1; k <= terms; ++k) {
      const auto span = emor::inverseBasis(k);
      const std::vector<double> h(span.begin(), span.end());
      P[c].push_back(ratios[c] * convolve(applyTable(p.I[c], h), K) - applyTable(p.B[c], h));
    }
  }
  if (phiI_out) *phiI_out = phiI;
  const int usable = cv::countNonZero(p.usable);
  const int stride = std::max(1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(usable) / max_samples))));
  const int bx = (p.usable.cols + block - 1) / block;
  std::vector<Samples> out(nc);
  for (int y = 0; y < p.usable.rows; y += stride) {
    const uchar* m = p.usable.ptr<uchar>(y);
    for (int x = (y / stride) % 2 == 0 ? 0 : stride / 2; x < p.usable.cols; x += stride) {
      if (!m[x]) continue;
      const int tile = layout.tile_map.at<int>(y, x), half = layout.half_map.at<uchar>(y, x);
      for (int c = 0; c < nc; ++c) {
        Samples& s = out[c];
        const double b = p.B[c].at<double>(y, x);
        s.block.push_back((y / block) * bx + x / block);
        s.fold.push_back(layout.fold(tile, half));
        s.tile.push_back(tile);
        s.w.push_back(1.0);  // set below
        s.Y.push_back(phiB[c].at<double>(y, x));
        s.rho2.push_back(p.rho2.at<double>(y, x));
        s.level.push_back(b);
        s.pos.emplace_back(x, y);
        s.X.resize(nc);
        for (int d = 0; d < nc; ++d) s.X[d].push_back(X[d].at<double>(y, x));
        s.P.resize(P[c].size());
        for (std::size_t k = 0; k < P[c].size(); ++k) s.P[k].push_back(P[c][k].at<double>(y, x));
        s.u.push_back(U[c].at<double>(y, x));
        s.t.push_back(T[c].at<double>(y, x));
      }
    }
  }
  for (int c = 0; c < nc; ++c)
    for (std::size_t i = 0; i < out[c].size(); ++i) {
      out[c].w[i] = 1.0 / std::max(curves[c].derivative(out[c].level[i]), 0.05);
      const double f = out[c].w[i] * out[c].w[i] * ratios[c] * ratios[c];
      out[c].u[i] *= f;
      out[c].t[i] *= f;
    }
  return out;
}

struct TileKernels {
  bool ok = false;
  std::string problem;
  std::vector<std::array<cv::Mat, 2>> half;  // per tile, per half
  std::array<cv::Mat, 2> global;             // per fold
};

int croppedSize(const cv::Mat& K, int limit) {
  const cv::Mat c = cropKernel(K, 0.0);
  int n = std::max(c.rows, c.cols) + 8;
  if (n % 2 == 0) ++n;
  return std::min(std::max(n, 9), std::max(limit, 9) | 1);
}

TileKernels estimateTileKernels(const cv::Mat& phiI, const cv::Mat& phiB, const cv::Mat& usable, const Layout& layout,
                                const cv::Mat& K, const KernelEstimationOptions& base) {
  TileKernels tk;
  KernelEstimationOptions ko = base;
  ko.progress = nullptr;
  ko.throw_on_size_limit = false;
  ko.kernel_size = croppedSize(K, base.kernel_size);
  const cv::Mat den = denoiseForKernel(phiI);
  tk.half.resize(layout.tiles.size());
  std::array<std::vector<cv::Rect>, 2> by_fold;
  for (std::size_t t = 0; t < layout.tiles.size(); ++t)
    for (int h = 0; h < 2; ++h) by_fold[layout.fold(static_cast<int>(t), h)].push_back(layout.halves[t][h]);
  try {
    for (int f = 0; f < 2; ++f) tk.global[f] = estimateKernel(den, phiB, by_fold[f], usable, ko).kernel;
  } catch (const InvalidInput& e) {
    tk.problem = std::string("global kernel per fold failed: ") + e.what();
    return tk;
  }
  for (std::size_t t = 0; t < layout.tiles.size(); ++t)
    for (int h = 0; h < 2; ++h) {
      try {
        tk.half[t][h] = estimateKernel(den, phiB, {layout.halves[t][h]}, usable, ko).kernel;
      } catch (const InvalidInput&) {
        tk.half[t][h] = tk.global[layout.fold(static_cast<int>(t), h)];  // no edges: no tile-specific kernel
      }
    }
  tk.ok = true;
  return tk;
}

void addTileColumns(std::vector<Samples>& samples, const std::vector<cv::Mat>& phiI, const Layout& layout,
                    const TileKernels& tk) {
  for (std::size_t c = 0; c < samples.size(); ++c) {
    Samples& s = samples[c];
    s.Xt_ext.assign(s.size(), 0.0);
    s.Xt_base.assign(s.size(), 0.0);
    // Held-out global kernels on the whole window, per fold.
    std::array<cv::Mat, 2> g;
    for (int f = 0; f < 2; ++f) g[f] = convolve(phiI[c], tk.global[f]);
    for (std::size_t t = 0; t < layout.tiles.size(); ++t) {
      std::array<cv::Mat, 2> local;
      for (int h = 0; h < 2; ++h) local[h] = convolveIn(phiI[c], tk.half[t][h], layout.tiles[t]);
      for (std::size_t i = 0; i < s.size(); ++i) {
        if (s.tile[i] != static_cast<int>(t)) continue;
        const cv::Point q = s.pos[i];
        const int h = layout.half_map.at<uchar>(q);
        // The kernel of the other half of the same tile / the global kernel of the other fold.
        s.Xt_ext[i] = local[1 - h].at<double>(q.y - layout.tiles[t].y, q.x - layout.tiles[t].x);
        s.Xt_base[i] = g[1 - s.fold[i]].at<double>(q);
      }
    }
  }
}

// Held-out Gaussian NLL of residuals with a variance linear in the level vs a constant variance.
struct NoiseTest {
  std::vector<double> block_nll_base, block_nll_ext;
  double total_base = 0, total_ext = 0;
  long count = 0;
  double alpha = 0, beta = 0;
};

// Variance of the held-out residuals: base Var(e) = α u + γ (σ_I constant in intensity, as the fitter assumes;
// γ: B's own noise/quantisation), extended Var(e) = α u + β t + γ (σ_I² = α + β·I). Least squares on e² per fold,
// held-out Gaussian negative log-likelihood per block.
NoiseTest noiseTest(const std::vector<Samples>& samples, const Evaluation& ev, int blocks) {
  NoiseTest nt;
  nt.block_nll_base.assign(blocks, 0.0);
  nt.block_nll_ext.assign(blocks, 0.0);
  for (std::size_t c = 0; c < samples.size(); ++c) {
    const Samples& s = samples[c];
    std::array<Eigen::Vector2d, 2> base;
    std::array<Eigen::Vector3d, 2> ext;
    std::array<double, 2> mean{};
    for (int f = 0; f < 2; ++f) {
      Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
      Eigen::Vector3d b = Eigen::Vector3d::Zero();
      double n = 0;
      for (std::size_t i = 0; i < s.size(); ++i) {
        if (s.fold[i] != f) continue;
        const double e2 = ev.residual[c][i] * ev.residual[c][i];
        const Eigen::Vector3d v(s.u[i], 1.0, s.t[i]);
        A += v * v.transpose();
        b += v * e2;
        mean[f] += e2;
        n += 1;
      }
      if (n < 10) return nt;
      mean[f] /= n;
      A.diagonal().array() += 1e-12 * (A.diagonal().array().abs().maxCoeff() + 1e-30);
      ext[f] = A.ldlt().solve(b);
      base[f] = A.topLeftCorner<2, 2>().ldlt().solve(b.head<2>());
    }
    for (std::size_t i = 0; i < s.size(); ++i) {
      const int f = 1 - s.fold[i];
      const double e2 = ev.residual[c][i] * ev.residual[c][i];
      const double floor = 1e-3 * mean[f] + 1e-14;
      const double v0 = std::max(base[f](0) * s.u[i] + base[f](1), floor);
      const double v1 = std::max(ext[f](0) * s.u[i] + ext[f](1) + ext[f](2) * s.t[i], floor);
      const double n0 = 0.5 * (std::log(v0) + e2 / v0), n1 = 0.5 * (std::log(v1) + e2 / v1);
      nt.block_nll_base[s.block[i]] += n0;
      nt.block_nll_ext[s.block[i]] += n1;
      nt.total_base += n0;
      nt.total_ext += n1;
      ++nt.count;
    }
    if (c == 0 || samples.size() == 1) {
      nt.alpha = 0.5 * (ext[0](0) + ext[1](0));
      nt.beta = 0.5 * (ext[0](2) + ext[1](2));
    }
  }
  return nt;
}

std::string fmt(const char* format, double a, double b = 0, double c = 0) {
  char buffer[200];
  std::snprintf(buffer, sizeof buffer, format, a, b, c);
  return buffer;
}

// Index of the "scale" coefficient and the others in a fitted spec.
struct Coefficients {
  double scale = 1, v1 = 0, v2 = 0, offset = 0;
  std::vector<double> mix;  // per channel index (own = scale)
};

Coefficients coefficients(const Spec& spec, const ChannelFit& f, int self, int nc) {
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
      if (d != self) c.mix[d] = f.theta(k++);
  return c;
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
    e.gain_threshold = name == "signal_dependent_noise" ? options.min_nll_gain : options.min_gain;
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
  }
  const cv::Size size = p.B[0].size();
  {
    cv::Mat bad = cv::Mat::zeros(size, CV_8U);
    for (int c = 0; c < nc; ++c)
      bad |= (p.B[c] >= in.fit.saturation_high) | (p.B[c] <= in.fit.saturation_low) |
             (p.I[c] >= in.fit.saturation_high) | (p.I[c] <= in.fit.saturation_low);
    p.usable = ~dilateBy(bad, n);
    if (!in.valid.empty()) p.usable &= in.valid;
    const int m = n / 2 + 1;
    cv::Mat inner = cv::Mat::zeros(size, CV_8U);
    if (size.width > 2 * m && size.height > 2 * m) inner(cv::Rect(m, m, size.width - 2 * m, size.height - 2 * m)).setTo(255);
    p.usable &= inner;
  }
  p.centre = in.centre.x >= 0 ? in.centre : cv::Point2d((size.width - 1) / 2.0, (size.height - 1) / 2.0);
  p.radius = in.corner_radius > 0 ? in.corner_radius : 0.5 * std::hypot(size.width, size.height);
  p.rho2 = cv::Mat(size, CV_64F);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const double dx = (x - p.centre.x) / p.radius, dy = (y - p.centre.y) / p.radius;
      p.rho2.at<double>(y, x) = dx * dx + dy * dy;
    }
  const int grid = options.grid > 0 ? options.grid : (std::min(size.width, size.height) < 600 ? 2 : 3);
  const Layout layout = makeLayout(size, grid);
  const int blocks = ((size.width + options.block - 1) / options.block) * ((size.height + options.block - 1) / options.block);
  if (cv::countNonZero(p.usable) < 2000) {
    for (auto& e : report.entries) e.detail = "too few usable pixels";
    return report;
  }

  std::vector<cv::Mat> phiI;
  std::vector<double> ratios;
  for (const auto& name : in.channels) ratios.push_back(in.fits.at(name).ratio);
  Problem problem(collect(p, curves, ratios, K, layout, options.block, options.max_samples, options.phi_terms, &phiI),
                  blocks);
  report.samples = static_cast<int>(problem.samples()[0].size());
  std::vector<char> used_blocks(blocks, 0);
  for (int b : problem.samples()[0].block) used_blocks[b] = 1;

  // Spatially varying blur: held-out per-tile kernels (kernels estimated in the irradiance domain of φ_G).
  const int g_index = [&] {
    for (int c = 0; c < nc; ++c)
      if (in.channels[c] == "G") return c;
    return 0;
  }();
  TileKernels tk;
  bool spatial = options.test_spatial_blur && in.kernel_estimated;
  if (!spatial)
    entry("spatially_varying_blur").detail = in.kernel_estimated ? "disabled" : "kernel given (not estimated)";
  if (spatial) {
    tk = estimateTileKernels(phiI[g_index], curves[g_index].curve.inverse(p.B[g_index]), p.usable, layout, K,
                             in.kernel_options);
    if (!tk.ok) {
      spatial = false;
      entry("spatially_varying_blur").detail = tk.problem;
    } else {
      addTileColumns(problem.samples(), phiI, layout, tk);
    }
  }

  // Greedy forward selection of the level/blur effects.
  Spec current;
  Evaluation current_eval = problem.evaluate(current);
  report.base_error = current_eval.count > 0 ? current_eval.total / current_eval.count : 0;
  std::vector<std::string> candidates{"vignetting", "black_level_offset", "clipping"};
  if (nc == 3) candidates.push_back("channel_mixing");
  else entry("channel_mixing").detail = "needs three channels (--channels rgb)";
  if (spatial) candidates.push_back("spatially_varying_blur");
  std::vector<std::string> selected;
  auto extend = [](Spec s, const std::string& name) {
    if (name == "vignetting") s.vignetting = true;
    if (name == "black_level_offset") s.offset = true;
    if (name == "clipping") s.clipping = true;
    if (name == "channel_mixing") s.mixing = true;
    if (name == "spatially_varying_blur") s.source = Source::tile;
    return s;
  };
  while (true) {
    std::string best;
    double best_gain = 0;
    Evaluation best_eval;
    for (const auto& name : candidates) {
      if (std::find(selected.begin(), selected.end(), name) != selected.end()) continue;
      Spec base = current;
      if (name == "spatially_varying_blur") base.source = Source::heldout_global;
      const Evaluation be = name == "spatially_varying_blur" ? problem.evaluate(base) : current_eval;
      const Evaluation ee = problem.evaluate(extend(current, name));
      const Comparison cmp = compare(be.block_error, ee.block_error, be.total, &used_blocks);
      EffectEntry& e = entry(name);
      e.tested = true;
      e.gain = cmp.gain;
      e.statistic = cmp.z;
      if (cmp.gain >= options.min_gain && cmp.z >= options.min_z && cmp.gain > best_gain) {
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
  }

  // Parameters of the selected model (fitted on all samples).
  std::vector<Coefficients> coef;
  for (int c = 0; c < nc; ++c)
    coef.push_back(current_eval.full[c].ok ? coefficients(current, current_eval.full[c], c, nc) : Coefficients{});
  const int gi = g_index;
  {
    const Evaluation ev = problem.evaluate(extend(Spec{}, "vignetting"));
    const Coefficients v = ev.full[gi].ok ? coefficients(extend(Spec{}, "vignetting"), ev.full[gi], gi, nc) : Coefficients{};
    const Coefficients& cv = current.vignetting ? coef[gi] : v;
    auto& e = entry("vignetting");
    e.parameters = {{"v1", cv.v1}, {"v2", cv.v2}, {"corner_gain", 1 + cv.v1 + cv.v2}};
    e.detail = fmt("gain at the corner %.3f (1 + v1 rho^2 + v2 rho^4, v1 %.3f, v2 %.3f)", 1 + cv.v1 + cv.v2, cv.v1, cv.v2);
  }
  {
    const Spec s = current.offset ? current : extend(current, "black_level_offset");
    const Evaluation ev = current.offset ? current_eval : problem.evaluate(s);
    const Coefficients c = ev.full[gi].ok ? coefficients(s, ev.full[gi], gi, nc) : Coefficients{};
    auto& e = entry("black_level_offset");
    e.parameters = {{"offset", c.offset}, {"scale", c.scale}};
    e.detail = fmt("additive irradiance offset %.4f (%s)", c.offset, 0) +
               (c.offset >= 0 ? "in the blurred shot" : "in the sharp shot") + ")";
    e.detail = fmt("additive irradiance offset %.4f of full scale ", c.offset) +
               (c.offset >= 0 ? "(blurred shot brighter: flare/offset in B)" : "(offset in the sharp shot)");
  }
  {
    const Spec s = current.clipping ? current : extend(current, "clipping");
    const Evaluation ev = current.clipping ? current_eval : problem.evaluate(s);
    const double clip = ev.full[gi].ok ? ev.full[gi].clip : 0;
    auto& e = entry("clipping");
    const double level = clip > 0 ? curves[gi].curve.forward(clip) : 1.0;
    e.parameters = {{"clip_irradiance", clip}, {"clip_intensity", level}};
    e.detail = fmt("clip level: irradiance %.3f = intensity %.3f", clip, level);
  }
  if (nc == 3) {
    auto& e = entry("channel_mixing");
    const Spec s = current.mixing ? current : extend(current, "channel_mixing");
    const Evaluation ev = current.mixing ? current_eval : problem.evaluate(s);
    double largest = 0;
    for (int c = 0; c < nc; ++c) {
      if (!ev.full[c].ok) continue;
      const Coefficients cc = coefficients(s, ev.full[c], c, nc);
      for (int d = 0; d < nc; ++d) {
        const double m = cc.mix[d] / cc.scale;
        e.parameters["m_" + in.channels[c] + in.channels[d]] = m;
        if (d != c) largest = std::max(largest, std::abs(m));
      }
    }
    e.detail = fmt("largest off-diagonal mix %.3f (relative to the own channel)", largest);
  }
  if (spatial) {
    auto& e = entry("spatially_varying_blur");
    double mean = 0, worst = 0;
    int count = 0;
    for (std::size_t t = 0; t < tk.half.size(); ++t)
      for (int h = 0; h < 2; ++h) {
        const double d = kernelRelativeError(tk.half[t][h], tk.global[layout.fold(static_cast<int>(t), h)]);
        mean += d;
        worst = std::max(worst, d);
        ++count;
      }
    mean /= std::max(1, count);
    e.parameters = {{"tiles", static_cast<double>(layout.tiles.size())}, {"mean_kernel_difference", mean},
                    {"max_kernel_difference", worst}};
    e.detail = fmt("%.0f tiles; half-tile kernels differ from the fold's global kernel by %.3f on average (max %.3f)",
                   static_cast<double>(layout.tiles.size()), mean, worst);
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
      const Evaluation fe = problem.evaluate(fixed);
      const Comparison cmp = compare(fe.block_error, current_eval.block_error, fe.total, &used_blocks);
      const double a = coef[gi].scale;
      const double rel = a / in.exif_ratio - 1;
      e.tested = true;
      e.gain = cmp.gain;
      e.statistic = cmp.z;
      e.detected = cmp.gain >= options.min_gain && cmp.z >= options.min_z && std::abs(rel) > options.ratio_tolerance;
      e.parameters = {{"fitted_ratio", a}, {"exif_ratio", in.exif_ratio}, {"relative_difference", rel},
                      {"tolerance", options.ratio_tolerance}};
      e.detail = fmt("fitted r %.4f vs EXIF %.4f (%+.1f%%; tolerance of nominal EXIF values ", a, in.exif_ratio, 100 * rel) +
                 fmt("%.0f%%); phi from the free-r fit", 100 * options.ratio_tolerance);
    }
  }

  // Signal-dependent noise on the selected model's held-out residuals.
  {
    auto& e = entry("signal_dependent_noise");
    const NoiseTest nt = noiseTest(problem.samples(), current_eval, blocks);
    if (nt.count > 0) {
      const Comparison cmp = compare(nt.block_nll_base, nt.block_nll_ext, 1.0, &used_blocks);
      e.tested = true;
      e.gain = (nt.total_base - nt.total_ext) / nt.count;
      e.statistic = cmp.z;
      e.detected = e.gain >= options.min_nll_gain && cmp.z >= options.min_z;
      const double mean_level = 0.5;
      e.parameters = {{"alpha", nt.alpha}, {"beta", nt.beta}};
      e.detail = fmt("noise variance of I: %.3g + %.3g x I (intensity units)", nt.alpha, nt.beta, mean_level) +
                 (e.detected ? "; phi from the base model (the fitter has no per-pixel weights)" : "");
    }
  }

  // φ from the extended model.
  const bool refit_needed = current.vignetting || current.offset || current.mixing || current.clipping ||
                            current.source == Source::tile;
  if (options.refit && refit_needed) {
    std::vector<Curve> cur = curves;
    std::vector<Coefficients> cf = coef;
    std::vector<ChannelFit> fits_full = current_eval.full;
    const int rounds = 2;
    for (int round = 0; round < rounds; ++round) {
      std::vector<cv::Mat> Ic(nc), Bc(nc);
      std::vector<cv::Mat> Y(nc);
      for (int c = 0; c < nc; ++c) {
        Ic[c] = p.I[c].clone();
        Y[c] = cur[c].curve.inverse(p.B[c]);
        if (current.vignetting) {
          cv::Mat g = 1.0 + cf[c].v1 * p.rho2 + cf[c].v2 * p.rho2.mul(p.rho2);
          g = cv::max(g, 0.05);
          cv::divide(Y[c], g, Y[c]);
        }
        if (current.offset) {
          if (cf[c].offset >= 0) {
            Y[c] = Y[c] - cf[c].offset;
          } else {
            cv::Mat e = cur[c].curve.inverse(p.I[c]) + cf[c].offset / cf[c].scale;
            cv::Mat nodata = p.I[c] <= 0;
            Ic[c] = cur[c].curve.forward(cv::max(e, 0.0));
            Ic[c].setTo(0, nodata);
          }
        }
      }
      if (current.mixing) {
        Eigen::Matrix3d M, D = Eigen::Matrix3d::Zero();
        for (int c = 0; c < 3; ++c) {
          D(c, c) = cf[c].scale;
          for (int d = 0; d < 3; ++d) M(c, d) = cf[c].mix[d] / cf[c].scale;
        }
        const Eigen::Matrix3d T = D * M.inverse() * D.inverse();
        std::vector<cv::Mat> mixed(3);
        for (int c = 0; c < 3; ++c) mixed[c] = T(c, 0) * Y[0] + T(c, 1) * Y[1] + T(c, 2) * Y[2];
        Y = mixed;
      }
      for (int c = 0; c < nc; ++c) {
        Bc[c] = store(cur[c].curve.forward(cv::max(cv::min(Y[c], 1.0), 0.0)), p.depth[c]);
        Ic[c] = store(Ic[c], p.depth[c]);
      }
      std::map<std::string, CrfFitResult> fits;
      for (int c = 0; c < nc; ++c) {
        CrfFitOptions fo = in.fit;
        fo.progress = nullptr;
        if (current.clipping && fits_full[c].ok && fits_full[c].clip > 0) {
          const double level = cur[c].curve.forward(fits_full[c].clip) - 1.5 / 255.0;
          fo.saturation_high = std::max(fo.saturation_low + 0.1, std::min(fo.saturation_high, level));
        }
        try {
          if (current.source == Source::tile) {
            std::vector<CrfFitResult> tile_fits;
            KernelEstimationOptions ko = in.kernel_options;
            ko.progress = nullptr;
            ko.throw_on_size_limit = false;
            ko.kernel_size = croppedSize(K, in.kernel_options.kernel_size);
            const cv::Mat den = denoiseForKernel(cur[g_index].curve.inverse(p.I[g_index]));
            const cv::Mat bg = cur[g_index].curve.inverse(p.B[g_index]);
            for (const auto& t : layout.tiles) {
              try {
                const cv::Mat kt = estimateKernel(den, bg, {t}, p.usable, ko).kernel;
                const int m = std::max(kt.rows, kt.cols) / 2 + 1;
                const cv::Rect big = cv::Rect(t.x - m, t.y - m, t.width + 2 * m, t.height + 2 * m) &
                                     cv::Rect(0, 0, size.width, size.height);
                CrfFitOptions to = fo;
                to.min_pixels = std::min(fo.min_pixels, 100);
                tile_fits.push_back(fitInverseCrf(Ic[c](big), Bc[c](big), kt, to));
              } catch (const InvalidInput&) {
                // a tile without edges: skipped
              }
            }
            if (tile_fits.empty()) throw InvalidInput("no tile could be fitted");
            fits[in.channels[c]] = averageFits(tile_fits);
          } else {
            fits[in.channels[c]] = fitInverseCrf(Ic[c], Bc[c], K, fo);
          }
        } catch (const InvalidInput& e) {
          fits.clear();
          break;
        }
      }
      if (fits.empty()) break;
      report.fits = fits;
      if (round + 1 == rounds) break;
      // Re-estimate the parameters with the refitted φ.
      for (int c = 0; c < nc; ++c) cur[c] = makeCurve(report.fits.at(in.channels[c]).inverse_crf);
      std::vector<double> rr;
      for (const auto& name : in.channels) rr.push_back(report.fits.at(name).ratio);
      Problem again(collect(p, cur, rr, K, layout, options.block, options.max_samples, options.phi_terms, nullptr),
                    blocks);
      Spec s = current;
      if (s.source == Source::tile) s.source = Source::global;  // per-tile columns are not rebuilt
      const Evaluation ev = again.evaluate(s);
      for (int c = 0; c < nc; ++c)
        if (ev.full[c].ok) {
          cf[c] = coefficients(s, ev.full[c], c, nc);
          fits_full[c] = ev.full[c];
        }
    }
  }
  report.seconds = std::chrono::duration<double>(Clock::now() - start).count();
  return report;
}

}  // namespace crfcal
