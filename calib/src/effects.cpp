#include "crfcal/effects.hpp"

// The public face of the effect diagnostics: names, options, the report. The search itself is
// effect_search.cpp (diagnoseEffects) over the shared problem of effect_problem.hpp, one file per effect test.
#include <cstdio>
#include <sstream>

#include "crfcal/error.hpp"

namespace crfcal {

const std::vector<std::string>& effectNames() {
  static const std::vector<std::string> names{"exposure_ratio_mismatch", "channel_mixing",  "signal_dependent_noise",
                                              "clipping",                "vignetting",      "spatially_varying_blur",
                                              "black_level_offset"};
  return names;
}

void EffectOptions::check() const {
  if (!(min_gain >= 0 && min_gain < 1)) throw InvalidInput("effect options: min_gain must be in [0, 1)");
  if (!(min_z >= 0)) throw InvalidInput("effect options: min_z must be >= 0");
  if (!(min_noise_contrast >= 1)) throw InvalidInput("effect options: min_noise_contrast must be >= 1");
  if (noise_bins < 2 || noise_bins > 32) throw InvalidInput("effect options: noise_bins must be in 2..32");
  if (!(ratio_tolerance >= 0)) throw InvalidInput("effect options: ratio_tolerance must be >= 0");
  if (block < 8) throw InvalidInput("effect options: block must be >= 8");
  if (max_samples < 1000) throw InvalidInput("effect options: max_samples must be >= 1000");
  if (grid < 0 || grid > 6) throw InvalidInput("effect options: grid must be in 0..6");
  if (!(min_derivative > 0)) throw InvalidInput("effect options: min_derivative must be > 0");
  if (phi_terms < 0 || phi_terms > 10) throw InvalidInput("effect options: phi_terms must be in 0..10");
  if (refit_rounds < 1 || refit_rounds > 10) throw InvalidInput("effect options: refit_rounds must be in 1..10");
}

std::vector<std::string> EffectReport::detected() const {
  std::vector<std::string> out;
  for (const auto& e : entries)
    if (e.detected) out.push_back(e.name);
  return out;
}

const EffectEntry* EffectReport::find(const std::string& name) const {
  for (const auto& e : entries)
    if (e.name == name) return &e;
  return nullptr;
}

std::string EffectReport::summary() const {
  std::ostringstream s;
  s << "effects (" << samples << " samples/channel, " << seconds << " s):";
  for (const auto& e : entries) {
    char buffer[600];
    if (!e.tested)
      std::snprintf(buffer, sizeof buffer, "\n  %-24s not tested (%s)", e.name.c_str(), e.detail.c_str());
    else {
      const auto phi = e.parameters.find("phi_change");
      char change[64] = "";
      if (phi != e.parameters.end()) std::snprintf(change, sizeof change, "  dphi %.4f", phi->second);
      std::snprintf(buffer, sizeof buffer, "\n  %-24s %s  gain %.4f (>= %.3f)  z %.2f (>= %.1f)%s  %s", e.name.c_str(),
                    e.detected ? "DETECTED" : "no      ", e.gain, e.gain_threshold, e.statistic, e.threshold, change,
                    e.detail.c_str());
    }
    s << buffer;
    if (e.detected && !e.runner_up.empty()) {
      std::snprintf(buffer, sizeof buffer, "\n  %-24s   against the runner-up %s (its gain %.4f): held-out drop %.4f, z %.2f",
                    "", e.runner_up.c_str(), e.runner_up_gain, e.evidence_gain, e.evidence_z);
      s << buffer;
    }
  }
  // The base fit's φ under the extended model (guard test 3; 0 when not compared: an earlier test rejected the refit).
  char same_model[120] = "";
  if (heldout_error_base_fit_selected_model > 0)
    std::snprintf(same_model, sizeof same_model, ", %.3g with the base fit's phi under the extended model",
                  heldout_error_base_fit_selected_model);
  if (refit_adopted) {
    char buffer[200];
    std::snprintf(buffer, sizeof buffer,
                  "\n  phi refitted with the extended model (held-out error %.3g vs the base fit's %.3g",
                  heldout_error_refit, heldout_error_base_fit);
    s << buffer << same_model << ")";
  } else if (refit_failed) {
    s << "\n  refit with the extended model failed, the base fit's phi kept: " << refit_rejected_reason;
  } else if (refit_tried) {
    char buffer[200];
    std::snprintf(buffer, sizeof buffer, " (held-out error of the refit %.3g, of the base fit %.3g",
                  heldout_error_refit, heldout_error_base_fit);
    s << "\n  refit with the extended model rejected, the base fit's phi kept: " << refit_rejected_reason << buffer
      << same_model << ")";
  }
  return s.str();
}

}  // namespace crfcal
