// The diagnosis result, its JSON, and the whole-session wiring of the stages
// (see diagnosis.h). The stages themselves live in *_stage.cpp.
#include "diagnosis/diagnosis.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "diagnosis/internal.h"
#include "fitting/force_lowpass.h"

namespace dropfit::diagnosis {
namespace {

nlohmann::ordered_json number(double v) {
  if (!std::isfinite(v)) return nullptr;
  return v;
}

nlohmann::ordered_json error_set(const ErrorSet& e) {
  nlohmann::ordered_json j = nlohmann::ordered_json::object();
  for (const auto& [k, v] : e) j[k] = number(v);
  return j;
}

nlohmann::ordered_json numbers(const std::vector<double>& v) {
  nlohmann::ordered_json j = nlohmann::ordered_json::array();
  for (double x : v) j.push_back(number(x));
  return j;
}

nlohmann::ordered_json residual_map_json(const std::string& model, const ResidualMap& m) {
  nlohmann::ordered_json o;
  o["model"] = model;
  o["form"] = m.form;
  o["proposal"] = m.proposal;
  o["loading_unloading_r2"] = number(m.loading_unloading_r2);
  o["order_slope_sd"] = number(m.order_slope_sd);
  o["order_slope_t"] = number(m.order_slope_t);
  o["axes"] = nlohmann::ordered_json::array();
  for (const auto& a : m.axes)
    o["axes"].push_back({{"name", a.name},
                         {"r2", number(a.r2)},
                         {"centre", numbers(a.centre)},
                         {"mean_sd", numbers(a.mean_sd)},
                         {"count", numbers(a.count)}});
  return o;
}

// The face height (contact face, lab z) per video frame: mean of the base
// markers minus their height above the face; NaN unless all are present.
Eigen::VectorXd face_heights(const reconstruction::Trajectories& traj, const std::vector<int>& base,
                             double base_height_m) {
  Eigen::VectorXd z = Eigen::VectorXd::Constant(traj.n_frames(), kNaN);
  if (base.empty()) return z;
  for (int f = 0; f < traj.n_frames(); ++f) {
    double sum = 0.0;
    bool ok = true;
    for (int p : base) {
      if (p < 0 || 3 * p + 2 >= traj.lab_m.cols()) {
        ok = false;
        break;
      }
      const double v = traj.lab_m(f, 3 * p + 2);
      if (!std::isfinite(v)) {
        ok = false;
        break;
      }
      sum += v;
    }
    if (ok) z(f) = sum / static_cast<double>(base.size()) - base_height_m;
  }
  return z;
}

}  // namespace

const Effect* DiagnosisResult::find(const std::string& name) const {
  for (const auto& e : effects)
    if (e.name == name) return &e;
  return nullptr;
}

std::string DiagnosisResult::report() const {
  std::string s = fmt::format("diagnosis (baseline {}): {} effect(s) added{}\n", baseline_model, effects.size(),
                              unexplained ? "; structured residual remains unexplained" : "");
  auto errors = [](const ErrorSet& e) {
    std::string out;
    for (const auto& [k, v] : e) out += fmt::format("{}{} {:.3g}", out.empty() ? "" : ", ", k, v);
    return out;
  };
  for (const auto& e : effects) {
    s += fmt::format("  + {} / {}: {}\n", e.stage, e.name, e.evidence);
    s += fmt::format("      before: {}\n      after:  {}\n", errors(e.error_before), errors(e.error_after));
  }
  for (const auto& r : remaining) s += fmt::format("  ? {} / {}: {}\n", r.stage, r.name, r.description);
  for (const auto& r : rejected) s += fmt::format("  - {} / {}: {}\n", r.stage, r.name, r.reason);
  for (const auto& n : notes) s += fmt::format("  note: {}\n", n);
  return s;
}

std::string diagnosis_json(const DiagnosisResult& result) {
  nlohmann::ordered_json j;
  j["baseline_model"] = result.baseline_model;
  j["effects"] = nlohmann::ordered_json::array();
  for (const auto& e : result.effects) {
    nlohmann::ordered_json o;
    o["stage"] = e.stage;
    o["name"] = e.name;
    o["evidence"] = e.evidence;
    o["error_before"] = error_set(e.error_before);
    o["error_after"] = error_set(e.error_after);
    o["estimate"] = error_set(e.estimate);
    j["effects"].push_back(o);
  }
  j["unexplained"] = result.unexplained;
  j["remaining"] = nlohmann::ordered_json::array();
  for (const auto& r : result.remaining)
    j["remaining"].push_back({{"stage", r.stage},
                              {"name", r.name},
                              {"description", r.description},
                              {"frequency_hz", std::isfinite(r.frequency_hz) ? nlohmann::ordered_json(r.frequency_hz)
                                                                             : nlohmann::ordered_json(nullptr)}});
  j["rejected"] = nlohmann::ordered_json::array();
  for (const auto& r : result.rejected)
    j["rejected"].push_back({{"stage", r.stage}, {"name", r.name}, {"reason", r.reason}});
  j["not_assessed"] = result.not_assessed;
  j["notes"] = result.notes;
  j["residual_maps"] = nlohmann::ordered_json::array();
  for (const auto& [model, map] : result.residual_maps) j["residual_maps"].push_back(residual_map_json(model, map));
  return j.dump(2) + "\n";
}

std::vector<PlateTrial> plate_trials(const SessionData& state, double offset_s) {
  std::vector<PlateTrial> plates;
  const double fps = state.frame_rate_hz;
  for (const auto& tr : state.trials) {
    if (!tr.force || !tr.result.accepted) continue;
    const forceplate::ForceTrial& f = *tr.force;
    PlateTrial p;
    p.id = tr.result.id;
    p.t_s = f.plate.t_s;
    p.fz_n = f.plate.f_n.col(2);
    p.noise_n = f.noise_n;
    p.contact_time_s = f.contact_time_s;
    p.end_time_s = f.end_time_s;
    p.quiet_end_s = std::min(f.trigger_time_s, f.contact_time_s) - state.quiet_guard_s;
    p.impact_velocity_m_s = tr.result.impact_velocity_m_s;
    // The mat top the cameras see (trial.h: contact height), as the face is.
    p.mat_top_z_m = std::isfinite(tr.result.contact_height_m) ? tr.result.contact_height_m : state.mat_top_z_m;
    p.max_deformation_time_s = tr.result.max_deformation_time_s;
    p.fall_accel_m_s2 = tr.result.fall_accel_m_s2;
    p.fall_accel_se_m_s2 = tr.result.fall_accel_se_m_s2;
    const Eigen::VectorXd z = face_heights(tr.trajectories, state.base_markers, state.base_marker_height_m);
    p.face_z_m = z;
    p.video_t_s.resize(z.size());
    for (Eigen::Index k = 0; k < z.size(); ++k)
      p.video_t_s(k) = (static_cast<double>(k) - state.trigger_frame) / fps - offset_s;
    plates.push_back(std::move(p));
  }
  return plates;
}

// See diagnosis.h.
double trajectory_estimate_bias_s(fitting::ModelKind model, const fitting::MatParams& params, double velocity_m_s,
                                  double mass_kg, double gravity_m_s2, const PlateCorrection& plate,
                                  double contact_time_s, double force_lowpass_hz) {
  fitting::Impact imp;
  imp.mass_kg = mass_kg;
  imp.velocity_m_s = velocity_m_s;
  imp.gravity_m_s2 = gravity_m_s2;
  imp.output_dt_s = 1e-4;
  imp.duration_s = 0.3;
  fitting::Simulation sim;
  try {
    sim = fitting::simulate(model, params, imp);
  } catch (const std::exception&) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  const Eigen::Index n = sim.t_s.size();
  if (n < 20) return std::numeric_limits<double>::quiet_NaN();
  const double end = std::isfinite(sim.separation_s) ? sim.separation_s : sim.t_s(n - 1);
  // What the plate reads: gain x force + drift (PlateCorrection::apply inverted).
  Eigen::VectorXd read_n = plate.gain * sim.grf_n;
  if (force_lowpass_hz > 0.0) {
    // ... through the force channel's low-pass, when one was found.
    std::vector<double> v(read_n.data(), read_n.data() + n);
    fitting::force_lowpass(v, imp.output_dt_s, force_lowpass_hz);
    read_n = Eigen::Map<const Eigen::VectorXd>(v.data(), n);
  }
  if (plate.drift && std::isfinite(contact_time_s)) {
    const Eigen::VectorXd t_force = sim.t_s.array() + contact_time_s;
    read_n -= plate.gain * plate.apply(t_force, Eigen::VectorXd::Zero(n), contact_time_s);
  }
  // The face's lag behind free fall, matched as the trial matches it
  // (trial::trajectory_shift_s; the force is zero before contact).
  std::vector<double> tk, dz;
  for (Eigen::Index k = 0; k < n && sim.t_s(k) <= end; ++k) {
    const double t = sim.t_s(k);
    tk.push_back(t);
    dz.push_back(velocity_m_s * t + 0.5 * gravity_m_s2 * t * t - sim.impactor_m(k));
  }
  return trial::trajectory_shift_s(sim.t_s, read_n, 0, mass_kg, tk, dz, 0.0);
}

namespace {

// Later stages left out because an earlier one could not explain its
// residual: one note each, in the result and the report.
void not_assessed(DiagnosisResult& result, const std::string& stage, const std::string& upstream) {
  result.notes.push_back(fmt::format("{}: not assessed: upstream unresolved ({} residual unexplained)", stage,
                                     upstream));
  result.not_assessed.push_back(stage);
}

// The clock offset once more, from each trial's contact instant as the final
// mat model places it (the onset estimate minus the fitted contact shift):
// the contact-instant estimate carries the plate's onset lag, which depends
// on the mat (its layer masses, how fast it stiffens), and a mat the
// baseline got wrong reads as a clock offset. The fitted contact has no
// onset lag. Empty when fewer than two trials have a fitted contact or the
// offsets scatter (the onset verdict then stands).
std::optional<SyncDiagnosis> rejudge_sync(const std::vector<trial::TrialResult>& results,
                                          const fitting::FitResult& fit, const SyncStageOptions& options,
                                          double onset_offset_s, double mass_kg, double gravity_m_s2,
                                          const PlateCorrection& plate, bool model_explains,
                                          double force_lowpass_hz) {
  std::vector<trial::TrialResult> fitted = results;
  int n = 0;
  for (auto& r : fitted) {
    for (const auto& t : fit.trials) {
      if (t.id != r.id || !std::isfinite(t.contact_shift_se_s) || !std::isfinite(r.video_offset_s)) continue;
      r.video_offset_s -= t.contact_shift_s;
      // The independent estimate without the mat's inertia and the plate's
      // gain and drift, read through the mat model: only when that model
      // explains the mat (otherwise it would make the check agree with the
      // model it checks: a 28 Hz plate ring outside the library was fitted
      // with a 0.88 ms contact shift, and the corrected estimate agreed).
      if (model_explains && std::isfinite(r.video_offset_trajectory_s))
        r.video_offset_trajectory_s -= trajectory_estimate_bias_s(fit.model, fit.params, r.impact_velocity_m_s,
                                                                  mass_kg, gravity_m_s2, plate, r.contact_time_s,
                                                                  force_lowpass_hz);
      ++n;
    }
  }
  if (n < 2) return std::nullopt;
  SyncStageOptions so = options;
  so.onset_lag_s = 0.0;
  // A mat model that does not reach the noise places the contact with its
  // own error (a lumped chain on a foam column moved it 1.0-1.8 ms): the
  // offset it implies is judged with that discrepancy, the RMS of the
  // contact shifts it fitted, added to the systematic uncertainty.
  double widen_s = 0.0;
  if (!model_explains) {
    double ss = 0.0;
    int k = 0;
    for (const auto& t : fit.trials)
      if (std::isfinite(t.contact_shift_se_s)) ss += t.contact_shift_s * t.contact_shift_s, ++k;
    widen_s = k > 0 ? std::sqrt(ss / k) : 0.0;
    so.systematic_s = std::hypot(so.systematic_s, widen_s);
  }
  SyncDiagnosis refit = diagnose_sync(fitted, so);
  if (!refit.remaining.empty()) return std::nullopt;
  refit.notes.push_back(fmt::format(
      "sync: judged on the contact instants the final mat model fits ({} trials; the plate-onset estimate gave "
      "{:.2f} ms and was used to align the plate stage){}",
      n, 1e3 * onset_offset_s,
      model_explains ? ""
                     : fmt::format("; the mat model leaves structure unexplained, so its contact placement's "
                                   "discrepancy ({:.2f} ms RMS) widens the offset's uncertainty",
                                   1e3 * widen_s)));
  return refit;
}

}  // namespace

namespace {

// A named value of an error set (NaN when absent).
double value_of(const ErrorSet& set, const std::string& name) {
  for (const auto& [k, v] : set)
    if (k == name) return v;
  return kNaN;
}

// The accepted trials' fit data with the plate's gain and drift taken out.
std::vector<fitting::TrialData> corrected_mat_data(const SessionData& state, const PlateCorrection& correction) {
  std::vector<fitting::TrialData> data;
  for (std::size_t i = 0; i < state.fit_data.size() && i < state.trials.size(); ++i) {
    const fitting::TrialData& d = state.fit_data[i];
    if (!d.accepted) continue;
    fitting::TrialData c = d;
    const double tc = state.trials[i].result.contact_time_s;
    if (correction.drift || correction.gain != 1.0) {
      const Eigen::VectorXd t_abs = d.t_s.array() + tc;
      c.grf_n = correction.apply(t_abs, d.grf_n, tc);
      c.force_noise_n = d.force_noise_n / correction.gain;
    }
    data.push_back(std::move(c));
  }
  return data;
}

}  // namespace

namespace {

// After the mat stage: the force channel's undeclared low-pass, where the
// model reaches the noise (its lag otherwise reads as clock offset), then
// sync once more, on the contacts the final mat model fits (through the
// filter when one was named), told what the low-pass profile found.
std::optional<LowpassDiagnosis> force_channel_and_sync(const SessionData& state, const DiagnosisOptions& options,
                                                       const std::vector<fitting::TrialData>& data,
                                                       const MatDiagnosis& md, double explained_sd,
                                                       const std::vector<trial::TrialResult>& sync_results,
                                                       const PlateCorrection& correction,
                                                       std::optional<SyncDiagnosis>& sync) {
  std::optional<LowpassDiagnosis> lowpass;
  if (options.force_lowpass && md.fit_after)
    lowpass = diagnose_force_lowpass(data, md.options_after, md.fit_after->params,
                                     value_of(md.error_after, "heldout_force_rms_noise_sd"),
                                     value_of(md.error_after, "heldout_impactor_rms_noise_sd"), explained_sd,
                                     options.lowpass_stage);
  const bool filtered = lowpass && lowpass->named;
  if (sync && md.fit_after)
    if (auto refit = rejudge_sync(sync_results, filtered ? *lowpass->fit : *md.fit_after, options.sync_stage,
                                  sync->offset_s, state.impactor_mass_kg, state.gravity_m_s2, correction,
                                  md.remaining.empty(), filtered ? lowpass->corner_hz : 0.0))
      sync = std::move(refit);
  if (sync && lowpass) detail::attribute_lag(*sync, *lowpass, options.lowpass_stage.min_ambiguity_s);
  return lowpass;
}

}  // namespace

namespace {

// The between-trials stage into the result, with each trial's trend scale
// when the mat changes (the pipeline predicts each trial with it).
void append_order(DiagnosisResult& result, const OrderDiagnosis& order) {
  append(result, order);
  if (order.changed)
    for (std::size_t i = 0; i < order.ids.size(); ++i)
      result.trial_stiffness_scale.emplace_back(order.ids[i], order.trend_scale[i]);
}

}  // namespace

namespace {

// Between trials: is it one mat in every trial? (`data` is in recording
// order.) Without the run's own baseline the mat stage's is fitted here, kept
// in *own so that mo->baseline may point at it.
std::optional<OrderDiagnosis> judge_order(const std::vector<fitting::TrialData>& data, const DiagnosisOptions& options,
                                          MatStageOptions* mo, std::optional<fitting::FitResult>* own,
                                          DiagnosisResult* result) {
  if (!options.order || data.size() < 4) return std::nullopt;
  if (!mo->baseline) {
    try {
      *own = fitting::fit(data, mo->fit);
      mo->baseline = &**own;
    } catch (const std::exception& e) {
      result->notes.push_back(fmt::format("between trials: not judged: the baseline fit failed: {}", e.what()));
      return std::nullopt;
    }
  }
  return diagnose_order(data, *mo->baseline, options.order_stage);
}

}  // namespace

DiagnosisResult diagnose(const SessionData& state, const DiagnosisOptions& options) {
  DiagnosisResult result;
  MatStageOptions mo = options.mat_stage;
  if (!options.mat_stage_fit_set) mo.fit = state.baseline_fit_options;
  result.baseline_model = fitting::model_name(mo.fit.model);
  bool any = false;
  for (const auto& t : state.trials) any = any || t.result.accepted;

  // Stages in order; the first whose residual stays unexplained stops the rest.
  std::string unresolved;
  auto gate = [&](const std::string& stage) {
    if (unresolved.empty()) return true;
    not_assessed(result, stage, unresolved);
    return false;
  };

  // ---- calibration (decided by the pipeline; every trial used its choice) ----
  if (options.calibration) {
    append(result, state.calibration);
    if (!state.calibration.remaining.empty()) unresolved = "calibration";
  }
  if (!any && unresolved.empty()) {
    // Every trial rejected (its reason is in trial.json): nothing for the
    // later stages to judge.
    result.notes.push_back("no accepted trial: sync, force plate and mat not assessed");
    unresolved = "trials";
  }

  // ---- sync ----
  // Judged first on the contact instants (they align video and force for
  // the plate stage); its verdict is written after the mat stage, which may
  // re-judge it on the fitted contacts (below).
  double offset_s = 0.0;
  std::optional<SyncDiagnosis> sync;
  std::vector<trial::TrialResult> sync_results;
  if (options.sync && gate("sync")) {
    for (const auto& t : state.trials) sync_results.push_back(t.result);
    sync = diagnose_sync(sync_results, options.sync_stage);
    offset_s = sync->offset_s;
    if (!sync->remaining.empty()) {
      unresolved = "sync";
      append(result, *sync);
      sync.reset();
    }
  }

  // Sync and plate verdicts go into the result in stage order once the mat
  // stage has had its say on sync (or at once when a later stage will not run).
  std::optional<ForceplateDiagnosis> plate;
  auto flush = [&] {
    if (sync) append(result, *sync);
    if (plate) append(result, *plate);
    sync.reset();
    plate.reset();
  };

  // ---- force plate ----
  PlateCorrection correction;
  const std::vector<PlateTrial> plates = plate_trials(state, offset_s);
  if (options.forceplate && gate("forceplate")) {
    ForceplateStageOptions fo = options.forceplate_stage;
    fo.impactor_mass_kg = state.impactor_mass_kg;
    fo.gravity_m_s2 = state.gravity_m_s2;
    fo.frame_rate_hz = state.frame_rate_hz;
    if (!plates.empty()) {
      plate = diagnose_forceplate(plates, fo);
      correction = plate->correction;
      if (!plate->remaining.empty()) {
        unresolved = "forceplate";
        flush();
      }
    }
  }

  // ---- mat: the fits' own data, with the plate corrections applied ----
  if (options.mat && gate("mat")) {
    const std::vector<fitting::TrialData> data = corrected_mat_data(state, correction);
    // The run's own Model 4 fit is the baseline when the plate needed no
    // correction (the same data, the same options): it is not refitted.
    const fitting::FitResult* run_fit = state.fit(mo.fit.model);
    if (run_fit && !correction.drift && correction.gain == 1.0 && mo.fit.model == state.baseline_fit_options.model)
      mo.baseline = run_fit;
    // A changing mat leaves the effects of one mat unjudged.
    std::optional<fitting::FitResult> own_baseline;
    const std::optional<OrderDiagnosis> order = judge_order(data, options, &mo, &own_baseline, &result);
    const bool mat_changes = order && order->changed;
    if (mat_changes) {
      flush();
      result.notes.push_back(
          "mat: effects of one mat (stiffening, hysteresis, rate dependence, layer mass) not judged: the mat changes "
          "between trials, so no single set of parameters describes them all");
    } else if (!data.empty()) {
      if (options.after_mat_round)
        mo.after_round = [&](const fitting::FitResult& current, double force_sd, double impactor_sd) {
          options.after_mat_round(current, force_sd, impactor_sd, correction);
        };
      const MatDiagnosis md = diagnose_mat(data, mo);
      const std::optional<LowpassDiagnosis> lowpass =
          force_channel_and_sync(state, options, data, md, mo.unexplained_noise_sd, sync_results, correction, sync);
      flush();
      if (lowpass) append(result, *lowpass);
      append(result, md);
      const bool corrected = correction.drift || correction.gain != 1.0;
      if ((!md.effects.empty() || corrected) && md.fit_after) result.mat_fit = md.fit_after;
      // A named force-channel filter: the mat fitted through it is the mat.
      if (lowpass && lowpass->named && lowpass->fit) result.mat_fit = lowpass->fit;
    }
    if (order) append_order(result, *order);
  }
  flush();
  result.plate_correction = correction;
  return result;
}

}  // namespace dropfit::diagnosis
