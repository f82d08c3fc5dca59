#include "packed_spectrum.hpp"

#include <cstddef>
#include <initializer_list>

namespace crfcal::packed {
namespace {

// Calls element(re, im) for every (re, im) pair of the packed layout and element(re, -1) for every real element,
// by flat index (continuous matrices).
template <typename Element>
void forEachPacked(int rows, int cols, Element element) {
  CV_Assert(rows >= 2 && cols >= 2);
  const std::ptrdiff_t stride = cols;
  for (const int x : {0, cols - 1}) {
    if (x == cols - 1 && cols % 2 != 0) break;  // an odd width has one stacked column
    element(x, -1);
    for (int y = 1; y + 1 < rows; y += 2) element(y * stride + x, (y + 1) * stride + x);
    if (rows % 2 == 0) element((rows - 1) * stride + x, -1);
  }
  const int end = cols % 2 == 0 ? cols - 1 : cols;  // side-by-side pairs in columns [1, end)
  for (int y = 0; y < rows; ++y) {
    const std::ptrdiff_t row = y * stride;
    for (int x = 1; x < end; x += 2) element(row + x, row + x + 1);
  }
}

// (a_re + i a_im)(b_re + i b_im) in double, rounded to T once (cv::mulSpectrums' arithmetic).
template <typename T>
inline void complexProduct(T a_re, T a_im, T b_re, T b_im, T& c_re, T& c_im) {
  const double re = double(a_re) * b_re - double(a_im) * b_im;
  const double im = double(a_re) * b_im + double(a_im) * b_re;
  c_re = static_cast<T>(re);
  c_im = static_cast<T>(im);
}

void checkOperands(std::initializer_list<const cv::Mat*> operands, int depth) {
  const cv::Mat& first = **operands.begin();
  for (const cv::Mat* m : operands)
    CV_Assert(m->depth() == depth && m->channels() == 1 && m->isContinuous() && m->size() == first.size());
}

}  // namespace

template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fill, const cv::Mat& data_gain,
                   const cv::Mat& kernel, cv::Mat& u_spectrum, cv::Mat& prediction) {
  const int depth = cv::DataType<T>::depth;
  checkOperands({&adjoint, &reciprocal, &fill, &data_gain, &kernel}, depth);
  u_spectrum.create(adjoint.size(), depth);
  prediction.create(adjoint.size(), depth);
  const T *a = adjoint.ptr<T>(), *r = reciprocal.ptr<T>(), *f = fill.ptr<T>(), *g = data_gain.ptr<T>();
  const T* k = kernel.ptr<T>();
  T *u = u_spectrum.ptr<T>(), *p = prediction.ptr<T>();
  forEachPacked(adjoint.rows, adjoint.cols, [&](std::ptrdiff_t re, std::ptrdiff_t im) {
    if (im < 0) {
      const T data = f[re] * g[re];
      u[re] = a[re] * r[re] + data;
      p[re] = u[re] * k[re];
      return;
    }
    T data_re, data_im;
    complexProduct(f[re], f[im], g[re], g[im], data_re, data_im);
    u[re] = a[re] * r[re] + data_re;
    u[im] = a[im] * r[im] + data_im;
    complexProduct(u[re], u[im], k[re], k[im], p[re], p[im]);
  });
}

template <typename T>
void uStepSpectrum(const cv::Mat& adjoint, const cv::Mat& reciprocal, const cv::Mat& fixed_data, cv::Mat& u_spectrum) {
  const int depth = cv::DataType<T>::depth;
  checkOperands({&adjoint, &reciprocal, &fixed_data}, depth);
  u_spectrum.create(adjoint.size(), depth);
  const T *a = adjoint.ptr<T>(), *r = reciprocal.ptr<T>(), *c = fixed_data.ptr<T>();
  T* u = u_spectrum.ptr<T>();
  const std::size_t count = adjoint.total();
  for (std::size_t i = 0; i < count; ++i) u[i] = a[i] * r[i] + c[i];  // element-wise: the layout does not matter
}

template void uStepSpectrum<float>(const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&,
                                   cv::Mat&, cv::Mat&);
template void uStepSpectrum<double>(const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&, const cv::Mat&,
                                    cv::Mat&, cv::Mat&);
template void uStepSpectrum<float>(const cv::Mat&, const cv::Mat&, const cv::Mat&, cv::Mat&);
template void uStepSpectrum<double>(const cv::Mat&, const cv::Mat&, const cv::Mat&, cv::Mat&);

}  // namespace crfcal::packed
