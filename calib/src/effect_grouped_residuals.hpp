#pragma once
// The effect search's Levenberg–Marquardt (Problem::levenbergMarquardt, effect_problem.cpp) on the residuals
// r_i = w (t_i − c_i·θ) of samples that share their weight w = 1 / max(φ̂'(B) + Σ α_k h_k'(B), min_derivative):
// one weight group (groupByWeight: the same φ̂'(B) and h_k'(B), i.e. the same level of B).
//
// Everything the LM needs is a function of the group's triangular factor R̃ (QR of its rows [c_i t_i]):
// Σ q² = ‖R̃ (θ, −1)‖² with q_i = t_i − c_i·θ, Σ c q = −(R̃ᵀ R̃ (θ, −1))_c, G = Σ c cᵀ = (R̃ᵀR̃)_cc. So each pass costs
// O(groups · cols²) instead of O(samples · cols²): a few hundred levels of B against ~15,000 samples. The factor,
// not the sums Σ c cᵀ, Σ c t, Σ t²: their Σ q² = Σ t² − 2θ·Σ c t + θᵀGθ cancels to nothing when θ is far out (an
// ill-conditioned model's LM wandering off), while R̃ (θ, −1) errs as t_i − c_i·θ does. The factor depends on the
// samples alone, so a run paused and run on later makes the same passes, to the bit, as one run to the end.
#include <vector>

#include <Eigen/Core>

namespace crfcal::effect {

class GroupedResiduals {
 public:
  // cols: θ's size; terms: its last `terms` entries are the φ re-fit's α_k (they move w).
  GroupedResiduals(int cols, int terms, double min_derivative)
      : cols_(cols), terms_(terms), min_derivative_(min_derivative) {}

  // A group of `samples` samples with φ̂'(B) `derivative` and h_k'(B) `slope` (terms entries); returns its index.
  int addGroup(double derivative, const double* slope, int samples);
  // The next sample (design row x, cols entries; target t; its level of B) of group g; after every addGroup().
  void add(int g, const double* x, double t, double level);
  int groups() const { return static_cast<int>(d0_.size()); }
  // Factorises every group's samples (else the first evaluate() does).
  void factorise();
  // The groups whose samples all lie below B's level `clip`, factorised as this one (so the same, to the bit, as
  // those samples grouped and factorised on their own): the plateau grid's levels drop whole groups. False when a
  // group straddles `clip` (B not on integer codes): then nothing is written.
  bool below(double clip, GroupedResiduals& out) const;

  // Σ r² at θ; keeps each group's w, Σ c q and Σ q² there for normalEquations(). The first call factorises.
  double evaluate(const Eigen::VectorXd& theta);
  // JᵀJ and Jᵀr at the θ of the last evaluate().
  void normalEquations(Eigen::MatrixXd& JtJ, Eigen::VectorXd& Jtr) const;

 private:
  int width() const { return cols_ + 1; }

  int cols_, terms_;
  double min_derivative_;
  std::vector<double> d0_, slope_;     // per group: φ̂'(B); h_k'(B) (terms)
  std::vector<double> lowest_, highest_;  // per group: its samples' lowest and highest level of B
  std::vector<int> count_, filled_;    // per group: samples, samples added
  std::vector<std::size_t> start_;     // per group: its first entry in rows_
  std::vector<double> rows_;           // per group: its samples' [c t], column-major (count × width) until factorised
  std::vector<double> factor_, gram_;  // per group: R̃ (width², column-major, rows past the samples zero); G (cols²)
  Eigen::VectorXd w_, q2_;
  Eigen::MatrixXd q1_;
  std::vector<char> unfloored_;
};

}  // namespace crfcal::effect
