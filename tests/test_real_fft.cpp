// The deconvolution's DFTs (calib/src/real_fft.hpp): FFTW's transforms in OpenCV's packed CCS layout must be what
// cv::dft gives, for every parity of rows and columns, both precisions, and inputs OpenCV would accept (a view that
// is not continuous), so that the packed spectrum code reading them stays correct.
#include <algorithm>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "../calib/src/real_fft.hpp"

namespace crfcal {
namespace {

cv::Mat randomImage(int rows, int cols, int depth, int seed) {
  cv::Mat image(rows, cols, depth);
  cv::RNG rng(seed);
  rng.fill(image, cv::RNG::UNIFORM, -1.0, 1.0);
  return image;
}

// Largest |a − b| relative to the largest |b|.
double relativeMaxDifference(const cv::Mat& a, const cv::Mat& b) {
  return cv::norm(a, b, cv::NORM_INF) / std::max(cv::norm(b, cv::NORM_INF), 1e-30);
}

struct Shape {
  int rows, cols;
};

const std::vector<Shape> kShapes = {{2, 2}, {8, 8}, {9, 8}, {8, 9}, {9, 7}, {64, 90}, {75, 64}, {101, 97}, {240, 256}};

TEST(RealFft, ForwardGivesOpenCvsPackedSpectrumForEveryParity) {
  for (const int depth : {CV_32F, CV_64F})
    for (const Shape& shape : kShapes) {
      const cv::Mat image = randomImage(shape.rows, shape.cols, depth, shape.rows * 1000 + shape.cols);
      cv::Mat expected, packed;
      cv::dft(image, expected);
      fft::forward(image, packed);
      ASSERT_EQ(packed.size(), expected.size());
      ASSERT_EQ(packed.type(), expected.type());
      EXPECT_LT(relativeMaxDifference(packed, expected), depth == CV_32F ? 1e-5 : 1e-12)
          << shape.rows << "x" << shape.cols << (depth == CV_32F ? " float" : " double");
    }
}

TEST(RealFft, InverseGivesOpenCvsScaledRealInverseForEveryParity) {
  for (const int depth : {CV_32F, CV_64F})
    for (const Shape& shape : kShapes) {
      // a packed spectrum as OpenCV forms it, then altered so that it is not the spectrum of the image any more (a
      // product with another spectrum, as the solver's u-step makes)
      const cv::Mat image = randomImage(shape.rows, shape.cols, depth, 7 + shape.rows);
      const cv::Mat other = randomImage(shape.rows, shape.cols, depth, 11 + shape.cols);
      cv::Mat a, b, product;
      cv::dft(image, a);
      cv::dft(other, b);
      cv::mulSpectrums(a, b, product, 0);
      cv::Mat expected, real;
      cv::dft(product, expected, cv::DFT_INVERSE | cv::DFT_SCALE | cv::DFT_REAL_OUTPUT);
      fft::inverse(product, real);
      ASSERT_EQ(real.size(), expected.size());
      ASSERT_EQ(real.type(), expected.type());
      EXPECT_LT(relativeMaxDifference(real, expected), depth == CV_32F ? 1e-5 : 1e-12)
          << shape.rows << "x" << shape.cols << (depth == CV_32F ? " float" : " double");
    }
}

TEST(RealFft, RoundTripReturnsTheImageAndMayWriteOverTheSpectrum) {
  const cv::Mat image = randomImage(90, 64, CV_64F, 3);
  cv::Mat spectrum;
  fft::forward(image, spectrum);
  fft::inverse(spectrum, spectrum);  // in place: the spectrum is read before the image is written
  EXPECT_LT(relativeMaxDifference(spectrum, image), 1e-12);
}

TEST(RealFft, AcceptsViewsThatAreNotContinuous) {
  const cv::Mat canvas = randomImage(80, 100, CV_32F, 5);
  const cv::Mat view = canvas(cv::Rect(3, 5, 64, 48));
  ASSERT_FALSE(view.isContinuous());
  cv::Mat expected, packed;
  cv::dft(view, expected);
  fft::forward(view, packed);
  EXPECT_LT(relativeMaxDifference(packed, expected), 1e-5);

  cv::Mat output_canvas(80, 100, CV_32F, cv::Scalar(42)), back;
  cv::Mat output_view = output_canvas(cv::Rect(3, 5, 64, 48));
  fft::inverse(packed, output_view);  // written through the view, the rest of the canvas untouched
  EXPECT_LT(relativeMaxDifference(output_view, cv::Mat(view)), 1e-5);
  EXPECT_EQ(output_canvas.at<float>(0, 0), 42.0f);
  EXPECT_EQ(output_canvas.at<float>(79, 99), 42.0f);
}

TEST(RealFft, ConcurrentCallsOfNewSizesAgreeWithOneThread) {
  // plans are made on first use under a lock; transforms run concurrently with per-thread scratch
  std::vector<cv::Mat> images, serial(8), parallel(8);
  for (int i = 0; i < 8; ++i) images.push_back(randomImage(50 + 2 * i, 60 + 3 * i, CV_32F, i));
  std::vector<std::thread> threads;
  for (int i = 0; i < 8; ++i) threads.emplace_back([&, i] { fft::forward(images[i], parallel[i]); });
  for (std::thread& thread : threads) thread.join();
  for (int i = 0; i < 8; ++i) {
    fft::forward(images[i], serial[i]);
    EXPECT_EQ(cv::norm(parallel[i], serial[i], cv::NORM_INF), 0.0) << i;
  }
}

// FFTW's half spectrum against OpenCV's full complex DFT: frequency (y, j) for j ≤ cols/2.
TEST(RealFft, HalfSpectrumIsTheLeftHalfOfTheComplexDft) {
  for (const int depth : {CV_32F, CV_64F})
    for (const Shape& shape : kShapes) {
      const cv::Mat image = randomImage(shape.rows, shape.cols, depth, 31 + shape.rows);
      cv::Mat full, half;
      cv::dft(image, full, cv::DFT_COMPLEX_OUTPUT);
      fft::forwardHalf(image, half);
      ASSERT_EQ(half.rows, shape.rows);
      ASSERT_EQ(half.cols, shape.cols / 2 + 1);
      ASSERT_EQ(half.type(), CV_MAKETYPE(depth, 2));
      EXPECT_LT(relativeMaxDifference(half, full.colRange(0, shape.cols / 2 + 1)), depth == CV_32F ? 1e-5 : 1e-12)
          << shape.rows << "x" << shape.cols;
    }
}

TEST(RealFft, PackedToHalfAndUnscaledInverseUndoTheTransforms) {
  for (const Shape& shape : kShapes) {
    const cv::Mat image = randomImage(shape.rows, shape.cols, CV_64F, 41 + shape.cols);
    cv::Mat packed, half, back;
    cv::dft(image, packed);
    const cv::Mat from_packed = fft::packedToHalf(packed, 0.5);
    fft::forwardHalf(image, half);
    EXPECT_LT(relativeMaxDifference(from_packed, 0.5 * half), 1e-12) << shape.rows << "x" << shape.cols;
    fft::inverseHalf(half, shape.cols, back);  // unscaled: rows · cols times the image
    EXPECT_LT(relativeMaxDifference(back, image * double(shape.rows * shape.cols)), 1e-12)
        << shape.rows << "x" << shape.cols;
  }
}

TEST(RealFft, InverseHalfRejectsAWidthThatDoesNotMatchTheHalfSpectrum) {
  cv::Mat half(8, 5, CV_32FC2, cv::Scalar(0, 0)), out;
  EXPECT_THROW(fft::inverseHalf(half, 10, out), cv::Exception);  // 10 columns have 6 frequencies
  EXPECT_NO_THROW(fft::inverseHalf(half, 9, out));                // 9 have 5
}

TEST(RealFft, RejectsWhatIsNotOneRealChannelOfAtLeastTwoByTwo) {
  cv::Mat out;
  EXPECT_THROW(fft::forward(cv::Mat(1, 8, CV_32F, cv::Scalar(0)), out), cv::Exception);
  EXPECT_THROW(fft::forward(cv::Mat(8, 8, CV_32FC2, cv::Scalar(0)), out), cv::Exception);
  EXPECT_THROW(fft::forward(cv::Mat(8, 8, CV_8U, cv::Scalar(0)), out), cv::Exception);
  EXPECT_THROW(fft::inverse(cv::Mat(), out), cv::Exception);
}

}  // namespace
}  // namespace crfcal
