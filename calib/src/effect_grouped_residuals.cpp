#include "effect_grouped_residuals.hpp"

#include <algorithm>
#include <limits>

#include <Eigen/QR>

#include "crfcal/error.hpp"

namespace crfcal::effect {

int GroupedResiduals::addGroup(double derivative, const double* slope, int samples) {
  d0_.push_back(derivative);
  slope_.insert(slope_.end(), slope, slope + terms_);
  start_.push_back(rows_.size());
  rows_.resize(rows_.size() + static_cast<std::size_t>(samples) * width(), 0.0);
  count_.push_back(samples);
  filled_.push_back(0);
  lowest_.push_back(std::numeric_limits<double>::infinity());
  highest_.push_back(-std::numeric_limits<double>::infinity());
  return groups() - 1;
}

void GroupedResiduals::add(int g, const double* x, double t, double level) {
  lowest_[static_cast<std::size_t>(g)] = std::min(lowest_[static_cast<std::size_t>(g)], level);
  highest_[static_cast<std::size_t>(g)] = std::max(highest_[static_cast<std::size_t>(g)], level);
  const std::size_t m = static_cast<std::size_t>(count_[static_cast<std::size_t>(g)]);
  double* column = rows_.data() + start_[static_cast<std::size_t>(g)] + filled_[static_cast<std::size_t>(g)]++;
  for (int a = 0; a < cols_; ++a) column[a * m] = x[a];
  column[cols_ * m] = t;
}

double GroupedResiduals::evaluate(const Eigen::VectorXd& theta) {
  const int n = groups(), p = width();
  factorise();
  w_.resize(n), q2_.resize(n), q1_.resize(cols_, n), unfloored_.resize(static_cast<std::size_t>(n));
  Eigen::VectorXd point(p), u(p);
  point << theta, -1.0;
  double cost = 0;
  for (int g = 0; g < n; ++g) {
    const Eigen::Map<const Eigen::VectorXd> slope(slope_.data() + static_cast<std::size_t>(g) * terms_, terms_);
    const double d = d0_[static_cast<std::size_t>(g)] + slope.dot(theta.tail(terms_));
    unfloored_[static_cast<std::size_t>(g)] = d >= min_derivative_;
    w_(g) = 1.0 / std::max(d, min_derivative_);
    const Eigen::Map<const Eigen::MatrixXd> R(factor_.data() + static_cast<std::size_t>(g) * p * p, p, p);
    u.noalias() = R.triangularView<Eigen::Upper>() * point;  // ‖u‖² = Σ (c·θ − t)²
    q2_(g) = u.squaredNorm();
    q1_.col(g).noalias() = -(R.leftCols(cols_).transpose() * u);
    cost += w_(g) * w_(g) * q2_(g);
  }
  return cost;
}

// J_i = ∂r_i/∂θ = −w (c_i + w u q_i e) with e = (0, h'(B)) and u = 1 where the derivative is not floored, so per
// group JᵀJ = w² (G + w u (Σcq eᵀ + e Σcqᵀ) + w² u Σq² e eᵀ) and Jᵀr = −w² (Σcq + w u Σq² e).
void GroupedResiduals::normalEquations(Eigen::MatrixXd& JtJ, Eigen::VectorXd& Jtr) const {
  JtJ = Eigen::MatrixXd::Zero(cols_, cols_);
  Jtr = Eigen::VectorXd::Zero(cols_);
  for (int g = 0; g < groups(); ++g) {
    const double w2 = w_(g) * w_(g);
    JtJ.noalias() += w2 * Eigen::Map<const Eigen::MatrixXd>(
                              gram_.data() + static_cast<std::size_t>(g) * cols_ * cols_, cols_, cols_);
    Jtr.noalias() -= w2 * q1_.col(g);
    if (!unfloored_[static_cast<std::size_t>(g)] || terms_ == 0) continue;
    const Eigen::Map<const Eigen::VectorXd> e(slope_.data() + static_cast<std::size_t>(g) * terms_, terms_);
    const double w3 = w2 * w_(g);
    JtJ.bottomRows(terms_).noalias() += w3 * e * q1_.col(g).transpose();
    JtJ.rightCols(terms_).noalias() += w3 * q1_.col(g) * e.transpose();
    JtJ.bottomRightCorner(terms_, terms_).noalias() += (w3 * w_(g) * q2_(g)) * e * e.transpose();
    Jtr.tail(terms_).noalias() -= (w3 * q2_(g)) * e;
  }
}

// Each group's rows factorised in place (Householder QR); R̃ and G = R̃_ccᵀ R̃_cc kept, the rows dropped.
void GroupedResiduals::factorise() {
  if (!factor_.empty() || groups() == 0) return;
  const int p = width();
  factor_.assign(static_cast<std::size_t>(groups()) * p * p, 0.0);
  gram_.resize(static_cast<std::size_t>(groups()) * cols_ * cols_);
  for (int g = 0; g < groups(); ++g) {
    const Eigen::Index m = count_[static_cast<std::size_t>(g)];
    Eigen::Map<Eigen::MatrixXd> a(rows_.data() + start_[static_cast<std::size_t>(g)], m, p);
    const Eigen::HouseholderQR<Eigen::Ref<Eigen::MatrixXd>> qr(a);  // in place: R̃ in a's upper triangle
    Eigen::Map<Eigen::MatrixXd> R(factor_.data() + static_cast<std::size_t>(g) * p * p, p, p);
    const Eigen::Index k = std::min<Eigen::Index>(m, p);
    R.topRows(k) = a.topRows(k).triangularView<Eigen::Upper>();
    Eigen::Map<Eigen::MatrixXd>(gram_.data() + static_cast<std::size_t>(g) * cols_ * cols_, cols_, cols_) =
        R.leftCols(cols_).transpose() * R.leftCols(cols_);
  }
  std::vector<double>().swap(rows_);
}

bool GroupedResiduals::below(double clip, GroupedResiduals& out) const {
  if (factor_.empty() && groups() > 0) throw Error("GroupedResiduals::below: not factorised");
  out = GroupedResiduals(cols_, terms_, min_derivative_);
  const std::size_t p2 = static_cast<std::size_t>(width()) * width(), c2 = static_cast<std::size_t>(cols_) * cols_;
  for (std::size_t g = 0; g < static_cast<std::size_t>(groups()); ++g) {
    if (lowest_[g] >= clip) continue;
    if (highest_[g] >= clip) return false;
    out.d0_.push_back(d0_[g]);
    out.slope_.insert(out.slope_.end(), slope_.begin() + g * terms_, slope_.begin() + (g + 1) * terms_);
    out.lowest_.push_back(lowest_[g]);
    out.highest_.push_back(highest_[g]);
    out.count_.push_back(count_[g]);
    out.filled_.push_back(filled_[g]);
    out.factor_.insert(out.factor_.end(), factor_.begin() + g * p2, factor_.begin() + (g + 1) * p2);
    out.gram_.insert(out.gram_.end(), gram_.begin() + g * c2, gram_.begin() + (g + 1) * c2);
  }
  return true;
}

}  // namespace crfcal::effect
