#include "real_fft.hpp"

#include <fftw3.h>

#include <cstddef>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <utility>

namespace crfcal::fft {
namespace {

// FFTW's float and double interfaces under one name.
template <typename T>
struct Fftw;

template <>
struct Fftw<float> {
  using Plan = fftwf_plan;
  using Complex = fftwf_complex;
  static Plan planForward(int rows, int cols, float* in, Complex* out, unsigned flags) {
    return fftwf_plan_dft_r2c_2d(rows, cols, in, out, flags);
  }
  static Plan planInverse(int rows, int cols, Complex* in, float* out, unsigned flags) {
    return fftwf_plan_dft_c2r_2d(rows, cols, in, out, flags);
  }
  static void executeForward(Plan plan, float* in, Complex* out) { fftwf_execute_dft_r2c(plan, in, out); }
  static void executeInverse(Plan plan, Complex* in, float* out) { fftwf_execute_dft_c2r(plan, in, out); }
  static void* allocate(std::size_t bytes) { return fftwf_malloc(bytes); }
  static void release(void* data) { fftwf_free(data); }
  static int alignmentOf(float* data) { return fftwf_alignment_of(data); }
  static void destroy(Plan plan) { fftwf_destroy_plan(plan); }
};

template <>
struct Fftw<double> {
  using Plan = fftw_plan;
  using Complex = fftw_complex;
  static Plan planForward(int rows, int cols, double* in, Complex* out, unsigned flags) {
    return fftw_plan_dft_r2c_2d(rows, cols, in, out, flags);
  }
  static Plan planInverse(int rows, int cols, Complex* in, double* out, unsigned flags) {
    return fftw_plan_dft_c2r_2d(rows, cols, in, out, flags);
  }
  static void executeForward(Plan plan, double* in, Complex* out) { fftw_execute_dft_r2c(plan, in, out); }
  static void executeInverse(Plan plan, Complex* in, double* out) { fftw_execute_dft_c2r(plan, in, out); }
  static void* allocate(std::size_t bytes) { return fftw_malloc(bytes); }
  static void release(void* data) { fftw_free(data); }
  static int alignmentOf(double* data) { return fftw_alignment_of(data); }
  static void destroy(Plan plan) { fftw_destroy_plan(plan); }
};

// A buffer from FFTW's allocator (aligned as its plans expect).
template <typename T>
struct FftwBuffer {
  struct Release {
    void operator()(void* data) const { Fftw<T>::release(data); }
  };
  std::unique_ptr<void, Release> data;
  std::size_t bytes = 0;

  void* reserve(std::size_t wanted) {
    if (wanted > bytes) {
      data.reset(Fftw<T>::allocate(wanted));
      if (!data) throw std::bad_alloc();
      bytes = wanted;
    }
    return data.get();
  }
};

// The half spectrum FFTW reads and writes (rows × (cols/2 + 1) complex values), one per thread and precision, kept
// between calls: a fresh one per transform would fault in its pages every time.
template <typename T>
typename Fftw<T>::Complex* halfSpectrum(int rows, int cols) {
  thread_local FftwBuffer<T> buffer;
  const std::size_t count = static_cast<std::size_t>(rows) * (cols / 2 + 1);
  return static_cast<typename Fftw<T>::Complex*>(buffer.reserve(count * sizeof(typename Fftw<T>::Complex)));
}

std::mutex& plannerMutex() {
  static std::mutex mutex;
  return mutex;
}

// The plans made so far, per (rows, cols), kept for the process's life and destroyed with it (at exit, when no
// transform runs any more): a plan that outlived its map was reported as leaked memory by LeakSanitizer.
template <typename T>
struct PlanCache {
  std::map<std::pair<int, int>, typename Fftw<T>::Plan> forward, inverse;
  PlanCache() = default;
  PlanCache(const PlanCache&) = delete;
  PlanCache& operator=(const PlanCache&) = delete;
  ~PlanCache() {
    for (auto* plans : {&forward, &inverse})
      for (const auto& entry : *plans) Fftw<T>::destroy(entry.second);
  }
};

// The plan of one (rows, cols, direction), made on scratch arrays of FFTW's alignment: executed later on other
// arrays (FFTW's new-array interface), which must have that alignment too (checked by the callers).
template <typename T>
typename Fftw<T>::Plan planFor(int rows, int cols, bool inverse) {
  using Plan = typename Fftw<T>::Plan;
  using Complex = typename Fftw<T>::Complex;
  static PlanCache<T> cache;
  const std::lock_guard<std::mutex> lock(plannerMutex());
  auto& plans = inverse ? cache.inverse : cache.forward;
  const auto found = plans.find({rows, cols});
  if (found != plans.end()) return found->second;
  FftwBuffer<T> real, spectrum;
  T* real_data = static_cast<T*>(real.reserve(static_cast<std::size_t>(rows) * cols * sizeof(T)));
  auto* spectrum_data = static_cast<Complex*>(spectrum.reserve(static_cast<std::size_t>(rows) * (cols / 2 + 1) * sizeof(Complex)));
  const Plan plan = inverse ? Fftw<T>::planInverse(rows, cols, spectrum_data, real_data, FFTW_ESTIMATE)
                            : Fftw<T>::planForward(rows, cols, real_data, spectrum_data, FFTW_ESTIMATE);
  CV_Assert(plan != nullptr);
  plans.emplace(std::make_pair(rows, cols), plan);
  return plan;
}

// FFTW's half spectrum Y(y, j), j ≤ cols/2, into the packed CCS layout: the side-by-side (re, im) pairs of columns
// (2j − 1, 2j) for 0 < j < cols/2 (every frequency row), and the self-conjugate frequency columns j = 0 and, for an
// even width, j = cols/2 stacked vertically in columns 0 and cols − 1 (rows 0 … rows/2 only: the others are their
// conjugates).
template <typename T>
void halfToPacked(const typename Fftw<T>::Complex* half_spectrum, int rows, int cols, cv::Mat& packed) {
  const int half = cols / 2 + 1;
  const int last_pair = cols % 2 == 0 ? cols / 2 - 1 : cols / 2;
  for (int y = 0; y < rows; ++y) {
    const auto* in = half_spectrum + static_cast<std::size_t>(y) * half;
    T* out = packed.ptr<T>(y);
    for (int j = 1; j <= last_pair; ++j) {
      out[2 * j - 1] = in[j][0];
      out[2 * j] = in[j][1];
    }
  }
  const auto stack = [&](int column, int j) {
    const auto at = [&](int frequency_row) { return half_spectrum[static_cast<std::size_t>(frequency_row) * half + j]; };
    packed.ptr<T>(0)[column] = at(0)[0];
    for (int i = 1; 2 * i < rows; ++i) {
      packed.ptr<T>(2 * i - 1)[column] = at(i)[0];
      packed.ptr<T>(2 * i)[column] = at(i)[1];
    }
    if (rows % 2 == 0) packed.ptr<T>(rows - 1)[column] = at(rows / 2)[0];
  };
  stack(0, 0);
  if (cols % 2 == 0) stack(cols - 1, cols / 2);
}

// The packed layout back into FFTW's half spectrum, times `scale`: the stacked columns' conjugate rows filled in,
// the imaginary parts of the self-conjugate frequencies (row 0, and row rows/2 of an even height) zero.
template <typename T>
void packedToHalf(const cv::Mat& packed, T scale, typename Fftw<T>::Complex* half_spectrum) {
  const int rows = packed.rows, cols = packed.cols, half = cols / 2 + 1;
  const int last_pair = cols % 2 == 0 ? cols / 2 - 1 : cols / 2;
  for (int y = 0; y < rows; ++y) {
    const T* in = packed.ptr<T>(y);
    auto* out = half_spectrum + static_cast<std::size_t>(y) * half;
    for (int j = 1; j <= last_pair; ++j) {
      out[j][0] = in[2 * j - 1] * scale;
      out[j][1] = in[2 * j] * scale;
    }
  }
  const auto unstack = [&](int column, int j) {
    const auto set = [&](int frequency_row, T re, T im) {
      auto& value = half_spectrum[static_cast<std::size_t>(frequency_row) * half + j];
      value[0] = re;
      value[1] = im;
    };
    set(0, packed.ptr<T>(0)[column] * scale, T(0));
    for (int i = 1; 2 * i < rows; ++i) {
      const T re = packed.ptr<T>(2 * i - 1)[column] * scale, im = packed.ptr<T>(2 * i)[column] * scale;
      set(i, re, im);
      set(rows - i, re, -im);
    }
    if (rows % 2 == 0) set(rows / 2, packed.ptr<T>(rows - 1)[column] * scale, T(0));
  };
  unstack(0, 0);
  if (cols % 2 == 0) unstack(cols - 1, cols / 2);
}

// A continuous matrix whose data FFTW's plans accept (cv::Mat allocates 64-byte aligned): `m` itself or a copy.
template <typename T>
cv::Mat fftwReady(const cv::Mat& m) {
  if (m.isContinuous() && Fftw<T>::alignmentOf(const_cast<T*>(m.ptr<T>())) == 0) return m;
  return m.clone();
}

template <typename T>
void forwardAs(const cv::Mat& real, cv::Mat& packed) {
  const int rows = real.rows, cols = real.cols;
  const auto plan = planFor<T>(rows, cols, false);
  const cv::Mat input = fftwReady<T>(real);
  auto* half_spectrum = halfSpectrum<T>(rows, cols);
  Fftw<T>::executeForward(plan, const_cast<T*>(input.ptr<T>()), half_spectrum);  // r2c keeps its input
  packed.create(rows, cols, real.type());
  halfToPacked<T>(half_spectrum, rows, cols, packed);
}

template <typename T>
void inverseAs(const cv::Mat& packed, cv::Mat& real) {
  const int rows = packed.rows, cols = packed.cols;
  const auto plan = planFor<T>(rows, cols, true);
  auto* half_spectrum = halfSpectrum<T>(rows, cols);
  packedToHalf<T>(packed, static_cast<T>(1.0 / (static_cast<double>(rows) * cols)), half_spectrum);
  real.create(rows, cols, packed.type());
  cv::Mat output = fftwReady<T>(real);  // a copy only for a non-continuous or oddly aligned `real`
  Fftw<T>::executeInverse(plan, half_spectrum, output.ptr<T>());  // c2r overwrites the half spectrum
  if (output.data != real.data) output.copyTo(real);
}

void checkReal(const cv::Mat& m, const char* what) {
  CV_Assert(!m.empty() && m.dims == 2 && m.channels() == 1 && (m.depth() == CV_32F || m.depth() == CV_64F));
  if (m.rows < 2 || m.cols < 2) CV_Error(cv::Error::StsBadSize, std::string(what) + ": needs at least 2x2");
}

// A half spectrum FFTW can read or write in place of its planning arrays: continuous, FFTW's alignment.
template <typename T>
bool fftwHalfReady(const cv::Mat& half) {
  return half.isContinuous() && Fftw<T>::alignmentOf(reinterpret_cast<T*>(half.data)) == 0;
}

template <typename T>
void forwardHalfAs(const cv::Mat& real, cv::Mat& half) {
  const int rows = real.rows, cols = real.cols;
  const auto plan = planFor<T>(rows, cols, false);
  const cv::Mat input = fftwReady<T>(real);
  half.create(rows, cols / 2 + 1, CV_MAKETYPE(real.depth(), 2));
  if (!fftwHalfReady<T>(half)) half = cv::Mat(rows, cols / 2 + 1, CV_MAKETYPE(real.depth(), 2));
  Fftw<T>::executeForward(plan, const_cast<T*>(input.ptr<T>()),
                          reinterpret_cast<typename Fftw<T>::Complex*>(half.data));
}

template <typename T>
void inverseHalfAs(cv::Mat& half, int cols, cv::Mat& real) {
  const int rows = half.rows;
  const auto plan = planFor<T>(rows, cols, true);
  cv::Mat input = fftwHalfReady<T>(half) ? half : half.clone();
  real.create(rows, cols, half.depth());
  cv::Mat output = fftwReady<T>(real);
  Fftw<T>::executeInverse(plan, reinterpret_cast<typename Fftw<T>::Complex*>(input.data), output.ptr<T>());
  if (output.data != real.data) output.copyTo(real);
}

template <typename T>
cv::Mat packedToHalfAs(const cv::Mat& packed, double scale) {
  cv::Mat half(packed.rows, packed.cols / 2 + 1, CV_MAKETYPE(packed.depth(), 2));
  packedToHalf<T>(packed, static_cast<T>(scale), reinterpret_cast<typename Fftw<T>::Complex*>(half.data));
  return half;
}

}  // namespace

void forward(const cv::Mat& real, cv::Mat& packed) {
  checkReal(real, "fft::forward");
  if (real.depth() == CV_32F) forwardAs<float>(real, packed);
  else forwardAs<double>(real, packed);
}

void inverse(const cv::Mat& packed, cv::Mat& real) {
  checkReal(packed, "fft::inverse");
  if (packed.depth() == CV_32F) inverseAs<float>(packed, real);
  else inverseAs<double>(packed, real);
}

void forwardHalf(const cv::Mat& real, cv::Mat& half) {
  checkReal(real, "fft::forwardHalf");
  if (real.depth() == CV_32F) forwardHalfAs<float>(real, half);
  else forwardHalfAs<double>(real, half);
}

void inverseHalf(cv::Mat& half, int cols, cv::Mat& real) {
  CV_Assert(!half.empty() && half.dims == 2 && half.channels() == 2 && (half.depth() == CV_32F || half.depth() == CV_64F));
  if (half.rows < 2 || cols < 2 || half.cols != cols / 2 + 1)
    CV_Error(cv::Error::StsBadSize, "fft::inverseHalf: the half spectrum needs cols/2 + 1 columns and 2 rows or more");
  if (half.depth() == CV_32F) inverseHalfAs<float>(half, cols, real);
  else inverseHalfAs<double>(half, cols, real);
}

cv::Mat packedToHalf(const cv::Mat& packed, double scale) {
  checkReal(packed, "fft::packedToHalf");
  return packed.depth() == CV_32F ? packedToHalfAs<float>(packed, scale) : packedToHalfAs<double>(packed, scale);
}

}  // namespace crfcal::fft
