// The effect search's Levenberg–Marquardt (Problem::fitLevel, calib/src/effect_problem.cpp) factorises the samples
// once per weight group — the samples that share φ̂'(B) and h_k'(B), i.e. one level of B (groupByWeight) — and then
// iterates on the groups' factors (calib/src/effect_grouped_residuals.hpp). Checked here against the residuals
// computed sample by sample: the groups' cost, gradient and JᵀJ equal the per-sample sums even far from the fit
// (where sums of squares would cancel), and the grouped fit is a minimum of the residuals of Problem::residual
// (another code path) and the same fit as with every sample alone.
#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "../calib/src/effect_grouped_residuals.hpp"
#include "effect_problem_support.hpp"
#include "crfcal/emor.hpp"

namespace crfcal::effect {
namespace {

constexpr int kTerms = 2;

// One channel with vignetting, a black offset and two φ terms; B on 8-bit codes (so a few hundred groups), φ̂' of
// a gamma curve, floored near white (φ̂' < min_derivative there), as collect() forms the columns.
Samples eightBitSamples(unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> irradiance(0.01, 0.9), radius(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 0.01);
  std::vector<double> phi(emor::kSamples);
  for (int i = 0; i < emor::kSamples; ++i) phi[i] = std::pow(double(i) / (emor::kSamples - 1), 2.2);
  Samples s = emptySamples(1, kTerms, std::move(phi));
  for (int i = 0; i < 8000; ++i) {
    const double x = irradiance(rng), rho2 = radius(rng);
    const double e = std::clamp(x * (1 - 0.2 * rho2) + 0.01 + noise(rng), 0.0, 1.0);
    const double b = std::round(255 * std::pow(e, 1 / 2.2)) / 255;  // an 8-bit code
    const int bi = std::clamp(static_cast<int>(b * 1023 + 0.5), 0, 1023);
    s.block.push_back(i % 64);
    s.fine.push_back(i % 256);
    s.fold.push_back(i % 2);
    s.d.push_back(2.2 * std::pow(std::max(b, 1e-3), 1.2) * (1 - b) * 4);  // below 0.05 near b = 0 and b = 1
    s.Y.push_back(std::pow(b, 2.2));
    s.rho2.push_back(rho2);
    s.level.push_back(b);
    s.X[0].push_back(x);
    s.pos.emplace_back(i % 100, i / 100);
    for (int k = 0; k < kTerms; ++k) {
      const auto h = emor::inverseBasis(k + 1);
      const int lo = std::max(0, bi - 1), hi = std::min(emor::kSamples - 1, bi + 1);
      s.Hb[k].push_back(h[bi]);
      s.Dh[k].push_back((h[hi] - h[lo]) * (emor::kSamples - 1) / (hi - lo));
      s.KH[k].push_back(h[static_cast<int>(x * 1023)]);
      s.P[k].push_back(h[static_cast<int>(x * 1023)] - h[bi]);
    }
  }
  return s;
}

Spec vignettingAndOffset() {
  Spec spec;
  spec.vignetting = true;
  spec.offset = true;
  return spec;
}

// Groups of 1–40 samples with two nearly collinear columns (1 + 1e-5 u and 1) and two φ terms, some groups' φ̂'
// below the floor; the cost, gradient and JᵀJ computed sample by sample in long double.
struct GroupedCase {
  static constexpr int kCols = 5, kPhiTerms = 2;
  static constexpr double kFloor = 0.05;
  std::vector<std::vector<std::array<double, kCols + 1>>> rows;  // per group: [c t]
  std::vector<double> d0;
  std::vector<std::array<double, kPhiTerms>> slope;

  explicit GroupedCase(unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    std::uniform_int_distribution<int> size(1, 40);
    for (int g = 0; g < 60; ++g) {
      d0.push_back(unit(rng) < 0.2 ? 0.03 : 0.1 + 2 * unit(rng));
      slope.push_back({unit(rng) - 0.5, unit(rng) - 0.5});
      rows.emplace_back();
      for (int i = size(rng); i > 0; --i)
        rows.back().push_back({1 + 1e-5 * unit(rng), 1.0, unit(rng), unit(rng) - 0.5, unit(rng), unit(rng)});
    }
  }
  // Group g at B's level g / 255; only the groups below `clip`.
  GroupedResiduals residuals(double clip = 2) const {
    GroupedResiduals out(kCols, kPhiTerms, kFloor);
    for (std::size_t g = 0; g < rows.size(); ++g) {
      if (g / 255.0 >= clip) continue;
      const int id = out.addGroup(d0[g], slope[g].data(), static_cast<int>(rows[g].size()));
      for (const auto& r : rows[g]) out.add(id, r.data(), r[kCols], g / 255.0);
    }
    return out;
  }
  double weight(std::size_t g, const Eigen::VectorXd& theta) const {
    const double d = d0[g] + slope[g][0] * theta(kCols - 2) + slope[g][1] * theta(kCols - 1);
    return 1.0 / std::max(d, kFloor);
  }
  // Σ r², Jᵀr and JᵀJ with J_i = −w (c_i + w u q_i e), sample by sample.
  void direct(const Eigen::VectorXd& theta, long double& cost, Eigen::VectorXd& jtr, Eigen::MatrixXd& jtj) const {
    cost = 0;
    jtr = Eigen::VectorXd::Zero(kCols);
    jtj = Eigen::MatrixXd::Zero(kCols, kCols);
    for (std::size_t g = 0; g < rows.size(); ++g) {
      const double w = weight(g, theta);
      const double d = d0[g] + slope[g][0] * theta(kCols - 2) + slope[g][1] * theta(kCols - 1);
      for (const auto& r : rows[g]) {
        long double p = 0;
        for (int a = 0; a < kCols; ++a) p += static_cast<long double>(r[a]) * theta(a);
        const double q = static_cast<double>(r[kCols] - p);
        cost += static_cast<long double>(w) * w * q * q;
        Eigen::VectorXd j(kCols);
        for (int a = 0; a < kCols; ++a) j(a) = -w * r[a];
        if (d >= kFloor)
          for (int k = 0; k < kPhiTerms; ++k) j(kCols - kPhiTerms + k) -= w * w * q * slope[g][k];
        jtr += j * (w * q);
        jtj += j * j.transpose();
      }
    }
  }
};

TEST(EffectGroupedResiduals, CostGradientAndNormalMatrixEqualTheSampleBySampleSumsFarFromTheFit) {
  const GroupedCase data(7);
  GroupedResiduals grouped = data.residuals();
  // Far out along the collinear pair (c·θ stays O(10) while θ's entries are 1e6: Σ t² − 2θ·Σct + θᵀGθ would lose
  // all but a few digits), and near the origin.
  for (const Eigen::VectorXd& theta : {Eigen::VectorXd((Eigen::VectorXd(5) << 1e6, -1e6, 0.3, 0.2, -0.1).finished()),
                                       Eigen::VectorXd((Eigen::VectorXd(5) << 0.5, 0.1, 0.3, 0.2, -0.1).finished())}) {
    long double cost = 0;
    Eigen::VectorXd jtr;
    Eigen::MatrixXd jtj;
    data.direct(theta, cost, jtr, jtj);
    const double grouped_cost = grouped.evaluate(theta);
    EXPECT_NEAR(grouped_cost, static_cast<double>(cost), 1e-10 * static_cast<double>(cost)) << theta.transpose();
    Eigen::MatrixXd JtJ;
    Eigen::VectorXd Jtr;
    grouped.normalEquations(JtJ, Jtr);
    EXPECT_LE((Jtr - jtr).norm(), 1e-8 * jtr.norm()) << theta.transpose();
    EXPECT_LE((JtJ - jtj).norm(), 1e-9 * jtj.norm()) << theta.transpose();
  }
}

// The plateau grid's levels take their groups from one factorisation of all samples: the same to the bit as
// grouping and factorising each level's samples anew; a group that straddles the level cannot be taken.
TEST(EffectGroupedResiduals, GroupsBelowAPlateauLevelEqualThoseFactorisedOnTheirOwn) {
  const GroupedCase data(8);
  GroupedResiduals all = data.residuals();
  all.factorise();
  const double clip = 30.5 / 255;
  GroupedResiduals taken(0, 0, 0);
  ASSERT_TRUE(all.below(clip, taken));
  GroupedResiduals anew = data.residuals(clip);
  ASSERT_EQ(taken.groups(), 31);
  ASSERT_EQ(anew.groups(), 31);
  const Eigen::VectorXd theta = (Eigen::VectorXd(5) << 0.5, 0.1, 0.3, 0.2, -0.1).finished();
  EXPECT_EQ(taken.evaluate(theta), anew.evaluate(theta));
  Eigen::MatrixXd a, b;
  Eigen::VectorXd ga, gb;
  taken.normalEquations(a, ga);
  anew.normalEquations(b, gb);
  EXPECT_EQ(a, b);
  EXPECT_EQ(ga, gb);
  // one group whose samples lie on both sides of the level
  GroupedResiduals straddling(GroupedCase::kCols, GroupedCase::kPhiTerms, GroupedCase::kFloor);
  const double slope[2] = {0.1, 0.2}, row[6] = {1, 1, 0.5, 0.1, 0.2, 0.3};
  const int g = straddling.addGroup(1.0, slope, 2);
  straddling.add(g, row, row[5], 0.40);
  straddling.add(g, row, row[5], 0.41);
  straddling.factorise();
  GroupedResiduals none(0, 0, 0);
  EXPECT_FALSE(straddling.below(0.405, none));
  EXPECT_TRUE(straddling.below(0.5, none));
  EXPECT_EQ(none.groups(), 1);
}

TEST(EffectWeightGroups, SamplesAreGroupedByTheirLevelOfB) {
  Samples s = eightBitSamples(1);
  groupByWeight(s);
  ASSERT_EQ(s.weight_group.size(), s.size());
  EXPECT_EQ(s.weight_groups, static_cast<int>(std::set<double>(s.level.begin(), s.level.end()).size()));
  std::vector<std::size_t> first(static_cast<std::size_t>(s.weight_groups), s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    std::size_t& f = first[static_cast<std::size_t>(s.weight_group[i])];
    if (f == s.size()) f = i;
    EXPECT_EQ(s.d[i], s.d[f]);
    for (int k = 0; k < kTerms; ++k) EXPECT_EQ(s.Dh[k][i], s.Dh[k][f]);
  }
}

TEST(EffectWeightGroups, GroupedFitIsAMinimumOfTheSampleBySampleResiduals) {
  for (unsigned seed : {2u, 3u}) {
    Samples s = eightBitSamples(seed);
    groupByWeight(s);
    const Problem problem({s}, 64, 256, 0.05);
    const Spec spec = vignettingAndOffset();
    const ChannelFit f = problem.fitLevel(problem.samples()[0], spec, test::allSamples(s), 0);
    ASSERT_TRUE(f.ok);
    ASSERT_EQ(f.theta.size(), 4 + kTerms);  // scale, two vignetting terms, offset, φ terms
    const double at_fit = test::inSampleError(problem, spec, f);
    for (Eigen::Index a = 0; a < f.theta.size(); ++a)
      for (double sign : {-1.0, 1.0}) {
        ChannelFit moved = f;
        moved.theta(a) += sign * 1e-3 * (std::abs(f.theta(a)) + 1e-3);
        EXPECT_GE(test::inSampleError(problem, spec, moved), at_fit * (1 - 1e-9))
            << "coefficient " << a << " moved by " << sign << " lowers the residuals, seed " << seed;
      }
  }
}

TEST(EffectWeightGroups, GroupedFitEqualsTheFitWithEverySampleAlone) {
  Samples grouped = eightBitSamples(4);
  groupByWeight(grouped);
  ASSERT_LT(grouped.weight_groups, 300);
  const Samples alone = eightBitSamples(4);  // no groups: each sample its own
  const Spec spec = vignettingAndOffset();
  const Problem by_group({grouped}, 64, 256, 0.05), by_sample({alone}, 64, 256, 0.05);
  const ChannelFit a = by_group.fitLevel(by_group.samples()[0], spec, test::allSamples(grouped), 0);
  const ChannelFit b = by_sample.fitLevel(by_sample.samples()[0], spec, test::allSamples(alone), 0);
  ASSERT_TRUE(a.ok && b.ok);
  for (Eigen::Index k = 0; k < a.theta.size(); ++k)
    EXPECT_NEAR(a.theta(k), b.theta(k), 1e-6 * (std::abs(b.theta(k)) + 1e-3)) << "coefficient " << k;
}

}  // namespace
}  // namespace crfcal::effect
