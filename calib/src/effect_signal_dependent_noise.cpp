// signal_dependent_noise, tested on I itself (its noise is what the seed models; in the residuals of B it is
// averaged by the kernel and hidden under B's quantisation): Immerkær's residual (noise_estimation.hpp) in each of
// `noise_bins` level bins (equal counts of I's 5×5 local mean), on the 30 % of each bin with the least 7×7 residual
// energy, same folds. Base: one variance for all levels (the seed's homoscedastic Gaussian); extended: one per
// level bin. Robust (MAD) scales on one fold, held-out Huber negative log-likelihood on the other; detected when
// the paired block t (as z) ≥ min_z AND the variance contrast of the log-linear trend across the levels the bins
// cover (at most 0.8 of a level) ≥ min_noise_contrast (below a contrast κ homoscedastic weights keep ≥ 4κ/(1+κ)² of
// the efficiency, Kantorovich: the efficiency of a fit over those levels).
#include <algorithm>
#include <cmath>

#include "crfcal/noise_estimation.hpp"
#include "effect_problem.hpp"

namespace crfcal::effect {

namespace {

struct NoiseTest {
  bool ok = false;
  std::string problem;
  std::vector<double> block_nll_base, block_nll_ext;
  double total_base = 0, total_ext = 0;
  long count = 0;
  double contrast = 1;  // variance ratio of the log-linear trend across the bins' levels, ≤ 0.8 apart (worst channel)
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

// A pixel of I: its local mean level, local residual energy and residual.
struct Item {
  double level, local, e;
  int x, y;
};

// The unclipped pixels of one channel, sorted by level.
std::vector<Item> noiseItems(const cv::Mat& image, const cv::Mat& valid) {
  const cv::Mat op = (cv::Mat_<double>(3, 3) << 1, -2, 1, -2, 4, -2, 1, -2, 1) / 6.0;
  const double sigma0 = estimateNoiseSigma(image).sigma;
  cv::Mat residual, mean, local;
  cv::filter2D(image, residual, CV_64F, op, cv::Point(-1, -1), 0, cv::BORDER_REFLECT);
  cv::blur(image, mean, cv::Size(5, 5), cv::Point(-1, -1), cv::BORDER_REFLECT);
  cv::blur(residual.mul(residual), local, cv::Size(7, 7), cv::Point(-1, -1), cv::BORDER_REFLECT);
  // Clipped values (0 or 1) truncate the noise: exclude their neighbourhoods and levels within 3σ of the ends.
  const cv::Mat clipped = dilateBy((image <= 0.5 / 255.0) | (image >= 254.5 / 255.0), 7);
  const double margin = std::max(3 * sigma0, 2.0 / 255.0);
  std::vector<Item> items;
  for (int y = 3; y < image.rows - 3; ++y)
    for (int x = 3; x < image.cols - 3; ++x) {
      if (clipped.at<uchar>(y, x) || (!valid.empty() && !valid.at<uchar>(y, x))) continue;
      const double m = mean.at<double>(y, x);
      if (m < margin || m > 1 - margin) continue;
      items.push_back({m, local.at<double>(y, x), residual.at<double>(y, x), x, y});
    }
  std::sort(items.begin(), items.end(), [](const Item& a, const Item& b) { return a.level < b.level; });
  return items;
}

// Equal-count level bins. In each, the pixels whose 7×7 residual energy is in the lowest 30 %: texture only adds
// energy, so these are noise (the same fraction in every bin keeps the σ ratios between bins).
struct Bins {
  std::vector<std::vector<Item>> binned;
  std::vector<double> level, sig, count;
  std::array<std::vector<std::vector<double>>, 2> fold_e;  // per fold, per bin
  std::vector<const Item*> kept;
  std::vector<int> kept_bin;
};

void fillBins(const std::vector<Item>& items, const Layout& layout, int bins, Bins& bn) {
  bn.binned.assign(bins, {});
  for (std::size_t i = 0; i < items.size(); ++i) bn.binned[i * bins / items.size()].push_back(items[i]);
  bn.level.assign(bins, 0.0);
  bn.sig.assign(bins, 0.0);
  bn.count.assign(bins, 0.0);
  for (auto& f : bn.fold_e) f.assign(bins, {});
  for (int b = 0; b < bins; ++b) {
    auto& v = bn.binned[b];
    std::sort(v.begin(), v.end(), [](const Item& a, const Item& c) { return a.local < c.local; });
    v.resize(std::max<std::size_t>(1, v.size() * 3 / 10));
    double msum = 0;
    std::vector<double> all;
    for (const auto& it : v) {
      msum += it.level;
      all.push_back(it.e);
      bn.fold_e[layout.foldAt(it.x, it.y)][b].push_back(it.e);
      bn.kept.push_back(&it);
      bn.kept_bin.push_back(b);
    }
    bn.level[b] = msum / static_cast<double>(v.size());
    bn.sig[b] = robustSigma(all);
    bn.count[b] = static_cast<double>(v.size());
  }
}

// Size of the level dependence: the log-variance trend over the bins, as the variance ratio across the levels the
// bins cover, over at most 0.8 of a level (the 0.1–0.9 of min_noise_contrast's choice). What the size decides is how
// much homoscedastic weights cost the fit, and the fit has only these levels. (Extrapolated to 0.1–0.9 whatever the
// bins cover, a dark sharp shot whose bins span 0.01–0.06 turns σ 0.2 → 0.5 of a level into a contrast of 5·10¹³:
// vivo X6S pair 2, docs/RESULTS.md#noise-contrast.)
double levelContrast(const Bins& bn, int bins) {
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  double lowest = 1, highest = 0;
  for (int b = 0; b < bins; ++b) {
    if (!(bn.sig[b] > 0)) continue;
    const double w = bn.count[b], x = bn.level[b], y = std::log(bn.sig[b] * bn.sig[b]);
    sw += w, sx += w * x, sy += w * y, sxx += w * x * x, sxy += w * x * y;
    lowest = std::min(lowest, x);
    highest = std::max(highest, x);
  }
  const double det = sw * sxx - sx * sx;
  const double slope = det > 1e-12 ? (sw * sxy - sx * sy) / det : 0.0;
  return std::exp(std::abs(slope) * std::clamp(highest - lowest, 0.0, 0.8));
}

// One channel: per fold one robust σ (base) and one per bin (extended); the held-out NLL per block into nt.
// False (nt.problem set) when the channel cannot be tested.
bool testChannel(const cv::Mat& image, const cv::Mat& valid, const Layout& layout, int block, int bins,
                 NoiseTest& nt) {
  const std::vector<Item> items = noiseItems(image, valid);
  if (static_cast<int>(items.size()) < 200 * bins) {
    nt.problem = "too few unclipped pixels in I";
    return false;
  }
  Bins bn;
  fillBins(items, layout, bins, bn);
  std::array<double, 2> base{};
  std::array<std::vector<double>, 2> ext;
  for (int f = 0; f < 2; ++f) {
    std::vector<double> all;
    ext[f].assign(bins, 0.0);
    for (int b = 0; b < bins; ++b) {
      all.insert(all.end(), bn.fold_e[f][b].begin(), bn.fold_e[f][b].end());
      ext[f][b] = robustSigma(bn.fold_e[f][b]);
    }
    base[f] = robustSigma(all);
    if (!(base[f] > 0)) {
      nt.problem = "no noise measurable in I";
      return false;
    }
    for (int b = 0; b < bins; ++b)
      if (!(ext[f][b] > 0)) ext[f][b] = base[f];
  }
  const int bx = (image.cols + block - 1) / block;
  for (std::size_t i = 0; i < bn.kept.size(); ++i) {
    const Item& it = *bn.kept[i];
    const int held = 1 - layout.foldAt(it.x, it.y);  // parameters from the other fold
    const double n0 = huberNll(it.e, base[held]), n1 = huberNll(it.e, ext[held][bn.kept_bin[i]]);
    const int blk = (it.y / block) * bx + it.x / block;
    nt.block_nll_base[blk] += n0;
    nt.block_nll_ext[blk] += n1;
    nt.total_base += n0;
    nt.total_ext += n1;
    ++nt.count;
  }
  nt.contrast = std::max(nt.contrast, levelContrast(bn, bins));
  nt.level.push_back(bn.level);
  nt.sigma.push_back(bn.sig);
  return true;
}

NoiseTest noiseTest(const std::vector<cv::Mat>& I, const cv::Mat& valid, const Layout& layout, int block, int bins,
                    int blocks) {
  NoiseTest nt;
  nt.block_nll_base.assign(blocks, 0.0);
  nt.block_nll_ext.assign(blocks, 0.0);
  for (const auto& image : I)
    if (!testChannel(image, valid, layout, block, bins, nt)) return nt;
  nt.ok = nt.count > 0;
  return nt;
}

void run(EffectSearch& search) {
  const EffectInputs& in = search.in;
  const EffectOptions& options = search.options;
  auto& e = search.entry("signal_dependent_noise");
  cv::Mat valid = in.valid.empty() ? cv::Mat(search.size, CV_8U, cv::Scalar(255)) : in.valid.clone();
  for (int c = 0; c < search.nc; ++c) valid &= (search.p.I[c] > 0);  // sharp 0: no data (outside the overlap)
  const NoiseTest nt = noiseTest(search.p.I, valid, search.layout, options.block, options.noise_bins, search.blocks);
  if (!nt.ok) {
    e.detail = nt.problem;
    return;
  }
  std::vector<char> noise_blocks(search.blocks, 0);
  for (int b = 0; b < search.blocks; ++b) noise_blocks[b] = nt.block_nll_base[b] != 0 || nt.block_nll_ext[b] != 0;
  const Comparison cmp = compare(nt.block_nll_base, nt.block_nll_ext, 1.0, noise_blocks);
  e.tested = true;
  e.gain = (nt.total_base - nt.total_ext) / nt.count;
  e.statistic = cmp.z;
  search.noise_detected = e.gain > 0 && cmp.z >= options.min_z && nt.contrast >= options.min_noise_contrast;
  e.detected = search.noise_detected;
  e.parameters = {{"contrast", nt.contrast}, {"contrast_threshold", options.min_noise_contrast},
                  {"samples", static_cast<double>(nt.count)}};
  const auto& lv = nt.level[search.g_index];
  const auto& sg = nt.sigma[search.g_index];
  for (std::size_t b = 0; b < lv.size(); ++b) {
    e.parameters["level_" + std::to_string(b)] = lv[b];
    e.parameters["sigma_" + std::to_string(b)] = sg[b];
  }
  search.noise_level = nt.level;
  search.noise_sigma = nt.sigma;
  e.detail = fmt("noise std of I from %.1f/255 (level %.2f) ", 255 * sg.front(), lv.front()) +
             fmt("to %.1f/255 (level %.2f); variance contrast %.2f", 255 * sg.back(), lv.back(), nt.contrast);
  // Without σ in the fitter (noise handling none: the pixels are selected by B alone) the noise law only changes
  // the weights; what remains is the second-order Jensen bias of φ(I), as for homoscedastic noise of the same power.
  if (search.noise_detected)
    e.detail += in.fit.experimental.noise == NoiseHandling::none
                    ? "; phi from the base fit (noise handling none: pixels are selected by B alone, so sigma(v) "
                      "would only change the weights)"
                    : "; sigma(v) handed to the refit (noise_sigma_per_level)";
}

}  // namespace

const ModelCheck& signalDependentNoiseCheck() {
  static const ModelCheck check{"signal_dependent_noise", run};
  return check;
}

}  // namespace crfcal::effect
