#include "crfcal/deconvolution.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"

namespace crfcal {
namespace {

// ---- spectra -------------------------------------------------------------------------------------------------
// Real DFTs in OpenCV's packed CCS layout (half the spectrum; cv::mulSpectrums / cv::divSpectrums understand it).
// Spectra of real, even operators (|K̂|², |D̂|², the u-step's denominator) have zero imaginary parts there, so a
// product or quotient with them acts on real and imaginary parts alike.

cv::Mat spectrum(const cv::Mat& real) {
  cv::Mat packed;
  cv::dft(real, packed);
  return packed;
}

cv::Mat realInverse(const cv::Mat& packed) {
  cv::Mat real;
  cv::dft(packed, real, cv::DFT_INVERSE | cv::DFT_SCALE | cv::DFT_REAL_OUTPUT);
  return real;
}

// a · b (conjugate_b: a · conj(b)), element-wise on packed spectra.
cv::Mat multiply(const cv::Mat& a, const cv::Mat& b, bool conjugate_b = false) {
  cv::Mat product;
  cv::mulSpectrums(a, b, product, 0, conjugate_b);
  return product;
}

// The spectrum of the circular operator u ↦ Σ_d P(d) u(p − d) that equals crfcal::convolve in the interior:
// convolve(u)(p) = Σ_q K(q) u(p − q + c) with c = (cols/2, rows/2), i.e. P(d) = K(c + d), d taken modulo the size.
cv::Mat kernelSpectrum(const cv::Mat& kernel, cv::Size size, int depth) {
  cv::Mat psf = cv::Mat::zeros(size, CV_64F);
  const int cx = kernel.cols / 2, cy = kernel.rows / 2;
  for (int y = 0; y < kernel.rows; ++y)
    for (int x = 0; x < kernel.cols; ++x) {
      const int py = ((y - cy) % size.height + size.height) % size.height;
      const int px = ((x - cx) % size.width + size.width) % size.width;
      psf.at<double>(py, px) += kernel.at<double>(y, x);
    }
  psf.convertTo(psf, depth);
  return spectrum(psf);
}

// Forward differences with wrap-around (the circular gradient whose adjoint FTVd's FFT solve assumes):
// (Dx u)(p) = u(p + eₓ) − u(p); as an operator P(0) = −1, P(−eₓ) = 1.
cv::Mat differenceSpectrum(cv::Size size, bool along_x, int depth) {
  cv::Mat psf = cv::Mat::zeros(size, CV_64F);
  psf.at<double>(0, 0) = -1;
  if (along_x) psf.at<double>(0, size.width - 1) = 1;
  else psf.at<double>(size.height - 1, 0) = 1;
  psf.convertTo(psf, depth);
  return spectrum(psf);
}

// The packed spectrum of the identity operator: ones at every frequency (real), zero imaginary parts.
cv::Mat identitySpectrum(cv::Size size, int depth) {
  cv::Mat delta = cv::Mat::zeros(size, depth);
  cv::Mat(1, 1, CV_64F, cv::Scalar(1)).convertTo(delta(cv::Rect(0, 0, 1, 1)), depth);
  return spectrum(delta);
}

// ---- padding -------------------------------------------------------------------------------------------------

struct Padding {
  int top = 0, left = 0, bottom = 0, right = 0;
  cv::Size padded;
  cv::Rect interior() const { return {left, top, padded.width - left - right, padded.height - top - bottom}; }
};

// At least the kernel's extent on every side (so that wrap-around only couples padded pixels), rounded up to a
// fast FFT size; the extra goes to the bottom/right.
Padding choosePadding(cv::Size image, const cv::Mat& kernel) {
  const int margin = std::max(kernel.rows, kernel.cols);
  Padding padding;
  padding.top = padding.left = margin;
  padding.padded = {cv::getOptimalDFTSize(image.width + 2 * margin), cv::getOptimalDFTSize(image.height + 2 * margin)};
  padding.right = padding.padded.width - image.width - margin;
  padding.bottom = padding.padded.height - image.height - margin;
  return padding;
}

cv::Mat reflectPad(const cv::Mat& image, const Padding& padding) {
  cv::Mat padded;
  // BORDER_REFLECT_101 cannot pad beyond the image's own size; tile reflections for small images.
  cv::Mat current = image;
  int top = padding.top, bottom = padding.bottom, left = padding.left, right = padding.right;
  while (top > 0 || bottom > 0 || left > 0 || right > 0) {
    const int t = std::min(top, current.rows - 1), b = std::min(bottom, current.rows - 1);
    const int l = std::min(left, current.cols - 1), r = std::min(right, current.cols - 1);
    cv::copyMakeBorder(current, padded, t, b, l, r, cv::BORDER_REFLECT_101);
    current = padded;
    top -= t, bottom -= b, left -= l, right -= r;
    if (current.rows == 1 || current.cols == 1) {  // a single row/column cannot reflect: replicate the rest
      cv::copyMakeBorder(current, padded, std::max(top, 0), std::max(bottom, 0), std::max(left, 0),
                         std::max(right, 0), cv::BORDER_REPLICATE);
      return padded;
    }
  }
  return current.clone();
}

// ---- solvers -------------------------------------------------------------------------------------------------

cv::Mat wienerSolve(const cv::Mat& f, const cv::Mat& kernel_spectrum, double nsr) {
  const cv::Mat denominator = multiply(kernel_spectrum, kernel_spectrum, true) + nsr * identitySpectrum(f.size(), f.depth());
  cv::Mat quotient;
  cv::divSpectrums(multiply(spectrum(f), kernel_spectrum, true), denominator, quotient, 0);
  return realInverse(quotient);
}

// ---- TV solver -----------------------------------------------------------------------------------------------
// Everything between the FFTs is fused into a few passes over buffers allocated once per tile (as cv::Mat
// expressions each operation allocated and faulted in a full-size temporary: 6–11 % more CPU at 12 MP). The FFTs
// themselves are most of the time (docs/RESULTS.md, "Speed at 12 MP").

// The w-step and the ADMM multiplier update in one pass (Goldstein & Osher 2009): g = ∇u + b, w = shrink(g, 1/β)
// (isotropic), b ← g − w; writes the u-step's field w − b (bregman; b starts at 0) or w into (px, py). ∇ is
// forwardDifference: (Dx u)(p) = u(p + eₓ) − u(p) with wrap-around.
template <typename T>
void shrinkGradient(const cv::Mat& u, double beta, bool bregman, cv::Mat& bx, cv::Mat& by, cv::Mat& px, cv::Mat& py) {
  const int rows = u.rows, cols = u.cols;
  const T threshold = static_cast<T>(1.0 / beta), tiny = static_cast<T>(1e-12);
  for (int y = 0; y < rows; ++y) {
    const T* here = u.ptr<T>(y);
    const T* below = u.ptr<T>(y + 1 < rows ? y + 1 : 0);
    T *bxr = bx.ptr<T>(y), *byr = by.ptr<T>(y), *pxr = px.ptr<T>(y), *pyr = py.ptr<T>(y);
    const auto step = [&](int x, T right) {
      const T gx = right - here[x] + bxr[x];
      const T gy = below[x] - here[x] + byr[x];
      const T magnitude = std::sqrt(gx * gx + gy * gy);
      const T scale = std::max(magnitude - threshold, T(0)) / std::max(magnitude, tiny);
      const T wx = gx * scale, wy = gy * scale;
      if (bregman) {
        bxr[x] = gx - wx;
        byr[x] = gy - wy;
        pxr[x] = wx - bxr[x];
        pyr[x] = wy - byr[x];
      } else {
        pxr[x] = wx;
        pyr[x] = wy;
      }
    };
    for (int x = 0; x + 1 < cols; ++x) step(x, here[x + 1]);
    step(cols - 1, here[0]);
  }
}

// Dᵀp = Dxᵀ px + Dyᵀ py, (Dxᵀ g)(p) = g(p − eₓ) − g(p): the adjoint of forwardDifference, formed in the image
// domain (two FFTs fewer per u-step than through spectra).
template <typename T>
void gradientAdjoint(const cv::Mat& px, const cv::Mat& py, cv::Mat& out) {
  const int rows = px.rows, cols = px.cols;
  for (int y = 0; y < rows; ++y) {
    const T *pxr = px.ptr<T>(y), *pyr = py.ptr<T>(y), *above = py.ptr<T>(y > 0 ? y - 1 : rows - 1);
    T* o = out.ptr<T>(y);
    o[0] = (pxr[cols - 1] - pxr[0]) + (above[0] - pyr[0]);
    for (int x = 1; x < cols; ++x) o[x] = (pxr[x - 1] - pxr[x]) + (above[x] - pyr[x]);
  }
}

// ‖next − u‖ / ‖next‖ in one pass.
template <typename T>
double relativeChange(const cv::Mat& next, const cv::Mat& u) {
  double difference = 0, norm = 0;
  for (int y = 0; y < u.rows; ++y) {
    const T *n = next.ptr<T>(y), *p = u.ptr<T>(y);
    for (int x = 0; x < u.cols; ++x) {
      const double d = double(n[x]) - double(p[x]);
      difference += d * d;
      norm += double(n[x]) * double(n[x]);
    }
  }
  return std::sqrt(difference) / std::max(std::sqrt(norm), 1e-12);
}

// A real, even operator's packed spectrum (zero imaginary parts) with its value copied into both slots of every
// (re, im) pair: multiplying a packed spectrum by it element-wise (cv::multiply) is then the spectral product.
cv::Mat bothSlots(const cv::Mat& real_spectrum) {
  return multiply(cv::Mat::ones(real_spectrum.size(), real_spectrum.type()), real_spectrum);
}

// FTVd (Wang et al. 2008, Alg. 1 with continuation) with the masked data term minimised by MM (see header).
// Per u-step four real FFTs: K ⊗ u and F(ḟ) for the MM fill ḟ = M f + (1 − M) K ⊗ u, F(Dᵀw) (Dᵀw formed in the
// image domain), and u. (Refreshing ḟ only once per β saves two but measurably slows the fill of the padding and
// of saturated regions: −1 dB on the tests' images.) The u-step
//   (DᵀD + λ/β KᵀK) u = Dᵀw + λ/β Kᵀḟ
// is diagonal in Fourier: Û = F(Dᵀw) · R + F(ḟ) · G with R = 1 / (|D̂x|² + |D̂y|² + λ/β |K̂|²) and
// G = λ/β · conj(K̂) · R, both fixed per β.
template <typename T>
cv::Mat totalVariationSolve(const cv::Mat& f, const cv::Mat& mask, const cv::Mat& kernel_spectrum,
                            const DeconvolutionOptions& options, int* iterations) {
  const cv::Size size = f.size();
  const int depth = f.depth();
  const cv::Mat dx = differenceSpectrum(size, true, depth), dy = differenceSpectrum(size, false, depth);
  const cv::Mat gradient_energy = multiply(dx, dx, true) + multiply(dy, dy, true);
  const cv::Mat kernel_energy = multiply(kernel_spectrum, kernel_spectrum, true);
  const cv::Mat identity = identitySpectrum(size, depth);
  const bool masked = cv::countNonZero(mask) < mask.rows * mask.cols;

  // buffers, allocated once
  cv::Mat u = f.clone(), next(size, depth), fill(size, depth), adjoint(size, depth);
  cv::Mat bx = cv::Mat::zeros(size, depth), by = cv::Mat::zeros(size, depth);  // scaled ADMM multipliers of w = ∇u
  cv::Mat px(size, depth), py(size, depth);
  cv::Mat u_spectrum, fill_spectrum, adjoint_spectrum, product(size, depth), reciprocal, data_gain, fixed_data;
  cv::dft(u, u_spectrum);
  cv::dft(f, fill_spectrum);
  int steps = 0;
  for (double beta = options.beta_start; beta <= options.beta_max * (1 + 1e-12); beta *= options.beta_factor) {
    const double ratio = options.lambda / beta;
    cv::divide(1.0, bothSlots(gradient_energy + ratio * kernel_energy), reciprocal);
    cv::mulSpectrums(reciprocal.mul(identity), kernel_spectrum, data_gain, 0, true);
    data_gain *= ratio;
    if (!masked) cv::mulSpectrums(fill_spectrum, data_gain, fixed_data, 0);  // Kᵀf: the same at every step
    if (beta > options.beta_start) {  // the scaled multiplier b = y / β follows β
      bx /= options.beta_factor;
      by /= options.beta_factor;
    }
    for (int inner = 0; inner < options.inner_iterations; ++inner) {
      if (masked) {  // MM: masked-out data replaced by the current prediction K ⊗ u
        cv::mulSpectrums(u_spectrum, kernel_spectrum, product, 0);
        cv::dft(product, fill, cv::DFT_INVERSE | cv::DFT_SCALE | cv::DFT_REAL_OUTPUT);
        f.copyTo(fill, mask);
        cv::dft(fill, fill_spectrum);
      }
      shrinkGradient<T>(u, beta, options.bregman, bx, by, px, py);
      gradientAdjoint<T>(px, py, adjoint);
      cv::dft(adjoint, adjoint_spectrum);
      cv::multiply(adjoint_spectrum, reciprocal, u_spectrum);
      if (masked) {
        cv::mulSpectrums(fill_spectrum, data_gain, product, 0);
        u_spectrum += product;
      } else {
        u_spectrum += fixed_data;
      }
      cv::dft(u_spectrum, next, cv::DFT_INVERSE | cv::DFT_SCALE | cv::DFT_REAL_OUTPUT);
      const double change = relativeChange<T>(next, u);
      std::swap(u, next);
      ++steps;
      if (change < options.tolerance) break;
    }
  }
  if (iterations) *iterations = steps;
  return u;
}

// ---- tiles ---------------------------------------------------------------------------------------------------
// A large image is deconvolved tile by tile: each tile fits the image pixels of `data` (its core grown by the
// overlap, clipped to the image) on its own small FFT canvas with the free boundary around it, and keeps only its
// core. Small FFTs run several times faster per pixel than one image-sized FFT (they stay in cache) and bound the
// memory; the overlap keeps the tiles' free-boundary errors out of the kept cores.

struct Tile {
  cv::Rect core;  // pixels this tile writes
  cv::Rect data;  // pixels it fits (⊇ core)
};

std::vector<Tile> planTiles(cv::Size image, const cv::Mat& kernel, const DeconvolutionOptions& options) {
  const int margin = std::max(kernel.rows, kernel.cols);
  const int overlap = options.tile_overlap > 0 ? options.tile_overlap : 2 * margin;
  // the core a tile of `tile_size` leaves after the free-boundary padding and the overlap on both sides
  const int core = options.tile_size - 2 * (margin + overlap);
  const cv::Size whole(image.width + 2 * margin, image.height + 2 * margin);
  if (options.tile_size == 0 || core < 32 || (whole.width <= options.tile_size * 5 / 4 && whole.height <= options.tile_size * 5 / 4))
    return {Tile{cv::Rect({0, 0}, image), cv::Rect({0, 0}, image)}};
  const int nx = (image.width + core - 1) / core, ny = (image.height + core - 1) / core;
  const cv::Rect bounds({0, 0}, image);
  std::vector<Tile> tiles;
  for (int ty = 0; ty < ny; ++ty)
    for (int tx = 0; tx < nx; ++tx) {
      const int x0 = tx * image.width / nx, x1 = (tx + 1) * image.width / nx;
      const int y0 = ty * image.height / ny, y1 = (ty + 1) * image.height / ny;
      const cv::Rect kept(x0, y0, x1 - x0, y1 - y0);
      const cv::Rect fitted = cv::Rect(x0 - overlap, y0 - overlap, kept.width + 2 * overlap, kept.height + 2 * overlap) & bounds;
      tiles.push_back({kept, fitted});
    }
  return tiles;
}

// Deconvolves observed(tile.data) (CV_32F or CV_64F) and writes its tile.core into `result`.
void deconvolveTile(const cv::Mat& observed, const cv::Mat& data_mask, const cv::Mat& kernel, const Tile& tile,
                    const DeconvolutionOptions& options, cv::Mat& result, int* iterations) {
  const int depth = options.single_precision ? CV_32F : CV_64F;
  cv::Mat f;
  observed(tile.data).convertTo(f, depth);
  const Padding padding = choosePadding(f.size(), kernel);
  const cv::Mat padded = reflectPad(f, padding);
  const cv::Mat kernel_spectrum = kernelSpectrum(kernel, padding.padded, depth);
  cv::Mat u;
  if (options.method == DeconvolutionMethod::Wiener) {
    u = wienerSolve(padded, kernel_spectrum, options.wiener_nsr);
    if (iterations) *iterations = 1;
  } else {
    cv::Mat mask(padding.padded, CV_8U, cv::Scalar(options.free_boundary ? 0 : 255));
    if (data_mask.empty()) mask(padding.interior()).setTo(255);
    else cv::Mat(data_mask(tile.data) != 0).copyTo(mask(padding.interior()));
    u = depth == CV_32F ? totalVariationSolve<float>(padded, mask, kernel_spectrum, options, iterations)
                        : totalVariationSolve<double>(padded, mask, kernel_spectrum, options, iterations);
  }
  const cv::Rect core_in_u(padding.left + tile.core.x - tile.data.x, padding.top + tile.core.y - tile.data.y,
                           tile.core.width, tile.core.height);
  cv::Mat target = result(tile.core);
  u(core_in_u).convertTo(target, result.depth());
}

}  // namespace

DeconvolutionMethod parseDeconvolutionMethod(const std::string& name) {
  if (name == "tv") return DeconvolutionMethod::TotalVariation;
  if (name == "wiener") return DeconvolutionMethod::Wiener;
  throw InvalidInput("unknown deconvolution method '" + name + "' (tv or wiener)");
}

DeconvolutionDomain parseDeconvolutionDomain(const std::string& name) {
  if (name == "irradiance") return DeconvolutionDomain::Irradiance;
  if (name == "intensity") return DeconvolutionDomain::Intensity;
  throw InvalidInput("unknown deconvolution domain '" + name + "' (irradiance or intensity)");
}

const char* toString(DeconvolutionMethod method) {
  return method == DeconvolutionMethod::TotalVariation ? "tv" : "wiener";
}

const char* toString(DeconvolutionDomain domain) {
  return domain == DeconvolutionDomain::Irradiance ? "irradiance" : "intensity";
}

void DeconvolutionOptions::check() const {
  if (!(lambda > 0) || !std::isfinite(lambda)) throw InvalidInput("deconvolution lambda must be positive");
  if (!(beta_start > 0) || !(beta_max >= beta_start) || !std::isfinite(beta_max))
    throw InvalidInput("deconvolution needs 0 < beta_start <= beta_max");
  if (!(beta_factor > 1)) throw InvalidInput("deconvolution beta_factor must exceed 1");
  if (inner_iterations < 1) throw InvalidInput("deconvolution needs at least one inner iteration");
  if (!(tolerance >= 0)) throw InvalidInput("deconvolution tolerance must be non-negative");
  if (!(wiener_nsr > 0)) throw InvalidInput("Wiener noise-to-signal ratio must be positive");
  if (!(saturation > 0 && saturation <= 1)) throw InvalidInput("saturation level must lie in (0, 1]");
  if (tile_size < 0 || tile_overlap < 0) throw InvalidInput("deconvolution tile size and overlap must be >= 0");
}

std::string DeconvolutionResult::summary() const {
  char text[320];
  std::snprintf(text, sizeof text,
                "%s deconvolution in the %s domain: %dx%d, %d channel(s), %d tile(s), FFT %dx%d, %d u-step(s) per "
                "tile, %lld saturated pixel-channel(s) masked, %.2f s",
                toString(options.method), toString(options.domain), deblurred.cols, deblurred.rows,
                deblurred.channels(), tiles, padded_size.width, padded_size.height, iterations, saturated_pixels,
                seconds);
  return text;
}

cv::Mat deconvolveChannel(const cv::Mat& observed, const cv::Mat& kernel, const cv::Mat& data_mask,
                          const DeconvolutionOptions& options, int* iterations) {
  options.check();
  if (observed.empty() || observed.channels() != 1) throw InvalidInput("deconvolveChannel needs one channel");
  if (!data_mask.empty() && data_mask.size() != observed.size())
    throw InvalidInput("deconvolution mask and image differ in size");
  const cv::Mat k = normalizeKernel(kernel);
  const std::vector<Tile> tiles = planTiles(observed.size(), k, options);
  cv::Mat result(observed.size(), CV_64F);
  std::vector<int> steps(tiles.size(), 0);
  cv::parallel_for_(cv::Range(0, static_cast<int>(tiles.size())), [&](const cv::Range& range) {
    for (int t = range.start; t < range.end; ++t) deconvolveTile(observed, data_mask, k, tiles[t], options, result, &steps[t]);
  });
  if (iterations) *iterations = steps[0];
  return result;
}

DeconvolutionResult deconvolve(const cv::Mat& blurred, const cv::Mat& kernel, const std::vector<ResponseCurve>& curves,
                               const DeconvolutionOptions& options) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  options.check();
  if (blurred.empty()) throw InvalidInput("image to deblur is empty");
  const int channels = blurred.channels();
  if (curves.size() != 1 && static_cast<int>(curves.size()) != channels)
    throw InvalidInput("deblurring needs one response curve or one per channel (" + std::to_string(channels) + ")");
  const int image_depth = blurred.depth();
  if (image_depth != CV_8U && image_depth != CV_16U && image_depth != CV_32F && image_depth != CV_64F)
    throw InvalidInput("images to deblur must be 8-bit, 16-bit or floating point");
  const cv::Mat k = normalizeKernel(kernel);
  const bool irradiance = options.domain == DeconvolutionDomain::Irradiance;
  const bool masking = options.mask_saturated && options.method == DeconvolutionMethod::TotalVariation;
  const int depth = options.single_precision ? CV_32F : CV_64F;
  const auto curveOf = [&](int c) -> const ResponseCurve& { return curves.size() == 1 ? curves[0] : curves[c]; };

  // Per channel: the data mask and the signal to deconvolve (φ(B) or B), straight from the interleaved input in
  // one pass over its rows (no full-size intermediate planes: at 12 MP each would be ~100 MB).
  std::vector<cv::Mat> observed(channels), masks(channels), results(channels);
  for (int c = 0; c < channels; ++c) {
    observed[c].create(blurred.size(), depth);
    if (masking) masks[c].create(blurred.size(), CV_8U);
    results[c].create(blurred.size(), depth);
  }
  const double scale = image_depth == CV_8U ? 1.0 / 255 : image_depth == CV_16U ? 1.0 / 65535 : 1.0;
  cv::parallel_for_(cv::Range(0, blurred.rows), [&](const cv::Range& rows) {
    std::vector<double> unit(static_cast<size_t>(blurred.cols) * channels);
    for (int y = rows.start; y < rows.end; ++y) {
      cv::Mat row(1, blurred.cols * channels, CV_64F, unit.data());
      blurred.row(y).reshape(1, 1).convertTo(row, CV_64F, scale);  // B in [0,1]
      for (int c = 0; c < channels; ++c) {
        const ResponseCurve& curve = curveOf(c);
        uchar* mask = masking ? masks[c].ptr<uchar>(y) : nullptr;
        for (int x = 0; x < blurred.cols; ++x) {
          const double b = unit[static_cast<size_t>(x) * channels + c];
          const double value = irradiance ? curve.inverse(b) : b;
          if (depth == CV_32F) observed[c].ptr<float>(y)[x] = static_cast<float>(value);
          else observed[c].ptr<double>(y)[x] = value;
          if (mask) mask[x] = b < options.saturation ? 255 : 0;
        }
      }
    }
  });
  long long saturated = 0;
  for (int c = 0; c < channels && masking; ++c)
    saturated += static_cast<long long>(masks[c].total()) - cv::countNonZero(masks[c]);
  const auto prepared = Clock::now();

  // Every (channel, tile) pair is one job, so that two cores stay busy whatever the number of channels.
  const std::vector<Tile> tiles = planTiles(blurred.size(), k, options);
  const int jobs = channels * static_cast<int>(tiles.size());
  std::vector<int> steps(jobs, 0);
  cv::parallel_for_(cv::Range(0, jobs), [&](const cv::Range& range) {
    for (int job = range.start; job < range.end; ++job) {
      const int c = job / static_cast<int>(tiles.size());
      deconvolveTile(observed[c], masks[c], k, tiles[job % tiles.size()], options, results[c], &steps[job]);
    }
  });
  for (cv::Mat& plane : observed) plane.release();
  const auto solved = Clock::now();

  // Clamped to [0,1] and mapped back with ψ (irradiance), written into the interleaved CV_64F result.
  DeconvolutionResult result;
  result.deblurred.create(blurred.size(), CV_MAKETYPE(CV_64F, channels));
  cv::parallel_for_(cv::Range(0, blurred.rows), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      double* out = result.deblurred.ptr<double>(y);
      for (int c = 0; c < channels; ++c) {
        const ResponseCurve& curve = curveOf(c);
        for (int x = 0; x < blurred.cols; ++x) {
          const double solved_value = depth == CV_32F ? double(std::min(std::max(results[c].ptr<float>(y)[x], 0.0f), 1.0f))
                                                      : std::min(std::max(results[c].ptr<double>(y)[x], 0.0), 1.0);
          out[static_cast<size_t>(x) * channels + c] = irradiance ? curve.forward(solved_value) : solved_value;
        }
      }
    }
  });
  result.options = options;
  result.iterations = steps[0];
  result.saturated_pixels = saturated;
  result.tiles = static_cast<int>(tiles.size());
  result.padded_size = choosePadding(tiles[0].data.size(), k).padded;
  const auto seconds = [](Clock::time_point from, Clock::time_point to) { return std::chrono::duration<double>(to - from).count(); };
  result.prepare_seconds = seconds(start, prepared);
  result.solve_seconds = seconds(prepared, solved);
  result.seconds = seconds(start, Clock::now());
  return result;
}

double psnr(const cv::Mat& estimate, const cv::Mat& reference, int border) {
  if (estimate.size() != reference.size() || estimate.channels() != reference.channels())
    throw InvalidInput("PSNR needs images of the same size and channels");
  const cv::Rect inside(border, border, estimate.cols - 2 * border, estimate.rows - 2 * border);
  if (inside.width <= 0 || inside.height <= 0) throw InvalidInput("PSNR border leaves no pixels");
  cv::Mat a, b;
  estimate(inside).convertTo(a, CV_64F);
  reference(inside).convertTo(b, CV_64F);
  const double squared = cv::norm(a, b, cv::NORM_L2SQR) / (static_cast<double>(a.total()) * a.channels());
  return 10 * std::log10(1.0 / std::max(squared, 1e-20));
}

}  // namespace crfcal
