// The pieces of an estimated kernel and the message of an estimate at its size limit (calib/src/kernel_pieces.hpp).
#include <string>

#include <gtest/gtest.h>

#include "../calib/src/kernel_pieces.hpp"

namespace crfcal::detail {
namespace {

TEST(KernelPieces, SpecksBelowATenthOfTheLargestPieceAreDropped) {
  cv::Mat K = cv::Mat::zeros(35, 35, CV_64F);
  K(cv::Rect(8, 17, 20, 1)).setTo(0.05);  // a 20 px trajectory, mass 1
  K.at<double>(3, 3) = 0.05;               // a speck, 5 % of it
  K.at<double>(30, 30) = 0.2;              // a second piece, 20 % of it
  const KernelPieces pieces = keepMassivePieces(K);
  EXPECT_EQ(pieces.count, 2);
  EXPECT_NEAR(pieces.largest_share, 1.0 / 1.2, 1e-12);
  EXPECT_EQ(K.at<double>(3, 3), 0.0);
  EXPECT_EQ(K.at<double>(30, 30), 0.2);
}

TEST(KernelPieces, AnEstimateScatteredOverItsWindowIsSaidToHaveFallenApart) {
  cv::Mat K = cv::Mat::zeros(79, 79, CV_64F);
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 5; ++j) K.at<double>(6 + 13 * i, 6 + 16 * j) = 1.0 / 30;  // 30 specks, none on the border
  K.at<double>(0, 40) = 0.02;                                                     // and some mass on it
  const KernelPieces pieces = keepMassivePieces(K);
  EXPECT_EQ(pieces.count, 31);
  const std::string message = kernelSizeLimitMessage(K, pieces);
  EXPECT_NE(message.find("fell apart at its size limit (79x79 px: 31 separate pieces, the largest with 3%"),
            std::string::npos) << message;
}

TEST(KernelPieces, ATrajectoryCutByTheWindowReachesItsSizeLimit) {
  cv::Mat K = cv::Mat::zeros(35, 35, CV_64F);
  K(cv::Rect(10, 17, 25, 1)).setTo(1.0 / 25);  // runs out of the window on the right
  const KernelPieces pieces = keepMassivePieces(K);
  EXPECT_EQ(pieces.count, 1);
  EXPECT_NEAR(borderMass(K), 2.0 / 25, 1e-12);
  const std::string message = kernelSizeLimitMessage(K, pieces);
  EXPECT_NE(message.find("reaches its size limit (35x35 px, 8% of its mass on the border)"), std::string::npos)
      << message;
  EXPECT_NE(message.find("try a larger --max-kernel-size"), std::string::npos) << message;
}

// Pieces that pile their mass on the border are a blur cut off by the window, however many there are.
TEST(KernelPieces, PiecesPiledOnTheBorderAreACutOffBlurNotAFallenApartOne) {
  cv::Mat K = cv::Mat::zeros(35, 35, CV_64F);
  for (int i = 0; i < 4; ++i) K(cv::Rect(0, 4 + 8 * i, 3, 1)).setTo(1.0 / 12);  // four pieces at the left edge
  const KernelPieces pieces = keepMassivePieces(K);
  EXPECT_EQ(pieces.count, 4);
  EXPECT_GT(borderMass(K), borderAreaShare(35));
  EXPECT_NE(kernelSizeLimitMessage(K, pieces).find("reaches its size limit"), std::string::npos);
}

TEST(KernelPieces, AnEvenSpreadPutsTheRingsAreaShareOnTheBorder) {
  EXPECT_NEAR(borderMass(cv::Mat::ones(35, 35, CV_64F)), borderAreaShare(35), 1e-12);
  EXPECT_NEAR(borderMass(cv::Mat::ones(11, 11, CV_64F)), borderAreaShare(11), 1e-12);
  EXPECT_NEAR(borderAreaShare(79), 1.0 - 75.0 * 75.0 / (79.0 * 79.0), 1e-12);
}

}  // namespace
}  // namespace crfcal::detail
