// Model 6 as a candidate final model (pipeline/model6_stage.h).
#include "pipeline/model6_stage.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "core/error.h"
#include "diagnosis/diagnosis.h"
#include "fitting/model6_calibration.h"

#include "pipeline/pipeline.h"
#include "pipeline/wiring.h"

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

namespace {

// The accepted trials only: a rejected trial may have no force to predict.
std::vector<fitting::TrialData> accepted_data(const std::vector<fitting::TrialData>& all) {
  std::vector<fitting::TrialData> data;
  for (const auto& d : all)
    if (d.accepted) data.push_back(d);
  return data;
}

// Bit for bit (NaN equal to NaN): the early fit is taken only on the very
// numbers the fit after the loop would see.
bool same_bits(double a, double b) { return std::memcmp(&a, &b, sizeof a) == 0; }
bool same_bits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  return a.size() == b.size() &&
         (a.size() == 0 || std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<std::size_t>(a.size())) == 0);
}
bool same_trial(const fitting::TrialData& a, const fitting::TrialData& b) {
  return a.id == b.id && a.accepted == b.accepted && same_bits(a.impact_velocity_m_s, b.impact_velocity_m_s) &&
         same_bits(a.impactor_mass_kg, b.impactor_mass_kg) && same_bits(a.gravity_m_s2, b.gravity_m_s2) &&
         same_bits(a.t_s, b.t_s) && same_bits(a.grf_n, b.grf_n) && same_bits(a.impactor_m, b.impactor_m) &&
         same_bits(a.surface_m, b.surface_m) && same_bits(a.force_noise_n, b.force_noise_n) &&
         same_bits(a.marker_noise_m, b.marker_noise_m) && same_bits(a.impact_velocity_se_m_s, b.impact_velocity_se_m_s) &&
         same_bits(a.contact_time_se_s, b.contact_time_se_s) &&
         same_bits(a.velocity_contact_time_cov, b.velocity_contact_time_cov) &&
         same_bits(a.travel_reference_se_m, b.travel_reference_se_m) &&
         same_bits(a.calibration_scale_sd, b.calibration_scale_sd);
}

}  // namespace

EarlyModel6::~EarlyModel6() { stop(); }

void EarlyModel6::stop() {
  cancel_ = true;
  if (thread_.joinable()) thread_.join();
}

void EarlyModel6::start(std::vector<fitting::TrialData> data, fitting::Model6FitOptions options) {
  stop();
  cancel_ = false;
  fit_.reset();
  error_.clear();
  data_ = std::move(data);
  options_ = std::move(options);
  options_.cancel = &cancel_;
  thread_ = std::thread([this] {
    try {
      fit_ = fitting::fit_model6(data_, options_);
    } catch (const std::exception& e) {
      error_ = e.what();
      if (error_.empty()) error_ = "fit_model6 failed";
    }
  });
}

std::optional<fitting::Model6FitResult> EarlyModel6::take(const std::vector<fitting::TrialData>& data,
                                                          const fitting::Model6FitOptions& options) {
  const bool same = started() && options.train_ids == options_.train_ids && data.size() == data_.size() &&
                    std::equal(data.begin(), data.end(), data_.begin(), same_trial);
  if (!same) {
    stop();
    return std::nullopt;
  }
  thread_.join();
  if (!error_.empty()) throw Error(error_);
  return std::move(fit_);
}

std::vector<std::string> model6_train_ids(const std::vector<fitting::TrialData>& accepted,
                                          const std::vector<std::string>& rival_train_ids) {
  const fitting::TrialData* deepest = fitting::deepest_trial(accepted);
  if (!deepest) return {};
  int both_hold_out = 0;
  for (const auto& t : accepted)
    if (t.id != deepest->id && std::find(rival_train_ids.begin(), rival_train_ids.end(), t.id) == rival_train_ids.end())
      ++both_hold_out;
  return both_hold_out >= kModel6MinPairedTrials ? std::vector<std::string>{deepest->id} : rival_train_ids;
}

void start_model6_early(const SessionState& state, EarlyModel6& early, const fitting::FitResult& current,
                        double force_sd, double impactor_sd, const diagnosis::PlateCorrection& correction) {
  if (early.started() || !(std::max(force_sd, impactor_sd) > kEarlyModel6NoiseSd)) return;
  fitting::Model6FitOptions options = model6_options(state.session.manifest);
  std::vector<fitting::TrialData> data = accepted_data(corrected_fit_data(state, correction));
  options.train_ids = model6_train_ids(data, current.train_ids);
  early.start(std::move(data), std::move(options));
}

namespace {

// Every elastic stress of both foams times `scale` (the plateau, modulus,
// hardening and densification stresses; the memory's g_i are shares of the
// elastic stress and follow it; the viscosity, a damping, does not): the
// same column made uniformly softer or stiffer.
fitting::Model6Params scaled_foams(fitting::Model6Params p, double scale) {
  for (fitting::FoamLaw* law : {&p.top, &p.base}) {
    law->plateau_pa *= scale, law->modulus_pa *= scale;
    law->hardening_pa *= scale, law->densification_pa *= scale;
  }
  return p;
}

// See consider_model6 (model6_stage.h): the change between trials judged
// again on Model 6's fit in `m6`, before it is judged against the lumped
// model.
void judge_changing_mat(SessionState& state, Model6Stage& m6) {
  if (!state.loop || !m6.fit) return;
  if (state.loop->find("mat_change_between_trials")) return;
  fitting::Model6FitResult& fit = *m6.fit;
  if (fit.train_ids.size() != 1) return;
  const fitting::Model6Params params = fit.params;
  const fitting::Model6Geometry geometry = m6.options.geometry;
  // The mismatch: measured less simulated largest face travel, which falls
  // as the column stiffens (its peak force does not always rise: a column
  // much softer bottoms out in densification and peaks higher again).
  const diagnosis::ScaleMismatch mismatch = [&](const fitting::TrialData& d, double scale) {
    const double nan = std::numeric_limits<double>::quiet_NaN();
    double measured = -1.0;
    for (Eigen::Index i = 0; i < d.impactor_m.size(); ++i)
      if (std::isfinite(d.impactor_m[i])) measured = std::max(measured, d.impactor_m[i]);
    if (!(measured > 0.0)) return nan;
    fitting::Impact imp;
    imp.mass_kg = d.impactor_mass_kg;
    imp.velocity_m_s = d.impact_velocity_m_s;
    imp.gravity_m_s2 = d.gravity_m_s2;
    // To past the deepest point (30-60 ms after contact on a landing mat)
    // on the column's own largest step: 0.1 s.
    imp.output_dt_s = geometry.max_step_s;
    imp.duration_s = 0.1;
    try {
      const fitting::Simulation sim = fitting::simulate_model6(scaled_foams(params, scale), geometry, imp);
      return sim.impactor_m.size() > 0 ? measured - sim.impactor_m.maxCoeff() : nan;
    } catch (const std::exception&) {
      return nan;
    }
  };
  // In recording order, as the loop's own test on the lumped model; that
  // one reads the lumped model's misfit with speed, which on a foam is far
  // larger than a few per cent of stiffness per trial.
  diagnosis::OrderStageOptions oo;
  oo.min_scale = 0.5, oo.max_scale = 2.0;
  oo.bisection_steps = 14;  // the scale to 0.01 %, against the regression's 0.3 % floor
  const diagnosis::OrderDiagnosis od = diagnosis::diagnose_order(state.fit_data, mismatch, oo);
  if (!od.changed) {
    for (const auto& r : od.rejected)
      state.loop->notes.push_back("between trials, judged again on Model 6 (the foam column): " + r.reason);
    for (const auto& n : od.notes) state.loop->notes.push_back(n + " (on Model 6, the foam column)");
    return;
  }
  auto& rejected = state.loop->rejected;
  std::erase_if(rejected, [](const diagnosis::Rejected& r) { return r.name == "mat_change_between_trials"; });
  for (diagnosis::Effect e : od.effects) {
    e.evidence = "judged on Model 6 (the foam column; the lumped model's misfit with speed hid it): " + e.evidence;
    state.loop->effects.push_back(std::move(e));
  }
  state.loop->trial_stiffness_scale.clear();
  for (std::size_t i = 0; i < od.ids.size(); ++i) state.loop->trial_stiffness_scale.emplace_back(od.ids[i], od.trend_scale[i]);
  // Each held-out trial predicted with the training trial's column times
  // the stiffness scale the recording-order trend fitted without it gives.
  auto scale_of = [&](const std::string& id, const std::vector<double>& scales) {
    for (std::size_t i = 0; i < od.ids.size(); ++i)
      if (od.ids[i] == id) return scales[i];
    return std::numeric_limits<double>::quiet_NaN();
  };
  const double train_own = scale_of(fit.train_ids.front(), od.stiffness_scale);
  const std::string warning = predict_with_stiffness_scales(
      fit.trials, state.fit_data, fit.train_ids.front(),
      [&](const std::string& id) { return scale_of(id, od.trend_scale); },
      [&](const fitting::TrialData& d, double s) {
        fitting::TrialReport rep = fitting::predict_model6(d, scaled_foams(params, s), m6.options);
        // The trial's clock offset is its own measurement: its contact is
        // placed by the column at the trial's own scale (the one that
        // matches its travel), not the trend's prediction.
        const double own = scale_of(d.id, od.stiffness_scale) / train_own;
        if (std::isfinite(own)) {
          const fitting::TrialReport at_own = fitting::predict_model6(d, scaled_foams(params, own), m6.options);
          rep.contact_shift_s = at_own.contact_shift_s;
          rep.contact_shift_se_s = at_own.contact_shift_se_s;
        }
        return rep;
      },
      "every foam stress", state.notes);
  if (!warning.empty()) fit.warnings.push_back(warning);
}

}  // namespace

void consider_model6(SessionState& state, EarlyModel6* early) {
  state.model6.reset();
  if (!final_model_short_of_noise(state)) return;
  Model6Stage stage;
  const fitting::FitResult& rival = *state.final_fit();
  stage.rival = state.final_label();
  stage.options = model6_options(state.session.manifest);
  const std::vector<fitting::TrialData> data = accepted_data(state.fit_data);
  stage.options.train_ids = model6_train_ids(data, rival.train_ids);
  try {
    std::optional<fitting::Model6FitResult> fit;
    if (early) fit = early->take(data, stage.options);
    stage.fit = fit ? std::move(*fit) : fitting::fit_model6(data, stage.options);
    stage.fitted = true;
  } catch (const std::exception& e) {
    stage.reason = fmt::format("Model 6 (the foam column) fit failed: {}; {} stays the final model", e.what(),
                               stage.rival);
    state.notes.push_back(stage.reason);
    state.model6 = std::move(stage);
    return;
  }
  judge_changing_mat(state, stage);
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
      "fitted on {} ({:.2f} s): {}{}",
      stage.rival, fmt::join(stage.fit->train_ids, ", "), stage.fit->seconds, stage.choice->evidence,
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

// The sync verdict on the offsets Model 6's contacts give (`results`: the
// trials with those offsets and their SEs as fitted, before any
// calibration; rms_se_s: the RMS of the fitted contacts' SEs).
void judge_model6_offsets(SessionState& state, const std::vector<trial::TrialResult>& results, double rms_se_s) {
  const Model6Stage& m6 = *state.model6;
  // The column carries the plate's delay behind the face, so no onset lag
  // is allowed for. Each offset's SE counts Model 6's misfit of that trial as noise
  // (fitting::predict_model6); short of the noise, their RMS widens the
  // verdict's systematic uncertainty.
  diagnosis::SyncStageOptions so;
  so.onset_lag_s = 0.0;
  const double widen_s = m6.reaches_noise ? 0.0 : rms_se_s;
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

// The reported per-trial offset SEs calibrated (fitting/model6_calibration.h):
// each SE times the Birge ratio of the session's offsets about their
// weighted mean (one clock offset per session: a scatter beyond the SEs
// shows them too small), in quadrature with Model 6's common timing
// discrepancy (a bias every trial shares). Applied after the sync verdict,
// which weighs the model's misfit through its own systematic term.
void calibrate_offset_ses(SessionState& state, double common_s) {
  std::vector<trial::TrialResult*> rs;
  std::vector<double> offsets, ses;
  for (auto& t : state.trials) {
    trial::TrialResult& r = t.result;
    if (!r.accepted || !std::isfinite(r.video_offset_s) || !std::isfinite(r.video_offset_se_s)) continue;
    rs.push_back(&r);
    offsets.push_back(r.video_offset_s);
    ses.push_back(r.video_offset_se_s);
  }
  const std::vector<double> out = fitting::calibrated_offset_ses(offsets, ses, common_s);
  for (std::size_t i = 0; i < rs.size(); ++i) rs[i]->video_offset_se_s = out[i];
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
  if (state.loop) judge_model6_offsets(state, results, std::sqrt(ss_se / std::max(n, 1)));
  calibrate_offset_ses(state, m6.fit->timing_discrepancy_s);
}

}  // namespace dropfit::pipeline
