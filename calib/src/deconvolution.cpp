#include "crfcal/deconvolution.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <mutex>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/error.hpp"
#include "crfcal/kernel.hpp"
#include "real_fft.hpp"
#include "tv_solver.hpp"

namespace crfcal {
namespace {

using detail::CanvasOperators;
using detail::totalVariationSolve;

// ---- spectra -------------------------------------------------------------------------------------------------
// Real DFTs in OpenCV's packed CCS layout (half the spectrum; cv::mulSpectrums / cv::divSpectrums understand it),
// computed by FFTW (real_fft.hpp: a third to a quarter of cv::dft's cost at these sizes). The TV solver's inner
// loop works in FFTW's own half layout instead (no conversion pass per DFT).
// Spectra of real, even operators (|K̂|², |D̂|², the u-step's denominator) have zero imaginary parts there, so a
// product or quotient with them acts on real and imaginary parts alike.

cv::Mat spectrum(const cv::Mat& real) {
  cv::Mat packed;
  fft::forward(real, packed);
  return packed;
}

cv::Mat realInverse(const cv::Mat& packed) {
  cv::Mat real;
  fft::inverse(packed, real);
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

// The smallest length ≥ n whose only prime factors are 2, 3 and 5 (cv::getOptimalDFTSize) and that is even: FFTW's
// real transforms of odd lengths cost about twice as much per pixel (1125² 14.8 ns against 1152² 5.2 ns).
int fastFftLength(int n) {
  int length = cv::getOptimalDFTSize(n);
  while (length % 2 != 0) length = cv::getOptimalDFTSize(length + 1);
  return length;
}

// At least the kernel's extent on every side (so that wrap-around only couples padded pixels), rounded up to a
// fast FFT size; the extra goes to the bottom/right.
Padding choosePadding(cv::Size image, const cv::Mat& kernel) {
  const int margin = std::max(kernel.rows, kernel.cols);
  Padding padding;
  padding.top = padding.left = margin;
  padding.padded = {fastFftLength(image.width + 2 * margin), fastFftLength(image.height + 2 * margin)};
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

// ---- the u-step's operators on one FFT canvas (tv_solver.hpp) ----------------------------------------------------
// Formed once per canvas size and kernel (at 12 MP a handful for the (channel, tile) jobs) instead of four DFTs and a
// dozen passes per tile.

// The real part of a packed spectrum whose imaginary parts are zero (|K̂|², |D̂|²) in FFTW's half layout: one real
// value per frequency.
cv::Mat realHalf(const cv::Mat& packed_real_spectrum) {
  cv::Mat real_part;
  cv::extractChannel(fft::packedToHalf(packed_real_spectrum), real_part, 0);
  return real_part;
}


CanvasOperators canvasOperators(const cv::Mat& kernel, cv::Size size, const DeconvolutionOptions& options) {
  const int depth = options.single_precision ? CV_32F : CV_64F;
  CanvasOperators canvas;
  canvas.kernel_spectrum = kernelSpectrum(kernel, size, depth);
  if (options.method != DeconvolutionMethod::TotalVariation) return canvas;
  const cv::Mat dx = differenceSpectrum(size, true, depth), dy = differenceSpectrum(size, false, depth);
  canvas.size = size;
  canvas.kernel_half = fft::packedToHalf(canvas.kernel_spectrum);
  canvas.gradient_energy = realHalf(multiply(dx, dx, true) + multiply(dy, dy, true));
  canvas.kernel_energy = realHalf(multiply(canvas.kernel_spectrum, canvas.kernel_spectrum, true));
  canvas.stepOperators(options.beta_start, options.lambda, canvas.first_reciprocal, canvas.first_data_gain);
  return canvas;
}

// ---- tiles ---------------------------------------------------------------------------------------------------
// A large image is deconvolved tile by tile: each tile fits the image pixels of `data` (its core grown by the
// overlap, clipped to the image) on its own small FFT canvas with the free boundary around it, and keeps only its
// core. Small FFTs run several times faster per pixel than one image-sized FFT (they stay in cache) and bound the
// memory; the overlap keeps the tiles' free-boundary errors out of the kept cores.

struct Tile {
  cv::Rect core;   // pixels this tile writes
  cv::Rect data;   // pixels it fits (⊇ core)
  int kernel = 0;  // index of its kernel (several local kernels: the one whose centre is nearest the core's)
};

// The kernels of one deconvolution: one for the whole image, or local kernels each holding around its centre.
struct KernelSet {
  std::vector<cv::Mat> kernels;     // normalised
  std::vector<cv::Point2d> centres;  // one per kernel (unused for a single kernel)

  int margin() const {  // the largest extent: every tile's overlap and the tiling use it
    int extent = 0;
    for (const cv::Mat& k : kernels) extent = std::max({extent, k.rows, k.cols});
    return extent;
  }
  int nearest(cv::Point2d point) const {
    int best = 0;
    for (std::size_t i = 1; i < centres.size(); ++i)
      if (cv::norm(centres[i] - point) < cv::norm(centres[static_cast<std::size_t>(best)] - point)) best = static_cast<int>(i);
    return best;
  }
  // With local kernels, tiles no larger than their spacing (cores about the distance between the two closest
  // centres, at least 64 px), so that each part of the image is deconvolved with the kernel estimated nearest it.
  int tileSize(const DeconvolutionOptions& options) const {
    if (kernels.size() < 2 || options.tile_size == 0) return options.tile_size;
    double spacing = std::numeric_limits<double>::infinity();
    for (std::size_t i = 0; i < centres.size(); ++i)
      for (std::size_t j = i + 1; j < centres.size(); ++j) spacing = std::min(spacing, cv::norm(centres[i] - centres[j]));
    const int overlap = options.tile_overlap > 0 ? options.tile_overlap : 2 * margin();
    const int core = static_cast<int>(std::max(64.0, std::min(spacing, 1e6)));
    return std::min(options.tile_size, core + 2 * (margin() + overlap));
  }
};

std::vector<Tile> planTiles(cv::Size image, const KernelSet& kernels, const DeconvolutionOptions& options) {
  const int margin = kernels.margin();
  const int overlap = options.tile_overlap > 0 ? options.tile_overlap : 2 * margin;
  const int tile_size = kernels.tileSize(options);
  // the core a tile of `tile_size` leaves after the free-boundary padding and the overlap on both sides
  const int core = tile_size - 2 * (margin + overlap);
  const cv::Size whole(image.width + 2 * margin, image.height + 2 * margin);
  const auto withKernels = [&](std::vector<Tile> tiles) {
    for (Tile& tile : tiles)
      tile.kernel = kernels.nearest({tile.core.x + 0.5 * (tile.core.width - 1), tile.core.y + 0.5 * (tile.core.height - 1)});
    return tiles;
  };
  const bool fits_one_tile = whole.width <= tile_size * 5 / 4 && whole.height <= tile_size * 5 / 4;
  if (tile_size == 0 || core < 32 || (fits_one_tile && kernels.kernels.size() < 2))  // local kernels: always tiles
    return withKernels({Tile{cv::Rect({0, 0}, image), cv::Rect({0, 0}, image)}});
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
  return withKernels(std::move(tiles));
}

// The operators of every (canvas size, kernel) the tiles use, keyed by (width, height, kernel), formed in parallel.
using CanvasKey = std::tuple<int, int, int>;
using Canvases = std::map<CanvasKey, CanvasOperators>;

CanvasKey canvasKey(const Tile& tile, const KernelSet& kernels) {
  const cv::Size size = choosePadding(tile.data.size(), kernels.kernels[static_cast<std::size_t>(tile.kernel)]).padded;
  return {size.width, size.height, tile.kernel};
}

Canvases prepareCanvases(const std::vector<Tile>& tiles, const KernelSet& kernels, const DeconvolutionOptions& options) {
  Canvases canvases;
  for (const Tile& tile : tiles) canvases[canvasKey(tile, kernels)];
  std::vector<Canvases::value_type*> entries;
  for (auto& entry : canvases) entries.push_back(&entry);
  cv::parallel_for_(cv::Range(0, static_cast<int>(entries.size())), [&](const cv::Range& range) {
    for (int i = range.start; i < range.end; ++i) {
      const auto& [width, height, kernel] = entries[i]->first;
      entries[i]->second = canvasOperators(kernels.kernels[static_cast<std::size_t>(kernel)], {width, height}, options);
    }
  });
  return canvases;
}

// Deconvolves observed(tile.data) (CV_32F or CV_64F) and returns the solution on tile.core (a view, not clamped;
// TV: of the thread's workspace, valid until the thread's next solve).
cv::Mat solveTile(const cv::Mat& observed, const cv::Mat& data_mask, const KernelSet& kernels, const Tile& tile,
                  const Canvases& canvases, const DeconvolutionOptions& options, int* iterations) {
  const int depth = options.single_precision ? CV_32F : CV_64F;
  cv::Mat f;
  observed(tile.data).convertTo(f, depth);
  const Padding padding = choosePadding(f.size(), kernels.kernels[static_cast<std::size_t>(tile.kernel)]);
  const cv::Mat padded = reflectPad(f, padding);
  const CanvasOperators& canvas = canvases.at(canvasKey(tile, kernels));
  cv::Mat u;
  if (options.method == DeconvolutionMethod::Wiener) {
    u = wienerSolve(padded, canvas.kernel_spectrum, options.wiener_nsr);
    if (iterations) *iterations = 1;
  } else {
    cv::Mat mask(padding.padded, CV_8U, cv::Scalar(options.free_boundary ? 0 : 255));
    if (data_mask.empty()) mask(padding.interior()).setTo(255);
    else cv::Mat(data_mask(tile.data) != 0).copyTo(mask(padding.interior()));
    u = depth == CV_32F ? totalVariationSolve<float>(padded, mask, canvas, options, iterations)
                        : totalVariationSolve<double>(padded, mask, canvas, options, iterations);
  }
  const cv::Rect core_in_u(padding.left + tile.core.x - tile.data.x, padding.top + tile.core.y - tile.data.y,
                           tile.core.width, tile.core.height);
  return u(core_in_u);
}

// A tile's solution `core` (CV_32F or CV_64F) clamped to [0,1] and mapped back with ψ (irradiance) into channel c
// of the interleaved CV_64F `deblurred` at `where`: done by the tile's own job, so that no full-size plane of
// solutions is kept and faulted in (3 × 48 MB at 12 MP) and ψ needs no pass of its own.
void writeIntensity(const cv::Mat& core, cv::Rect where, int c, const ResponseCurve& curve, bool irradiance,
                    cv::Mat& deblurred) {
  const int channels = deblurred.channels();
  for (int y = 0; y < core.rows; ++y) {
    double* out = deblurred.ptr<double>(where.y + y) + static_cast<size_t>(where.x) * channels + c;
    for (int x = 0; x < core.cols; ++x) {
      const double solved_value = core.depth() == CV_32F ? double(std::min(std::max(core.ptr<float>(y)[x], 0.0f), 1.0f))
                                                         : std::min(std::max(core.ptr<double>(y)[x], 0.0), 1.0);
      out[static_cast<size_t>(x) * channels] = irradiance ? curve.forward(solved_value) : solved_value;
    }
  }
}

// Per channel: the signal to deconvolve (φ(B) or B, CV_32F or CV_64F = `depth`) and the data mask, straight from
// the interleaved input in one parallel pass over its rows (no full-size intermediate planes: at 12 MP each would be
// ~100 MB). 8- and 16-bit input goes through a table per channel indexed by the code, formed by the same conversion
// and the same φ as the per-pixel path (identical values; φ is then one lookup per pixel instead of an evaluation).
void prepareChannels(const cv::Mat& blurred, const std::vector<ResponseCurve>& curves, bool irradiance, bool masking,
                     double saturation, int depth, std::vector<cv::Mat>& observed, std::vector<cv::Mat>& masks) {
  const int channels = blurred.channels(), image_depth = blurred.depth();
  const auto curveOf = [&](int c) -> const ResponseCurve& { return curves.size() == 1 ? curves[0] : curves[c]; };
  for (int c = 0; c < channels; ++c) {
    observed[c].create(blurred.size(), depth);
    if (masking) masks[c].create(blurred.size(), CV_8U);
  }
  const double scale = image_depth == CV_8U ? 1.0 / 255 : image_depth == CV_16U ? 1.0 / 65535 : 1.0;
  const auto store = [&](int c, int y, int x, double value) {
    if (depth == CV_32F) observed[c].ptr<float>(y)[x] = static_cast<float>(value);
    else observed[c].ptr<double>(y)[x] = value;
  };
  const int codes = image_depth == CV_8U ? 256 : image_depth == CV_16U ? 65536 : 0;
  if (codes > 0) {
    cv::Mat code(1, codes, CV_32S), unit;
    for (int v = 0; v < codes; ++v) code.at<int>(v) = v;
    code.convertTo(code, image_depth);
    code.convertTo(unit, CV_64F, scale);  // B in [0,1], as the per-pixel path converts it
    std::vector<std::vector<double>> value_of(channels, std::vector<double>(codes));
    std::vector<uchar> kept_of(codes);
    for (int v = 0; v < codes; ++v) {
      const double b = unit.at<double>(v);
      for (int c = 0; c < channels; ++c) value_of[c][v] = irradiance ? curveOf(c).inverse(b) : b;
      kept_of[v] = b < saturation ? 255 : 0;
    }
    cv::parallel_for_(cv::Range(0, blurred.rows), [&](const cv::Range& rows) {
      for (int y = rows.start; y < rows.end; ++y)
        for (int c = 0; c < channels; ++c) {
          uchar* mask = masking ? masks[c].ptr<uchar>(y) : nullptr;
          for (int x = 0; x < blurred.cols; ++x) {
            const int v = image_depth == CV_8U ? blurred.ptr<uchar>(y)[x * channels + c]
                                               : blurred.ptr<ushort>(y)[x * channels + c];
            store(c, y, x, value_of[c][v]);
            if (mask) mask[x] = kept_of[v];
          }
        }
    });
    return;
  }
  cv::parallel_for_(cv::Range(0, blurred.rows), [&](const cv::Range& rows) {
    std::vector<double> unit(static_cast<size_t>(blurred.cols) * channels);
    for (int y = rows.start; y < rows.end; ++y) {
      cv::Mat row(1, blurred.cols * channels, CV_64F, unit.data());
      blurred.row(y).reshape(1, 1).convertTo(row, CV_64F, scale);  // B in [0,1]
      for (int c = 0; c < channels; ++c) {
        uchar* mask = masking ? masks[c].ptr<uchar>(y) : nullptr;
        for (int x = 0; x < blurred.cols; ++x) {
          const double b = unit[static_cast<size_t>(x) * channels + c];
          store(c, y, x, irradiance ? curveOf(c).inverse(b) : b);
          if (mask) mask[x] = b < saturation ? 255 : 0;
        }
      }
    }
  });
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

DeconvolutionOptions DeconvolutionOptions::withFastSchedule() const {
  DeconvolutionOptions fast = *this;
  fast.inner_iterations = 8;
  fast.beta_start = fast.beta_max = 128;
  return fast;
}

std::string DeconvolutionResult::summary() const {
  char text[320];
  std::snprintf(text, sizeof text,
                "%s deconvolution in the %s domain: %dx%d, %d channel(s), %d tile(s), FFT %dx%d, %d u-step(s) per "
                "tile, %lld saturated pixel-channel(s) masked, %.2f s",
                toString(options.method), toString(options.domain), deblurred.cols, deblurred.rows,
                deblurred.channels(), tiles, padded_size.width, padded_size.height, iterations, saturated_pixels,
                seconds);
  if (kernels > 1) return std::string(text) + ", " + std::to_string(kernels) + " local kernels (each tile the nearest)";
  return text;
}

cv::Mat deconvolveChannel(const cv::Mat& observed, const cv::Mat& kernel, const cv::Mat& data_mask,
                          const DeconvolutionOptions& options, int* iterations) {
  options.check();
  if (observed.empty() || observed.channels() != 1) throw InvalidInput("deconvolveChannel needs one channel");
  if (!data_mask.empty() && data_mask.size() != observed.size())
    throw InvalidInput("deconvolution mask and image differ in size");
  const KernelSet k{{normalizeKernel(kernel)}, {{0, 0}}};
  const std::vector<Tile> tiles = planTiles(observed.size(), k, options);
  const Canvases canvases = prepareCanvases(tiles, k, options);
  cv::Mat result(observed.size(), CV_64F);
  std::vector<int> steps(tiles.size(), 0);
  cv::parallel_for_(cv::Range(0, static_cast<int>(tiles.size())), [&](const cv::Range& range) {
    for (int t = range.start; t < range.end; ++t) {
      cv::Mat target = result(tiles[t].core);
      solveTile(observed, data_mask, k, tiles[t], canvases, options, &steps[t]).convertTo(target, CV_64F);
    }
  });
  if (iterations) *iterations = steps[0];
  return result;
}

namespace {

DeconvolutionResult deconvolveWith(const cv::Mat& blurred, const KernelSet& k, const std::vector<ResponseCurve>& curves,
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
  const bool irradiance = options.domain == DeconvolutionDomain::Irradiance;
  const bool masking = options.mask_saturated && options.method == DeconvolutionMethod::TotalVariation;
  const int depth = options.single_precision ? CV_32F : CV_64F;
  const auto curveOf = [&](int c) -> const ResponseCurve& { return curves.size() == 1 ? curves[0] : curves[c]; };

  std::vector<cv::Mat> observed(channels), masks(channels);
  prepareChannels(blurred, curves, irradiance, masking, options.saturation, depth, observed, masks);
  long long saturated = 0;
  for (int c = 0; c < channels && masking; ++c)
    saturated += static_cast<long long>(masks[c].total()) - cv::countNonZero(masks[c]);
  const auto prepared = Clock::now();

  // Every (channel, tile) pair is one job, so that two cores stay busy whatever the number of channels.
  const std::vector<Tile> tiles = planTiles(blurred.size(), k, options);
  const Canvases canvases = prepareCanvases(tiles, k, options);
  const int jobs = channels * static_cast<int>(tiles.size());
  std::vector<int> steps(jobs, 0);
  DeconvolutionResult result;
  result.deblurred.create(blurred.size(), CV_MAKETYPE(CV_64F, channels));
  std::mutex progress_mutex;
  int jobs_done = 0;
  cv::parallel_for_(cv::Range(0, jobs), [&](const cv::Range& range) {
    for (int job = range.start; job < range.end; ++job) {
      const int c = job / static_cast<int>(tiles.size());
      const Tile& tile = tiles[job % tiles.size()];
      writeIntensity(solveTile(observed[c], masks[c], k, tile, canvases, options, &steps[job]), tile.core, c,
                     curveOf(c), irradiance, result.deblurred);
      if (options.progress) {
        const std::lock_guard<std::mutex> lock(progress_mutex);
        ++jobs_done;
        options.progress(double(jobs_done) / jobs, std::to_string(jobs_done) + "/" + std::to_string(jobs));
      }
    }
  });
  for (cv::Mat& plane : observed) plane.release();
  const auto solved = Clock::now();

  result.options = options;
  result.iterations = steps[0];
  result.saturated_pixels = saturated;
  result.tiles = static_cast<int>(tiles.size());
  result.padded_size = choosePadding(tiles[0].data.size(), k.kernels[static_cast<std::size_t>(tiles[0].kernel)]).padded;
  std::vector<int> used;
  for (const Tile& tile : tiles) used.push_back(tile.kernel);
  std::sort(used.begin(), used.end());
  result.kernels = static_cast<int>(std::unique(used.begin(), used.end()) - used.begin());
  const auto seconds = [](Clock::time_point from, Clock::time_point to) { return std::chrono::duration<double>(to - from).count(); };
  result.prepare_seconds = seconds(start, prepared);
  result.solve_seconds = seconds(prepared, solved);
  result.seconds = seconds(start, Clock::now());
  return result;
}

}  // namespace

DeconvolutionResult deconvolve(const cv::Mat& blurred, const cv::Mat& kernel, const std::vector<ResponseCurve>& curves,
                               const DeconvolutionOptions& options) {
  return deconvolveWith(blurred, KernelSet{{normalizeKernel(kernel)}, {{0, 0}}}, curves, options);
}

DeconvolutionResult deconvolve(const cv::Mat& blurred, const std::vector<LocalKernel>& kernels,
                               const std::vector<ResponseCurve>& curves, const DeconvolutionOptions& options) {
  if (kernels.empty()) throw InvalidInput("deblurring with local kernels needs at least one");
  KernelSet set;
  for (const LocalKernel& local : kernels) {
    if (!std::isfinite(local.centre.x) || !std::isfinite(local.centre.y))
      throw InvalidInput("a local kernel's centre is not finite");
    set.kernels.push_back(normalizeKernel(local.kernel));
    set.centres.push_back(local.centre);
  }
  return deconvolveWith(blurred, set, curves, options);
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
