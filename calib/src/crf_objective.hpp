#pragma once
// Internal to the CRF fitter (crf_fitter.cpp): the objectives (seed Sec. 4).
//  * The seed's Eq. 22 (SeedObjective): Σ W² (ψ(r · (φ(I) ⊗ K)) − B)² over the pixels of Eq. 23/24, with the
//    closed-form r of Eq. 25; the mixtures φ(I) ⊗ K are sparse level mixtures (level_mixture.hpp).
//  * The binned irradiance moments (crfcal's default): per instrument bin k (B's level × B's local min/max), the
//    sums H_k (kernel masses of I's levels) and N_k (B's levels); the residual (r H_k − N_k) · φ divided by φ's
//    secant slope over the bin (the intensity-domain residual of Eq. 21 to first order). MomentResiduals are the
//    rows Levenberg–Marquardt minimises, with the priors' rows (crf_priors.hpp) appended.
//  * The continuously-updated GMM residuals (an ablation, CrfFitOptions::Experimental::variance_correction).
#include <array>
#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "crf_censored.hpp"
#include "crf_curve.hpp"
#include "crf_preparation.hpp"
#include "crfcal/level_mixture.hpp"
#include "crfcal/noise_debias.hpp"

namespace crfcal::crf_fit {

// ---------------------------------------------------------------------------------------------------------
// Seed objective (Eq. 22): Σ W² (ψ(r · m_p) − B_p)² / Σ W², m_p = Σ w_p(v) g(x_v), g = f or R f.
struct SeedObjective {
  const Prepared* prep;
  const LevelMixture* mixture;
  const Curve* curve;
  const NoiseDebias* debias;  // null: none
  std::vector<double> b_value;
  double ratio = 1;
  double weight_sum = 1;

  SeedObjective(const Prepared& prepared, const LevelMixture& mix, const NoiseDebias* debias_or_null, double r);
  double energy(const std::vector<double>& x) const;
  // Eq. 25: the least-squares r of φ(B) ≈ r · (φ(I) ⊗ K) at the current φ.
  double ratioStep(const std::vector<double>& x) const;
};

// ---------------------------------------------------------------------------------------------------------
// Moment sums: per fold (16×16 checkerboard tiles) and instrument bin, the kernel-mass histogram of I's levels
// (H), the level histogram of B (N) and the pixel count.
struct Moments {
  int levels = 256;
  int bins = 0;
  Eigen::MatrixXd h[2], n[2];  // bins × levels
  // squared aggregated masses: Σ_q [I_q = v] c_k(q)², c_k(q) = Σ_{p∈k} K(p − q); empty unless the CUE ablation
  // (CrfFitOptions::Experimental::variance_correction) asked for them, the only reader
  Eigen::MatrixXd q[2];
  Eigen::VectorXd count[2];
  bool hasSquaredMasses() const { return q[0].size() > 0; }
};

// The weighted rows of one data selection: residual_k = √ω_k (r Ĥ_k − N_k) · φ.
// The residual is divided by the secant slope of the current φ over the bin's B levels [v0, v1] (first-order
// intensity-domain residual, Eq. 21), which also removes the φ → 0 / r → 0 degeneracy of irradiance residuals.
struct MomentSystem {
  Eigen::MatrixXd h, n;  // rows already scaled by √ω
  Eigen::MatrixXd q;     // squared masses, scaled by ω (variance of the row's noise: r² q · Var g); empty without them
  std::vector<double> row_scale;  // √(ω/n) of each row
  std::vector<int> v0, v1;
  double weight = 0;     // Σ ω (normalisation of the energy)
  // Extrapolation prior (CrfFitOptions::exponent_smoothness): rows √λ (g_{bc} − g_{ab}) for node triples (a, b, c)
  // outside the covered levels, g_{ab} = (log φ_b − log φ_a) / (log x_b − log x_a) the local exponent.
  std::vector<std::array<int, 3>> exponent_triples;
  double exponent_weight = 0;
  std::vector<char> exponent_upper;  // triple of the chain above the covered levels
  double shoulder_weight = 0;        // upper triples: weight of the shoulder prior
  // upper triples: the reference's change of local exponent (g_{bc} − g_{ab} of the EMoR mean g0) that φ's change
  // is held to; empty: the one-sided prior (a rise is free, a fall costs shoulder_weight)
  std::vector<double> shoulder_reference;
  // Learned prior (CrfFitOptions::learned_prior; replaces the triples): rows M · log φ(learned_nodes) − d, the
  // whitened conditional Gaussian of the exponents outside the covered levels given those inside, √weight folded in.
  std::vector<int> learned_nodes;
  Eigen::MatrixXd learned_matrix;  // rows × learned_nodes.size()
  Eigen::VectorXd learned_offset;
  // Lower bound (CrfFitOptions::min_local_exponent): rows kPenaltyScale · max(0, ε − g_ab) for consecutive nodes.
  std::vector<std::array<int, 2>> exponent_pairs;
  double min_exponent = 0;
  // Exposure-ratio prior (CrfFitOptions::ratio_prior_sigma): one row scale · (log r − log r_nominal) when r is fitted.
  double ratio_prior_scale = 0;
  double ratio_prior_log_centre = 0;
  // Saturated pixels of B as censored observations (crf_censored.hpp); no rows when off or none.
  CensoredRows censored;
  int levels() const { return static_cast<int>(h.cols()); }
};

// The moment data of one pair: the sums, the instrument bins and the level operator of the noise handling.
struct MomentProblem {
  Moments moments;
  int level_bins = 64;
  std::vector<int> bin_level_bin;             // B-level bin of each instrument bin
  const Eigen::MatrixXd* level_operator = nullptr;  // R or J applied to the rows (null: g = φ)
  Eigen::VectorXd omega;                      // per-bin weights ω_k
  std::pair<int, int> covered_levels{0, 0};   // lowest/highest level of the data (0.1 % tails dropped)
  CensoredRows censored;                      // B's clipped pixels and those just below (crf_censored.hpp)

  // The system of one fold (0, 1) or of all the data (−1), without priors.
  MomentSystem system(int fold) const;
};

// Instruments from B alone, the moment sums and the covered levels. Fills result.mixture_nonzeros, moment_bins,
// covered_levels and timings.mixture_s.
MomentProblem buildMomentProblem(const Prepared& prep, const NoiseOperators& noise, const CrfFitOptions& options,
                                 int threads, CrfFitResult& result);

// Energy (per unit weight) of a fixed φ on a system's data rows, r given.
double momentEnergy(const MomentSystem& sys, const std::vector<double>& f, double r);

// Monotonicity penalty residuals on the 1024 grid: √P · max(0, f_i − f_{i+1} + ε); also the scale of the local
// exponent's lower bound.
constexpr double kPenaltyScale = 1e3;

// The residual vector Levenberg–Marquardt minimises for one curve on one system: parameters p = (model
// parameters, log r if fitted). Rows: the data (normalised so that the squared norm is the energy per unit
// weight), EMoR's monotonicity penalty on the 1024 grid, then the priors (crf_priors.hpp; the extrapolation prior
// only when with_prior), then the censored rows (crf_censored.hpp). False outside the model's domain.
class MomentResiduals {
 public:
  MomentResiduals(const Curve& curve, const MomentSystem& sys, double r0, bool fit_ratio, bool with_prior);
  bool operator()(const Eigen::VectorXd& p, Eigen::VectorXd& res, Eigen::MatrixXd* jac) const;

 private:
  // One evaluation's values that the Jacobian at the same point needs again.
  struct Evaluation {
    std::uint64_t owner = 0;  // id_ of the residuals that made it (0: none)
    Eigen::VectorXd p;
    std::vector<double> f, g;  // φ on the levels; EMoR on the validity grid
    double r = 1;
    Eigen::VectorXd hf, slope, raw, res;
    std::vector<double> prior_scale;
  };
  // The residual vector's shape (the same for the residuals and their Jacobian); the prior and censored rows
  // follow the monotonicity rows (crf_priors.hpp, crf_censored.hpp).
  struct Layout {
    int levels, dims, rows;  // levels of φ, curve parameters, data rows
    bool emor;
    double norm;             // 1/√(Σ ω): the data rows' normalisation
    int monotone_rows;       // EMoR's monotonicity penalty rows after the data
  };
  Layout layout() const;
  bool evaluate(const Eigen::VectorXd& p, Evaluation& e) const;
  void jacobian(const Eigen::VectorXd& p, const Evaluation& e, Eigen::MatrixXd& jac) const;

  const Curve& curve_;
  const MomentSystem& sys_;
  double r0_;
  bool fit_ratio_, with_prior_;
  std::uint64_t id_;
  // EMoR: φ = e₀ + E c is linear in c, so H φ = H e₀ + (H E) c and ∂(r H φ − N φ)/∂c = r (H E) − N E. The rows ×
  // levels products are formed once per fit here instead of once per evaluation and Jacobian (rows × dims).
  Eigen::VectorXd h_mean_, n_mean_;  // H e₀, N e₀
  Eigen::MatrixXd h_basis_, n_basis_;  // H E, N E (rows × dims)
  // Other models: H and N stored by their non-zeros when they are sparse. A row of N holds B's few levels in its
  // bin (≈ 4 of 256 on the phone pairs), a row of H the kernel masses of I's levels around them (≈ 20 %); the
  // products H φ, N φ and (r H − N) Jᵀ, most of a GGCM evaluation, then cost their non-zeros instead of
  // rows × levels. Dense when a level operator (crfcal/noise_debias.hpp) has filled H.
  using SparseRows = Eigen::SparseMatrix<double, Eigen::RowMajor>;
  bool sparse_ = false;
  SparseRows h_sparse_, n_sparse_;
};

// Continuously-updated GMM (CUE): residual_k = S_k / √V_k(φ, r), S_k = (r Ĥ_k − N_k)·φ the bin sum and
// V_k = r² Σ_v q_k(v) Var[g(I) | v] + Σ_v N_k(v) φ'(x_v)² Δ²/12 its model variance (I's noise through the
// transition matrix T, plus the quantisation of B and I). The noise part of E[S_k²/V_k] is 1 whatever φ is, so the
// squared noise no longer pulls φ (the errors-in-variables bias of squared sums), and the ratio is invariant to
// the scale of φ (no φ → 0 degeneracy).
struct CueModel {
  const Eigen::MatrixXd* t = nullptr;  // transition matrix (null: no noise of I)
  const Eigen::MatrixXd* r = nullptr;  // debias operator (null: g = φ)
};
bool cueResiduals(const MomentSystem& sys, const CueModel& cue, const std::vector<double>& f, double r,
                  Eigen::VectorXd& res);

}  // namespace crfcal::crf_fit
