#include "half_spectrum.hpp"

#include <cstddef>
#include <initializer_list>
#include <type_traits>

#include <opencv2/core/hal/intrin.hpp>

namespace crfcal::half {
namespace {

// (a_re + i a_im)(b_re + i b_im) in double, rounded to T once (cv::mulSpectrums' arithmetic).
template <typename T>
inline void complexProduct(T a_re, T a_im, T b_re, T b_im, T& c_re, T& c_im) {
  const double re = double(a_re) * b_re - double(a_im) * b_im;
  const double im = double(a_re) * b_im + double(a_im) * b_re;
  c_re = static_cast<T>(re);
  c_im = static_cast<T>(im);
}

void checkOperands(std::initializer_list<const cv::Mat*> complex_operands, const cv::Mat& real_operand, int depth) {
  const cv::Mat& first = **complex_operands.begin();
  for (const cv::Mat* m : complex_operands)
    CV_Assert(m->depth() == depth && m->channels() == 2 && m->isContinuous() && m->size() == first.size());
  CV_Assert(real_operand.depth() == depth && real_operand.channels() == 1 && real_operand.isContinuous() &&
            real_operand.size() == first.size());
}

// Four complex values at a time for float spectra (OpenCV's universal intrinsics; GCC does not vectorise the
// interleaved complex products): the complex products in float, not double. Returns the first index left to the
// scalar loop.
std::size_t uStepSimd(const float* a, const float* r, const float* f, const float* g, const float* k, float* u, float* p,
                      std::size_t count) {
  std::size_t i = 0;
#if CV_SIMD128
  for (; i + 4 <= count; i += 4) {
    cv::v_float32x4 a_re, a_im, f_re, f_im, g_re, g_im, k_re, k_im;
    cv::v_load_deinterleave(a + 2 * i, a_re, a_im);
    cv::v_load_deinterleave(f + 2 * i, f_re, f_im);
    cv::v_load_deinterleave(g + 2 * i, g_re, g_im);
    cv::v_load_deinterleave(k + 2 * i, k_re, k_im);
    const cv::v_float32x4 reciprocal = cv::v_load(r + i);
    const cv::v_float32x4 u_re = a_re * reciprocal + (f_re * g_re - f_im * g_im);
    const cv::v_float32x4 u_im = a_im * reciprocal + (f_re * g_im + f_im * g_re);
    cv::v_store_interleave(u + 2 * i, u_re, u_im);
    cv::v_store_interleave(p + 2 * i, u_re * k_re - u_im * k_im, u_re * k_im + u_im * k_re);
  }
#endif
  return i;
}

}  // namespace

template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fill, const cv::Mat& data_gain,
                   const cv::Mat& kernel, cv::Mat& u_spectrum, cv::Mat& prediction) {
  const int depth = cv::DataType<T>::depth;
  checkOperands({&adjoint, &fill, &data_gain, &kernel}, reciprocal, depth);
  u_spectrum.create(adjoint.size(), adjoint.type());
  prediction.create(adjoint.size(), adjoint.type());
  const T *a = adjoint.ptr<T>(), *r = reciprocal.ptr<T>(), *f = fill.ptr<T>(), *g = data_gain.ptr<T>();
  const T* k = kernel.ptr<T>();
  T *u = u_spectrum.ptr<T>(), *p = prediction.ptr<T>();
  const std::size_t count = reciprocal.total();
  std::size_t first = 0;
  if constexpr (std::is_same_v<T, float>) first = uStepSimd(a, r, f, g, k, u, p, count);
  for (std::size_t i = first; i < count; ++i) {
    const std::size_t re = 2 * i, im = re + 1;
    T data_re, data_im;
    complexProduct(f[re], f[im], g[re], g[im], data_re, data_im);
    u[re] = a[re] * r[i] + data_re;
    u[im] = a[im] * r[i] + data_im;
    complexProduct(u[re], u[im], k[re], k[im], p[re], p[im]);
  }
}

template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fixed_data, cv::Mat& u_spectrum) {
  const int depth = cv::DataType<T>::depth;
  checkOperands({&adjoint, &fixed_data}, reciprocal, depth);
  u_spectrum.create(adjoint.size(), adjoint.type());
  const T *a = adjoint.ptr<T>(), *r = reciprocal.ptr<T>(), *c = fixed_data.ptr<T>();
  T* u = u_spectrum.ptr<T>();
  const std::size_t count = reciprocal.total();
  for (std::size_t i = 0; i < count; ++i) {
    u[2 * i] = a[2 * i] * r[i] + c[2 * i];
    u[2 * i + 1] = a[2 * i + 1] * r[i] + c[2 * i + 1];
  }
}

template void uStepSpectrum<float>(const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&,
                                   cv::Mat&, cv::Mat&);
template void uStepSpectrum<double>(const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&,
                                    cv::Mat&, cv::Mat&);
template void uStepSpectrum<float>(const cv::Mat&, const cv::Mat&, const cv::Mat&, cv::Mat&);
template void uStepSpectrum<double>(const cv::Mat&, const cv::Mat&, const cv::Mat&, cv::Mat&);

}  // namespace crfcal::half
