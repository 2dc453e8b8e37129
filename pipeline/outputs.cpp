#include "pipeline/outputs.h"

#include <fmt/format.h>

#include <cmath>
#include <filesystem>

#include "pipeline/wiring.h"
#include "report/model6_results.h"
#include "report/opensim.h"
#include "report/results.h"
#include "report/session_report.h"

namespace dropfit::pipeline {

void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result,
                             const VideoSpec& video) {
  if (result.cameras.empty()) return;  // no cameras: every trial brought its own 3-D markers
  out.add("calibration.json", report::calibration_json(result));
  const bool bottom_left = video.image_origin == ImageOrigin::BottomLeft && video.image_height_px;
  out.add("dlt_coefficients.csv",
          report::dlt_coefficients_csv(cameras_of(result), bottom_left ? *video.image_height_px : 0.0));
}

void add_reconstruction_outputs(report::OutputSet& out, const SessionState& state) {
  for (const auto& t : state.trials) {
    const std::string dir = "trials/" + t.result.id + "/";
    out.add(dir + "xyzpts.csv", report::xyzpts_csv(t.trajectories));
    out.add(dir + "residuals.csv", report::residuals_csv(t.trajectories));
    out.add(dir + "xyzres.csv", report::xyzres_csv(t.trajectories, state.session.manifest.video.points));
  }
}

report::TrialSource trial_source(const SessionState& state, std::size_t i) {
  report::TrialSource source;
  const ForceRecord& record = state.session.trials[i].force;
  source.trigger = record.trigger;
  source.trigger_from_data = record.trigger_from_data;
  if (state.session.trials[i].has_3d_markers())
    source.markers_file = std::filesystem::path(state.session.trials[i].markers_path).filename().string();
  if (state.trials[i].force) source.cop_unavailable = state.trials[i].force->cop_unavailable;
  return source;
}

void add_trial_outputs(report::OutputSet& out, const SessionState& state) {
  add_reconstruction_outputs(out, state);
  const Manifest& man = state.session.manifest;
  std::vector<trial::TrialResult> results;
  for (std::size_t i = 0; i < state.trials.size(); ++i) {
    const diagnosis::TrialState& t = state.trials[i];
    const std::string dir = "trials/" + t.result.id + "/";
    const report::TrialSource source = trial_source(state, i);
    out.add(dir + "trial.json", report::trial_json(t.result, &source));
    out.add(dir + "series.csv", report::series_csv(t.result.series));
    // OpenSim: markers with frame i at its force-clock time (the nominal
    // video clock when synchronisation found no offset), and the plate's
    // reaction.
    const double offset_s = std::isfinite(t.result.video_offset_s) ? t.result.video_offset_s : 0.0;
    const double rate_hz = man.video.frame_rate_hz;
    Eigen::VectorXd frame_times_s(t.trajectories.n_frames());
    for (Eigen::Index i = 0; i < frame_times_s.size(); ++i)
      frame_times_s[i] = (static_cast<double>(i) - man.video.trigger_frame) / rate_hz - offset_s;
    out.add(dir + "markers.trc", report::markers_trc(t.trajectories, man.video.points, frame_times_s, rate_hz));
    if (t.force) out.add(dir + "grf.mot", report::grf_mot(*t.force));
    results.push_back(t.result);
  }
  out.add("summary.csv", report::summary_csv(results));
}

namespace {

void add_series(report::OutputSet& out, const std::string& prefix, const std::vector<fitting::TrialReport>& trials,
                const SessionState& state) {
  for (const auto& trial : trials) {
    for (const auto& data : state.fit_data) {
      if (data.id == trial.id) out.add(prefix + "series/" + data.id + ".csv", report::fit_series_csv(data, trial));
    }
  }
}

}  // namespace

std::vector<std::string> session_caveats(const SessionState& state) {
  std::vector<std::string> out;
  if (!state.loop) return out;
  const double gain = state.loop->plate_correction.gain;
  if (gain == 1.0 || !(gain > 0.0)) return out;
  // Impulse against momentum reads the product of the plate's gain and the
  // impactor's mass: the forces were divided by the gain, and a declared
  // mass off by the same factor explains the record as well. Then the
  // plate was right, and every force (and the stiffnesses fitted to them)
  // is off by 1 / gain.
  const double declared_kg = state.session.manifest.impactor.mass_kg;
  out.push_back(fmt::format(
      "every force here was divided by the plate gain {:.4g} that closing the loop found; an impactor of {:.2f} kg, "
      "where the manifest declares {:.2f} kg, explains the plate's impulse as well (the two cannot be told apart): "
      "if the mass is the cause, these forces, peaks and stiffnesses are {:.1f} % too {}; weigh the impactor or "
      "check the plate's calibration",
      gain, gain * declared_kg, declared_kg, 100.0 * std::abs(1.0 / gain - 1.0), gain < 1.0 ? "high" : "low"));
  return out;
}

void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const SessionState& state, const std::string& label) {
  fitting::FitResult shown = fit;
  for (std::string& w : session_caveats(state)) shown.warnings.push_back(std::move(w));
  out.add(prefix + "fit.json", report::fit_json(shown, state.session.manifest.impactor.mass_kg, label));
  add_series(out, prefix, fit.trials, state);
}

void add_model6_outputs(report::OutputSet& out, const std::string& prefix, const SessionState& state) {
  if (!state.model6 || !state.model6->fit) return;
  Model6Stage m6 = *state.model6;
  for (std::string& w : session_caveats(state)) m6.fit->warnings.push_back(std::move(w));
  report::Model6Choice choice;
  choice.rival = m6.rival;
  choice.chosen = m6.chosen;
  if (m6.choice) choice.evidence = m6.choice->evidence;
  choice.heldout_force_rms_noise_sd = m6.heldout_force_sd;
  choice.heldout_impactor_rms_noise_sd = m6.heldout_impactor_sd;
  choice.reaches_noise = m6.reaches_noise;
  out.add(prefix + "fit.json",
          report::model6_fit_json(*m6.fit, m6.options, state.session.manifest.impactor.mass_kg, choice));
  add_series(out, prefix, m6.fit->trials, state);
}

fitting::FitResult model6_headline_fit(const fitting::Model6FitResult& fit) {
  fitting::FitResult f = report::model6_as_fit(fit);
  for (const auto& e : fit.estimates)
    if (e.at_bound) f.warnings.push_back(e.name + " sits at the bound of its search range: the bound, not the data, sets it");
  return f;
}

report::MatGeometry mat_geometry(const Manifest& manifest) {
  report::MatGeometry geometry;
  geometry.length_m = manifest.mat.length_m;
  geometry.width_m = manifest.mat.width_m;
  const auto& layers = manifest.mat.layers;
  if (layers.size() >= 2) {
    geometry.bottom_thickness_m = layers.back().thickness_m;
    geometry.top_thickness_m = manifest.mat.thickness_m() - layers.back().thickness_m;
  }
  return geometry;
}

namespace {

bool layered(fitting::ModelKind model) {
  return model == fitting::ModelKind::Model3 || model == fitting::ModelKind::Model4;
}

}  // namespace

void add_run_outputs(report::OutputSet& out, const SessionState& state) {
  const Manifest& man = state.session.manifest;
  add_calibration_outputs(out, state.calibration.after, man.video);
  add_trial_outputs(out, state);
  for (const auto& fit : state.fits) {
    const std::string prefix = "fits/" + fitting::model_name(fit.model) + "/";
    add_fit_outputs(out, prefix, fit, state);
    if (layered(fit.model)) out.add(prefix + "mat.mjcf.xml", report::mjcf_xml(fit.model, fit.params, mat_geometry(man)));
  }
  // The final model is the result: the canonical fit.json and mat.mjcf.xml.
  const fitting::FitResult* final_fit = state.final_fit();
  if (state.loop) {
    out.add("diagnosis.json", diagnosis::diagnosis_json(*state.loop));
    if (state.loop->mat_fit) add_fit_outputs(out, "fits/closed_loop/", *state.loop->mat_fit, state, "closed_loop");
  }
  if (state.model6 && state.model6->fit) add_model6_outputs(out, "fits/model6/", state);
  if (state.final_model6()) {
    add_model6_outputs(out, "", state);
  } else if (final_fit) {
    add_fit_outputs(out, "", *final_fit, state, state.final_label());
    if (layered(final_fit->model))
      out.add("mat.mjcf.xml", report::mjcf_xml(final_fit->model, final_fit->params, mat_geometry(man)));
  }

  report::SessionReport rep;
  rep.session_name = summarise(state).session;
  rep.session_path = state.session.root;
  rep.calibration = &state.calibration.after;
  for (const auto& t : state.trials) rep.trials.push_back(t.result);
  rep.fit_data = state.fit_data;
  rep.fits = state.fits;
  if (const fitting::Model6FitResult* m6 = state.final_model6()) {
    rep.final_fit = model6_headline_fit(*m6);
    rep.final_label = "model6";
    rep.final_note = state.model6->reason + ". " + report::kModel6NoMjcf + ".";
  } else if (final_fit) {
    rep.final_fit = *final_fit;
    rep.final_label = state.final_label();
  }
  if (state.loop) {
    rep.loop_run = true;
    rep.loop_baseline_model = state.loop->baseline_model;
    rep.loop_unexplained = state.loop->unexplained;
    for (const auto& e : state.loop->effects)
      rep.loop_effects.push_back({e.stage, e.name, e.evidence, e.error_before, e.error_after});
    for (const auto& [model, map] : state.loop->residual_maps) {
      report::ResidualForm f{model, map.form, map.proposal, map.loading_unloading_r2, {}};
      for (const auto& a : map.axes) f.axes.push_back({a.name, a.centre, a.mean_sd, a.r2});
      rep.residual_forms.push_back(std::move(f));
    }
  }
  if (rep.final_fit)
    for (std::string& w : session_caveats(state)) rep.final_fit->warnings.push_back(std::move(w));
  rep.notes = state.all_notes();
  out.add("report.html", report::session_report_html(rep));
}

}  // namespace dropfit::pipeline
