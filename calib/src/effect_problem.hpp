#pragma once
// Internal to the effect diagnostics (crfcal/effects.hpp describes the models, the folds and the criterion).
// What every effect test works on:
//   - the residual samples of the seed's model B = ψ(r · (φ(I) ⊗ K)) (Eq. 4) in the irradiance domain, per channel
//     (Samples, collected by collect() from the Prepared pair and the current φ);
//   - the two held-out folds (Layout) and the blocks of the design effect;
//   - the linear residual model with φ re-fitted along the EMoR basis (Problem: fit, held-out evaluation, warm
//     starts of nested models) and the tests of a held-out drop (scoreTest, compare);
//   - the search's shared state (EffectSearch) and the correction + refit of the pair (refitPair, effect_refit.cpp).
// An effect is one file effect_<name>.cpp: a LevelEffect (a term of the residual model, tested by the search in
// effect_search.cpp) or a ModelCheck (its own model and statistic, run around the selected model). To add one:
// write the file, add its line to levelEffects() or modelChecks() (effect_search.cpp) and its name to
// effectNames() (effects.cpp, the report's order). A LevelEffect with new columns also adds them to Problem::row,
// Problem::expand and coefficients() (the column layout below).
#include <array>
#include <cstddef>
#include <map>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "crfcal/effects.hpp"
#include "crfcal/noise_debias.hpp"
#include "crfcal/response_curve.hpp"
#include "effect_grouped_residuals.hpp"
#include "image_units.hpp"

namespace crfcal::effect {

// ---- small helpers ------------------------------------------------------------------------------------------------

// Pixel units and mask dilation: one home for the whole calibration (image_units.hpp).
using detail::dilateBy;
using detail::fullScale;
using detail::unit;

// Back to the input's storage (so that the refit sees the same level grid as the base fit).
cv::Mat store(const cv::Mat& unit_image, int depth);

std::string fmt(const char* format, double a, double b = 0, double c = 0);

// ---- φ on the 1024-grid --------------------------------------------------------------------------------------------

struct Curve {
  ResponseCurve curve;
  std::vector<double> phi;  // 1024 samples
  double derivative(double b) const;
};

// A tabulated φ made valid (φ(0) = 0, φ(1) = 1, non-decreasing): fits can carry rounding-level dips at the ends.
Curve makeCurve(std::vector<double> phi);

// φ̂ + Σ α_k h_k on the 1024-grid, made a valid inverse response (φ(0) = 0, φ(1) = 1, non-decreasing).
std::vector<double> adjustedPhi(const std::vector<double>& phi, const std::vector<double>& alpha);

// A table over [0, 1] applied to a unit CV_64F image (linear interpolation).
cv::Mat applyTable(const cv::Mat& image, const std::vector<double>& table);

// f on the 1024-grid resampled to `levels` values f(v / (levels − 1)).
std::vector<double> onLevels(std::span<const double> f, int levels);

// ---- folds ---------------------------------------------------------------------------------------------------------

// Folds: grid × grid tiles over the window, each split in two halves along its longer side.
struct Layout {
  int grid = 2;
  std::vector<cv::Rect> tiles;
  std::vector<std::array<cv::Rect, 2>> halves;
  cv::Mat tile_map, half_map;  // CV_32S tile index, CV_8U half index
  int fold(int tile, int half) const {
    const int tx = tile % grid, ty = tile / grid;
    return half ^ ((tx + ty) & 1);
  }
  int foldAt(int x, int y) const { return fold(tile_map.at<int>(y, x), half_map.at<uchar>(y, x)); }
};

Layout makeLayout(cv::Size size, int grid);

// ---- the residual samples ------------------------------------------------------------------------------------------

// Residual samples of one channel.
struct Samples {
  std::vector<int> block, fine, fold;  // 32×32 block, 16×16 block, fold
  std::vector<double> d;      // φ̂'(B): irradiance → intensity scale of the residual
  std::vector<std::vector<double>> Dh;  // h_k'(B): the slope of the φ re-fit (the scale follows φ, see weight())
  std::vector<std::vector<double>> Hb;  // h_k(B)
  std::vector<double> phi;              // φ̂ on the 1024-grid (the clip level's irradiance)
  std::vector<double> Y;      // φ(B)
  std::vector<double> rho2;   // (r / R)²
  std::vector<double> level;  // B intensity
  std::vector<std::vector<double>> X;  // per channel index: a-free prediction φ_d(I_d) ⊗ K
  std::vector<std::vector<double>> P;  // φ columns a₀ K⊗h_k(I) − h_k(B) (EMoR basis h_k)
  std::vector<std::vector<double>> KH; // K⊗h_k(I): how this channel's X moves with its φ re-fit (mixing)
  std::vector<cv::Point> pos;
  // Samples with the same φ̂'(B) and h_k'(B) (the same level of B) share the LM's weight: their group (groupByWeight;
  // empty: each sample alone), and the number of groups.
  std::vector<int> weight_group;
  int weight_groups = 0;
  std::size_t size() const { return Y.size(); }
};

// No samples yet, of one channel among `channels`, with `phi_terms` φ columns, around φ̂ (`phi`, the 1024-grid).
Samples emptySamples(int channels, int phi_terms, std::vector<double> phi);

// Fills s.weight_group / s.weight_groups from d and Dh (exact equality); collect() calls it.
void groupByWeight(Samples& s);

// The pair in unit levels, with what the residuals need beside φ.
struct Prepared {
  std::vector<cv::Mat> I, B;        // unit CV_64F per channel (original)
  std::vector<int> depth;
  std::vector<int> levels;          // level grid of I (256 for 8-bit data, else 1024)
  std::vector<bool> noisy;          // per channel: I's noise above a quarter level (its black and white read by region)
  std::vector<NoiseDebias> debias;  // per channel (identity unless the fit debiases and I is noisy)
  cv::Mat usable;                   // CV_8U
  cv::Mat rho2;                     // CV_64F
  // Per channel and EMoR term k = 1…phi_terms: K ⊗ h_k(I) (debiased as `debias` says) and h_k(B). They do not
  // depend on φ or r, so they are formed once per search, not at every re-collection around a new φ.
  std::vector<std::vector<cv::Mat>> blurred_basis, basis_at_B;
};

// K ⊗ g(I) of channel c for a function f on the 1024-grid: f on I's levels, debiased (p.debias), looked up, blurred.
cv::Mat blurredLevelFunction(const Prepared& p, int c, std::span<const double> f, const cv::Mat& K);

// Fills p.blurred_basis and p.basis_at_B for the first `phi_terms` EMoR terms.
void blurBasis(Prepared& p, const cv::Mat& K, int phi_terms);

// The samples of every channel around the given φ (curves) and exposure ratios; I's level functions debiased as
// p.debias says (only when the base fit debiases).
std::vector<Samples> collect(const Prepared& p, const std::vector<Curve>& curves, const std::vector<double>& ratios,
                             const cv::Mat& K, const Layout& layout, const EffectOptions& options);

// ---- the residual model --------------------------------------------------------------------------------------------

// Which terms the model has. Column layout: [scale][v1 v2][offset][mix…][φ terms].
struct Spec {
  bool vignetting = false, offset = false, mixing = false, clipping = false;
  bool fixed_scale = false;
  double scale = 1;
};

// The order in which to start the fits of these models, `jobs_per_model` jobs each (model i's are i·jobs_per_model
// onwards), the dearest first so that no long fit starts last (parallel_jobs.hpp): a plateau level grid (clipping, a
// dozen levels per channel and part), then the coupled channels of mixing (three alternations), then the rest, each
// group in the models' order.
std::vector<int> dearestFitsFirst(const std::vector<Spec>& models, int jobs_per_model);

struct ChannelFit {
  Eigen::VectorXd theta;       // coefficients of the columns
  double clip = 0;             // clipping level (irradiance); 0: none
  bool ok = false;
};

struct Evaluation {
  std::vector<double> block_error;  // held-out Σ e² per block (all channels)
  std::vector<double> fine_error;   // the same per half-size block
  std::vector<std::vector<double>> residual;  // held-out e per channel and sample (0 where no fold fit)
  double total = 0;
  long count = 0;
  std::vector<ChannelFit> full;     // fitted on all samples (parameters for reporting/correction)
  std::array<std::vector<ChannelFit>, 2> folds;  // fitted on each fold (warm starts of nested models)
  Spec spec;
};

// One part of an evaluation: the channels' fits on one fold (0, 1) or on all samples, with the other channels' X_d
// they were coupled to (mixing).
struct PartFit {
  std::vector<ChannelFit> fits;
  std::vector<std::vector<double>> xs;
};

class Problem {
 public:
  // The LM's stop: a pass that lowers the cost by less than this fraction (every fit that is reported or tested),
  // or kFitPasses passes.
  static constexpr double kFitTolerance = 1e-9;
  static constexpr int kFitPasses = 40;
  // Where a paused Levenberg–Marquardt stands (a tolerance above kFitTolerance), to run it on later.
  struct LmState {
    double mu = 1e-3;        // damping
    int iteration = 0;       // passes made
    bool finished = true;    // stopped for good (kFitTolerance, kFitPasses, no improving step): nothing to run on
  };
  // The plateau grid's levels are compared on LM runs paused here (bestPlateau); the chosen one runs on to
  // kFitTolerance.
  static constexpr double kPlateauSelectionTolerance = 1e-6;
  Problem() = default;
  Problem(std::vector<Samples> samples, int blocks, int fine_blocks, double min_derivative)
      : s_(std::move(samples)), blocks_(blocks), fine_blocks_(fine_blocks), min_derivative_(min_derivative) {}
  std::vector<Samples>& samples() { return s_; }
  const std::vector<Samples>& samples() const { return s_; }

  // Columns of the linear part. Column 0 is the scale column unless the scale is fixed.
  int row(const Samples& s, std::size_t i, const Spec& spec, double* out, double& target) const {
    const double x = s.X[self(s)][i];
    int k = 0;
    target = s.Y[i];
    if (spec.fixed_scale) target -= spec.scale * x;
    else out[k++] = x;
    if (spec.vignetting) {
      out[k++] = x * s.rho2[i];
      out[k++] = x * s.rho2[i] * s.rho2[i];
    }
    if (spec.offset) out[k++] = 1.0;
    if (spec.mixing)  // Ŷ_c = a X_c + Σ_{d≠c} m_cd (X_d − X_c): a = the row sum, the exposure ratio of a grey
      for (int d = 0; d < static_cast<int>(s.X.size()); ++d)
        if (d != self(s)) out[k++] = (coupled_ ? (*coupled_)[d][i] : s.X[d][i]) - x;
    for (const auto& column : s.P) out[k++] = column[i];  // φ re-fitted with every model (nested, fair)
    return k;
  }

  // 1 / φ'(B) of the re-fitted φ = φ̂ + Σ α_k h_k (α: the last coefficients): the residual stays in intensity units
  // whatever the re-fit does to φ's scale (else shrinking φ over the data's range would "explain" everything).
  double weight(const Samples& s, std::size_t i, const Eigen::VectorXd* theta) const {
    double d = s.d[i];
    if (theta && !s.Dh.empty()) {
      const Eigen::Index first = theta->size() - static_cast<Eigen::Index>(s.Dh.size());
      for (std::size_t k = 0; k < s.Dh.size(); ++k) d += (*theta)(first + static_cast<Eigen::Index>(k)) * s.Dh[k][i];
    }
    return 1.0 / std::max(d, min_derivative_);
  }

  // The design rows (row()) and targets of some samples, formed once where several fits read them (the plateau
  // grid of fit()): the same values row() gives, so the fits are the same to the bit.
  struct DesignRows {
    int cols = 0;
    std::vector<double> values, target;  // rows × cols, rows
    std::vector<int> position;           // sample index → row (−1: not formed)
    const double* at(std::size_t i) const { return values.data() + static_cast<std::size_t>(position[i]) * cols; }
    double targetAt(std::size_t i) const { return target[static_cast<std::size_t>(position[i])]; }
  };
  DesignRows designRows(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx) const;

  // Least squares of the intensity-scaled residuals on the samples `idx`, B's plateau at `clip` censored.
  // `rows`: the samples' design rows already formed (null: formed here).
  // `tolerance`: the LM stops when a pass lowers the cost by less than this fraction.
  // `state`: where a paused run stands (in), where this one stopped (out); `start` then is the paused θ.
  // `all_groups`: the samples `idx` grouped and factorised already (groupedResiduals; the plateau grid's levels share
  // them); the groups below `clip` are taken from it, the same to the bit as grouping the level's samples anew.
  ChannelFit fitLevel(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx, double clip,
                      const Eigen::VectorXd* start = nullptr, const DesignRows* rows = nullptr,
                      double tolerance = kFitTolerance, LmState* state = nullptr,
                      const GroupedResiduals* all_groups = nullptr) const;
  // One channel on one fold (−1: all samples); clipping: the plateau level chosen on a grid of B's quantiles.
  ChannelFit fit(const Samples& s, const Spec& spec, int fold, const Eigen::VectorXd* start = nullptr) const;
  // Residual φ(B) − Ŷ in intensity units (clipping: two-sided against the plateau).
  double residual(const Samples& s, std::size_t i, const Spec& spec, const ChannelFit& f) const;
  // The same from the sample's design row `x` (cols entries) and target t.
  double residualOfRow(const Samples& s, std::size_t i, const ChannelFit& f, const double* x, int cols,
                       double t) const;
  // Fits of every channel on one fold (−1: all samples), coupled through X_d with mixing.
  std::vector<ChannelFit> fitAll(const Spec& spec, int fold, std::vector<std::vector<double>>& xs,
                                 const std::vector<Eigen::VectorXd>& starts) const;
  // Held-out errors of `spec` (both folds) and its fit on all samples; `warm`: a nested smaller model's evaluation.
  Evaluation evaluate(const Spec& spec, bool heldout = true, const Evaluation* warm = nullptr) const;
  // evaluate() in parts, for callers that run the parts in parallel: the fits on `fold` (−1: all samples) started
  // from `warm`'s fits of that part, and the evaluation assembled from them (folds used only when heldout).
  PartFit fitPart(const Spec& spec, int fold, const Evaluation* warm) const;
  Evaluation assemble(const Spec& spec, bool heldout, const std::array<PartFit, 2>& folds, PartFit full) const;
  // A nested model's θ mapped into a larger one's column layout.
  Eigen::VectorXd expand(const Spec& from, const Eigen::VectorXd& t, const Spec& to, int nc, int terms) const;
  std::vector<Eigen::VectorXd> warmStarts(const Evaluation* warm, int fold, const Spec& spec) const;

  int self(const Samples& s) const { return static_cast<int>(&s - s_.data()); }

 private:
  // The weighted linear solution without the φ terms (weights of φ̂): the start of the Levenberg–Marquardt.
  Eigen::VectorXd linearStart(const Samples& s, const Spec& spec, const std::vector<std::size_t>& use, int cols,
                              const DesignRows* rows) const;
  // The samples `use` by weight group, as the Levenberg–Marquardt reads them.
  GroupedResiduals groupedResiduals(const Samples& s, const Spec& spec, const std::vector<std::size_t>& use, int cols,
                                    const DesignRows* rows) const;
  // `grouped`: the samples `use` grouped already (null: grouped here).
  void levenbergMarquardt(const Samples& s, const Spec& spec, const std::vector<std::size_t>& use,
                          Eigen::VectorXd& theta, const DesignRows* rows, double tolerance, LmState* state,
                          GroupedResiduals* grouped) const;
  // The plateau level of `clips` (B intensity, 2: none) with the lowest in-sample error and its fit.
  ChannelFit bestPlateau(const Samples& s, const Spec& spec, const std::vector<std::size_t>& idx,
                         const std::vector<double>& clips, const Eigen::VectorXd* start,
                         const DesignRows& rows) const;
  void heldoutResiduals(const Spec& spec, const std::array<PartFit, 2>& folds, Evaluation& ev) const;
  // The design row of sample i and its target: from `rows` when formed, else row() into `buffer`.
  const double* designRow(const Samples& s, std::size_t i, const Spec& spec, const DesignRows* rows, double* buffer,
                          double& t) const;

  std::vector<Samples> s_;
  int blocks_ = 0, fine_blocks_ = 0;
  // mixing: the other channels' re-fitted X while fitAll / heldoutResiduals run. Per thread, not per Problem: the
  // candidates of one search step are evaluated in parallel on the same Problem (levelCandidates).
  static thread_local const std::vector<std::vector<double>>* coupled_;
  double min_derivative_ = 0.05;
};

// The clipping model's plateau levels for the samples `idx`: 2 (none, the nested base model) and B's 100, 99.9,
// 99.5, 99, 98, 97, 95, 93, 90, 85 and 80 % quantiles, descending, without repeats.
std::vector<double> plateauGrid(const Samples& s, const std::vector<std::size_t>& idx);

// The fitted coefficients of a spec, by meaning.
struct Coefficients {
  double scale = 1, v1 = 0, v2 = 0, offset = 0;
  std::vector<double> mix;    // per channel index (own = scale)
  std::vector<double> alpha;  // φ re-fit along the EMoR basis
};

Coefficients coefficients(const Spec& spec, const ChannelFit& f, int self, int nc, int terms);

// Whether an extended model's parameters are physical (a runaway fit is not an explanation).
bool physical(const Spec& spec, const Evaluation& ev, int nc, int terms);
// Whether a vignetting's corner gain 1 + v1 + v2 is one `physical` accepts (0.1–10: wider than the refit guard's
// 0.5–2; outside it the linearised fit has run away).
bool physicalCornerGain(double corner);
// Whether a model's free scale can be the camera's exposure ratio: finite and inside the range the fitter itself
// considers (kMinExposureRatio–kMaxExposureRatio, crf_fitter.hpp). The φ terms are linearised at the pair's r
// (P_k = r·K⊗h_k(I) − h_k(B)), so a scale far from r is outside the model's validity (vivo X6S pair 3: 0.0027).
bool fittableExposureRatio(double scale);

// ---- tests of a held-out drop --------------------------------------------------------------------------------------

struct Comparison {
  double gain = 0, z = 0;
};

// Paired one-sided test over blocks: d_b = base_b − ext_b.
Comparison compare(const std::vector<double>& base, const std::vector<double>& ext, double base_total,
                   const std::vector<char>& used);

// The score test of the held-out drop over the `affected` half-size blocks; `gain` returns Σ d (not normalised).
Comparison scoreTest(const std::vector<Samples>& samples, const Evaluation& base, const Evaluation& ext,
                     const std::vector<char>& affected, int blocks);

// ---- the varying kernel (effect_spatially_varying_blur.cpp fits it; the refit uses it per tile) -----------------

// K(p) = K₀ + u K_x + v K_y + c R(u, v) + d(u, v) · ∇K: first order in the position, plus the second-order term of a
// roll spread symmetrically about the centre, R(u, v) = (−v ∂x + u ∂y)² K, and a shift field d linear in (u, v), a
// residual misregistration (K the global kernel, normalised). The base model is K₀ with the shift field.
struct BlurTest {
  bool ok = false;
  std::string problem;
  Comparison cmp;
  double variation = 0;             // (‖K_x‖ + ‖K_y‖) / ‖K₀‖: relative first-order change from the centre to a corner
  cv::Mat K0, Kx, Ky;               // fitted on all samples (unnormalised: the scale carries r)
  double roll = 0;                  // c, fitted with them
  cv::Mat Kxx, Kxy, Kyy;            // the global kernel's second derivatives (R's parts)
  std::array<double, 4> shift{};    // d = ((d₀ u + d₁ v), (d₂ u + d₃ v)), fitted with them
  cv::Mat Kdx, Kdy;                 // the global kernel's first derivatives (the shift field's parts)
  double heldout_error = 0;         // Σe² / n of the varying kernel on the held-back rows
};

// The varying kernel at a point (u, v relative to the centre, over the half-diagonal), non-negative, normalised.
cv::Mat kernelAt(const BlurTest& bt, double u, double v);

// ---- the search's shared state -------------------------------------------------------------------------------------

struct EffectSearch {
  EffectSearch(const EffectInputs& inputs, const EffectOptions& effect_options);

  const EffectInputs& in;
  const EffectOptions& options;
  EffectReport report;              // one entry per effectNames()

  // The pair (prepareProblem, effect_problem.cpp).
  int nc = 0, terms = 0;
  cv::Mat K;                        // the normalised global kernel
  Prepared p;
  cv::Size size;
  cv::Point2d centre;               // optical centre, window coordinates
  double radius = 1;                // normalising radius of ρ
  Layout layout;
  int blocks = 0, fine_blocks = 0;  // 32×32 and 16×16 blocks of the window
  int g_index = 0;                  // the channel reported (G, else the first)

  // The model around which effects are tested (the search moves it).
  std::vector<Curve> curves;        // φ per channel
  std::vector<double> ratios;       // r per channel
  Problem problem;                  // residuals around curves / ratios
  std::vector<char> used_fine;      // half-size blocks holding samples
  Spec current;                     // the selected model
  Evaluation current_eval;
  std::vector<std::string> selected;
  std::vector<Coefficients> coef;   // the selected model's parameters (describeSelectedModel)
  // Why a level effect's model was not considered at the last forward step (not physical; bestCandidate), added
  // to its entry after the selected model's description.
  std::map<std::string, std::string> not_considered;
  // B within this margin of saturation_high is treated as saturated (intensity, worst channel; usablePixels).
  double full_scale_margin = 0;

  // What the model checks measured, for the final refit.
  BlurTest blur;
  std::vector<std::vector<double>> noise_level, noise_sigma;  // per channel: σ(v) bins of I (noise test)
  bool noise_detected = false;
  // exposure_ratio_mismatch's attribution: the level effect that explains the misfit with r at EXIF's value, to be
  // named instead of a ratio mismatch (effect_exposure_ratio_mismatch.cpp; empty: none).
  std::string ratio_explained_by;
  // Why the selected model's refit could not be fitted (refitWithSelectedModel; empty: it was, or was not asked
  // for); guardRefit reports it.
  std::string refit_failure;

  EffectEntry& entry(const std::string& name);
  Problem problemAround(const std::vector<Curve>& phi, const std::vector<double>& r) const;
  Spec withSelected(const std::string& except = {}) const;  // the selected effects except `except`
};

// Reads the pair into `search` (units, I's noise, usable pixels, ρ², folds). False: too few usable pixels.
bool prepareProblem(EffectSearch& search);

// One correction + refit with the extended model `spec`: the jointly re-fitted φ_ext = φ + Σ α_k h_k and the
// parameters correct the pair, fitInverseCrf refits φ (same options; r fixed when fixed_ratio > 0).
// with_blur: per-tile fits with the first-order kernel; with_noise: σ(v) to the fitter.
struct PairRefit {
  std::map<std::string, CrfFitResult> fits;  // φ per channel; empty when a channel could not be refitted
  std::string failure;                       // why not (the channel and the fitter's message); empty on success
};
PairRefit refitPair(const EffectSearch& search, const Spec& spec, const std::vector<Curve>& cur,
                    const std::vector<Coefficients>& cf, const std::vector<ChannelFit>& ff, bool with_blur,
                    bool with_noise, double fixed_ratio);

// The refit guard (effect_refit_guard.cpp): report.fits (the selected model's refit) is kept only when the refit is
// physically plausible and explains the held-back pixels at least as well as the base fit; else it moves to
// report.rejected_fits with the reason.
void guardRefit(EffectSearch& search);

// ---- the effects ---------------------------------------------------------------------------------------------------

// The pair as the selected model corrects it before the refit (refitPair): each selected LevelEffect corrects it.
struct PairCorrection {
  const EffectSearch& search;
  const std::vector<Curve>& ext;                  // φ_ext per channel (the corrections use it)
  const std::vector<Coefficients>& coefficients;  // per channel
  const std::vector<ChannelFit>& fits;            // per channel
  std::vector<cv::Mat> Y;                         // φ_ext(B) per channel, to be corrected
  std::vector<cv::Mat> sharp;                     // I as stored, per channel
  std::vector<CrfFitOptions> fit_options;         // the refit's options per channel
};

// An effect carried by the residual model: the search adds it when it lowers the held-out error.
struct LevelEffect {
  const char* name;
  Spec (*extend)(Spec spec);                     // the model with this effect
  bool (*in)(const Spec& spec);                  // whether `spec` has it
  const char* (*not_applicable)(const EffectSearch& search);  // why it cannot be tested here; nullptr: testable
  // The statistic: the held-out drop from `without` (lacking it) to `with` (having it).
  Comparison (*test)(const EffectSearch& search, const Evaluation& without, const Evaluation& with);
  bool phi_change_below_plateau;                 // its φ change is measured below the fitted plateau only
  // Its parameters in the entry, from the model `spec` (which has it) evaluated on all samples.
  void (*describe)(const EffectSearch& search, const Spec& spec, const Evaluation& ev, EffectEntry& entry);
  void (*correct)(PairCorrection& pair);         // the pair corrected for it (the model has it)
};

// An effect with its own model and statistic, checked around the selected model after the search.
struct ModelCheck {
  const char* name;
  void (*run)(EffectSearch& search);             // fills entry(name)
};

// The statistic most level effects use: the score test over every block holding samples, relative to the
// held-out error without the effect.
Comparison globalHeldoutTest(const EffectSearch& search, const Evaluation& without, const Evaluation& with);

const LevelEffect& vignettingEffect();
const LevelEffect& blackLevelOffsetEffect();
const LevelEffect& clippingEffect();
const LevelEffect& channelMixingEffect();
const ModelCheck& spatiallyVaryingBlurCheck();
const ModelCheck& exposureRatioMismatchCheck();
const ModelCheck& signalDependentNoiseCheck();

// Held-out Σe² / n of the varying kernel (BlurTest) around the given φ and r, φ held as given: (K₀, K_x, K_y, c, d)
// fitted on one fold of the reported channel's samples and measured on the other, both ways, as the check tests it.
// The refit guard compares a spatially varying blur's refitted φ with the base fit's by it (effect_refit_guard.cpp).
// +∞ when the model cannot be fitted.
double varyingKernelHeldoutError(const EffectSearch& search, const std::vector<Curve>& curves,
                                 const std::vector<double>& ratios);

// ---- attribution (effect_attribution.cpp) ---------------------------------------------------------------------------

// One competing explanation of the misfit: a level effect added to a model, judged on the held-back pixels.
struct Candidate {
  std::string name;
  Evaluation eval;         // held-out errors of the model with this effect
  Comparison cmp;          // its own test against the model without it
  bool plausible = false;  // physical parameters (physical()) and a φ re-fit that is not flattened
  bool passes = false;     // plausible and its own test passed (min_gain, min_z)
  std::string flattened;   // the channel whose φ re-fit this model flattened (flattenedChannel); empty: none
};

// The first channel whose φ re-fit under `spec` (the fit on all samples in `ev`) is flat — the verdict's rule
// (flatFraction, channel_verdict.hpp: a local exponent below 0.1 or a rise under a tenth of any real curve's) — over
// at least the verdict's max_flat_fraction more of the samples' levels of B (0.1 % tails dropped) than φ̂ itself;
// empty when none. No real inverse response is nearly constant over data, and a re-fit that flattens φ there
// shrinks the floored residuals (the weights 1/max(φ', min_derivative)) with it: on the real vivo X6S pairs every
// level model's re-fit was flat over 75–100 % of the data where φ̂ was not, and black_level_offset was named at z 53,
// 11 and 6 with a re-fitted φ equal to 0 up to x = 0.5 (docs/RESULTS.md#effects-flat-refit).
std::string flattenedChannel(const EffectSearch& search, const Problem& problem, const Spec& spec,
                             const Evaluation& ev);

// Every applicable level effect not in `base`, added to it and evaluated on `problem` (the search's own, or one
// around another φ on the same samples), with its own test against `base_eval`.
std::vector<Candidate> levelCandidates(const EffectSearch& search, const Problem& problem, const Spec& base,
                                       const Evaluation& base_eval);

// The held-out drop from the runner-up's model to the winner's, on the same held-back pixels (score test; gain
// relative to the runner-up's held-out error): how much better the winner explains what both try to explain.
Comparison headToHead(const EffectSearch& search, const Evaluation& runner_up, const Evaluation& winner);

// The winner's entry gets the runner-up (the other plausible candidate with the smallest held-out error), the
// runner-up's own gain and headToHead() against it.
void recordRunnerUp(EffectSearch& search, const Candidate& winner, const std::vector<Candidate>& candidates);

// The registries (effect_search.cpp), in the order they are tested.
const std::vector<const LevelEffect*>& levelEffects();
const std::vector<const ModelCheck*>& modelChecks();

}  // namespace crfcal::effect
