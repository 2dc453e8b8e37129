// Model 6 as a candidate final model (pipeline/model6_stage.h).
#include "pipeline/model6_stage.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "pipeline/pipeline.h"

namespace dropfit::pipeline {

fitting::Model6FitOptions model6_options(const Manifest& manifest) {
  fitting::Model6FitOptions o;
  const auto& layers = manifest.mat.layers;
  o.geometry.area_m2 = manifest.impactor.footprint_m.x() * manifest.impactor.footprint_m.y();
  if (layers.size() >= 2) {
    double top_t = 0.0, top_m = 0.0;
    for (std::size_t i = 0; i + 1 < layers.size(); ++i) top_t += layers[i].thickness_m, top_m += layers[i].mass_kg;
    o.geometry.top_thickness_m = top_t;
    o.top_mass_kg = top_m;
    o.geometry.base_thickness_m = layers.back().thickness_m;
    o.base_mass_kg = layers.back().mass_kg;
  } else if (layers.size() == 1) {
    // One declared foam: the column is one foam, cut into a top and a base
    // part with the same law's thickness and mass shares.
    o.geometry.top_thickness_m = 0.6 * layers.front().thickness_m;
    o.geometry.base_thickness_m = 0.4 * layers.front().thickness_m;
    o.top_mass_kg = 0.6 * layers.front().mass_kg;
    o.base_mass_kg = 0.4 * layers.front().mass_kg;
  }
  return o;
}

bool final_model_short_of_noise(const SessionState& state) {
  if (!state.loop || !state.final_fit()) return false;
  for (const auto& r : state.loop->remaining)
    if (r.stage == "mat") return true;
  return false;
}

void consider_model6(SessionState& state) {
  state.model6.reset();
  if (!final_model_short_of_noise(state)) return;
  Model6Stage stage;
  const fitting::FitResult& rival = *state.final_fit();
  stage.rival = state.final_label();
  stage.options = model6_options(state.session.manifest);
  stage.options.train_ids = rival.train_ids;
  // The accepted trials only: a rejected trial may have no force to predict.
  std::vector<fitting::TrialData> data;
  for (const auto& d : state.fit_data)
    if (d.accepted) data.push_back(d);
  try {
    stage.fit = fitting::fit_model6(data, stage.options);
    stage.fitted = true;
  } catch (const std::exception& e) {
    stage.reason = fmt::format("Model 6 (the foam column) fit failed: {}; {} stays the final model", e.what(),
                               stage.rival);
    state.notes.push_back(stage.reason);
    state.model6 = std::move(stage);
    return;
  }
  diagnosis::MatStageOptions mo;
  mo.fit = state.baseline_fit_options;
  stage.choice = diagnosis::choose_by_held_out(data, stage.rival, rival.trials, "model6", stage.fit->trials, mo);
  stage.chosen = stage.choice->chosen == "model6";
  stage.heldout_force_sd = stage.choice->force_b_sd;
  stage.heldout_impactor_sd = stage.choice->impactor_b_sd;
  stage.reaches_noise =
      stage.heldout_force_sd <= mo.unexplained_noise_sd && stage.heldout_impactor_sd <= mo.unexplained_noise_sd;
  stage.reason = fmt::format(
      "the final lumped model ({}) leaves the held-out residual above the noise, so Model 6 (the foam column) was "
      "fitted on the same training trial ({:.2f} s): {}{}",
      stage.rival, stage.fit->seconds, stage.choice->evidence,
      stage.chosen ? (stage.reaches_noise ? "; Model 6 is the final model and reaches the noise"
                                          : fmt::format("; Model 6 is the final model but does not reach the noise "
                                                        "either (held-out force {:.2f}, travel {:.2f} noise SDs)",
                                                        stage.heldout_force_sd, stage.heldout_impactor_sd))
                   : "");
  state.notes.push_back(stage.reason);
  // The loop's verdict on the mat: its structure left above the noise is
  // explained when Model 6, chosen, reaches the noise.
  if (stage.chosen) {
    diagnosis::DiagnosisResult& loop = *state.loop;
    if (stage.reaches_noise) {
      std::erase_if(loop.remaining, [](const diagnosis::Remaining& r) { return r.stage == "mat"; });
      loop.unexplained = !loop.remaining.empty();
    }
    loop.notes.push_back("mat: " + stage.reason);
  }
  state.model6 = std::move(stage);
}

namespace {

// The loop's sync entries replaced by `sync` (the stage's effects, rejected
// candidates, remaining structure and notes).
void replace_sync(diagnosis::DiagnosisResult& loop, const diagnosis::SyncDiagnosis& sync) {
  auto is_sync = [](const auto& x) { return x.stage == "sync"; };
  std::erase_if(loop.effects, is_sync);
  std::erase_if(loop.rejected, is_sync);
  std::erase_if(loop.remaining, is_sync);
  std::erase_if(loop.notes, [](const std::string& n) { return n.rfind("sync:", 0) == 0; });
  loop.effects.insert(loop.effects.begin(), sync.effects.begin(), sync.effects.end());
  loop.rejected.insert(loop.rejected.begin(), sync.rejected.begin(), sync.rejected.end());
  loop.remaining.insert(loop.remaining.begin(), sync.remaining.begin(), sync.remaining.end());
  loop.notes.insert(loop.notes.begin(), sync.notes.begin(), sync.notes.end());
}

}  // namespace

void apply_model6_offsets(SessionState& state) {
  if (!state.model6 || !state.model6->chosen || !state.model6->fit) return;
  const Model6Stage& m6 = *state.model6;
  double ss_se = 0.0;
  int n = 0;
  std::vector<trial::TrialResult> results;
  for (auto& t : state.trials) {
    trial::TrialResult& r = t.result;
    results.push_back(r);
    if (!std::isfinite(r.video_offset_s) || !r.accepted) continue;
    for (const auto& rep : m6.fit->trials) {
      if (rep.id != r.id) continue;
      const double onset = std::isfinite(r.video_offset_onset_s) ? r.video_offset_onset_s : r.video_offset_s;
      r.video_offset_onset_s = onset;
      r.video_offset_s = onset - rep.contact_shift_s;
      // The fitted contact's SE and the video contact instant's own.
      r.video_offset_se_s = std::isfinite(r.video_contact_time_se_s)
                                ? std::hypot(rep.contact_shift_se_s, r.video_contact_time_se_s)
                                : rep.contact_shift_se_s;
      if (std::isfinite(rep.contact_shift_se_s)) ss_se += rep.contact_shift_se_s * rep.contact_shift_se_s, ++n;
      results.back() = r;
    }
  }
  if (!state.loop) return;
  // The verdict on the offsets Model 6's contacts give: the column carries
  // the plate's delay behind the face, so no onset lag is allowed for.
  // Each offset's SE counts Model 6's misfit of that trial as noise
  // (fitting::predict_model6); short of the noise, their RMS widens the
  // verdict's systematic uncertainty.
  diagnosis::SyncStageOptions so;
  so.onset_lag_s = 0.0;
  const double widen_s = m6.reaches_noise || n == 0 ? 0.0 : std::sqrt(ss_se / n);
  so.systematic_s = std::hypot(so.systematic_s, widen_s);
  diagnosis::SyncDiagnosis sync = diagnosis::diagnose_sync(results, so);
  sync.notes.push_back(fmt::format(
      "sync: judged on the contact instants Model 6 (the final model) fits{}",
      m6.reaches_noise ? ""
                       : fmt::format("; Model 6 does not reach the noise, so the offsets are model-limited: their SE "
                                     "counts its misfit as noise ({:.2f} ms RMS), which widens the verdict",
                                     1e3 * widen_s)));
  replace_sync(*state.loop, sync);
}

}  // namespace dropfit::pipeline
