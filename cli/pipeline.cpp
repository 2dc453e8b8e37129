#include "cli/pipeline.h"

#include "report/opensim.h"
#include "report/results.h"

#include <fmt/format.h>

#include <algorithm>
#include <limits>
#include <atomic>
#include <optional>
#include <thread>
#include <cmath>

#include "capture/io.h"
#include "core/error.h"
#include "diagnosis/diagnosis.h"

namespace dropfit::pipeline {

std::vector<calibration::Marker> calibration_markers(const std::vector<CalibrationMarker>& frame) {
  std::vector<calibration::Marker> markers;
  markers.reserve(frame.size());
  for (const auto& m : frame) markers.push_back({m.id, m.lab_m, m.role == MarkerRole::Check});
  return markers;
}

std::vector<calibration::CameraView> camera_views(const std::vector<CalibrationImage>& images) {
  std::vector<calibration::CameraView> views;
  views.reserve(images.size());
  for (const auto& image : images) {
    calibration::CameraView view{image.camera, {}};
    for (const auto& o : image.observations) view.observations.emplace_back(o.id, o.image_px);
    views.push_back(std::move(view));
  }
  return views;
}

diagnosis::CalibrationDiagnosis choose_calibration(const Session& session) {
  if (!session.dlt_coefficients.empty()) {
    // A wand calibration's coefficients: nothing to choose; the frame's check
    // markers, when there is a frame, report its accuracy.
    diagnosis::CalibrationDiagnosis given;
    given.before = given.after = calibrate_session(session, calibration::CalibrationOptions{});
    given.notes.push_back("calibration: DLT coefficients given in the manifest; the camera model is not re-chosen");
    return given;
  }
  return diagnosis::diagnose_calibration(calibration_markers(session.frame), camera_views(session.images));
}

calibration::CalibrationResult calibrate_session(const Session& session) { return choose_calibration(session).after; }

calibration::CalibrationResult calibrate_session(const Session& session,
                                                 const calibration::CalibrationOptions& options) {
  // Coefficients given in the manifest ([calibration] dlt_coefficients):
  // used as they are, checked on the frame's check markers when there is one.
  if (!session.dlt_coefficients.empty()) {
    std::vector<calibration::Camera> cameras;
    for (std::size_t c = 0; c < session.dlt_coefficients.size(); ++c) {
      calibration::Camera& camera = cameras.emplace_back();
      camera.name = session.manifest.video.cameras[c];
      camera.dlt = session.dlt_coefficients[c];
    }
    return calibration::given_calibration(cameras, calibration_markers(session.frame), camera_views(session.images));
  }
  try {
    return calibration::calibrate(calibration_markers(session.frame), camera_views(session.images), options);
  } catch (const InputError&) {
    throw;
  } catch (const Error& e) {
    // Geometry failures (too few points, a degenerate frame) name the files.
    throw Error(fmt::format("{}/calibration (frame.csv and the camera files): {}", session.root, e.what()));
  }
}

std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result) {
  std::vector<calibration::Camera> cameras;
  for (const auto& fit : result.cameras) cameras.push_back(fit.camera);
  return cameras;
}

void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result,
                             const VideoSpec& video) {
  out.add("calibration.json", report::calibration_json(result));
  const bool bottom_left = video.image_origin == ImageOrigin::BottomLeft && video.image_height_px;
  out.add("dlt_coefficients.csv",
          report::dlt_coefficients_csv(cameras_of(result), bottom_left ? *video.image_height_px : 0.0));
}

void add_reconstruction_outputs(report::OutputSet& out, const std::string& trial_id,
                                const reconstruction::Trajectories& trajectories,
                                const std::vector<std::string>& point_names) {
  out.add("trials/" + trial_id + "/xyzpts.csv", report::xyzpts_csv(trajectories));
  out.add("trials/" + trial_id + "/residuals.csv", report::residuals_csv(trajectories));
  out.add("trials/" + trial_id + "/xyzres.csv", report::xyzres_csv(trajectories, point_names));
}

trial::TrialOptions trial_options(const Manifest& manifest, const std::string& trial_id) {
  auto index_of = [&](const std::string& name) {
    const auto& points = manifest.video.points;
    return static_cast<int>(std::find(points.begin(), points.end(), name) - points.begin());
  };
  trial::TrialOptions options;
  options.id = trial_id;
  options.impactor_mass_kg = manifest.impactor.mass_kg;
  options.gravity_m_s2 = manifest.gravity_m_s2;
  options.frame_rate_hz = manifest.video.frame_rate_hz;
  options.trigger_frame = manifest.video.trigger_frame;
  for (const auto& name : manifest.impactor.base_markers) options.base_markers.push_back(index_of(name));
  for (const auto& name : manifest.mat.surface_markers) options.surface_markers.push_back(index_of(name));
  options.point_names = manifest.video.points;
  options.base_marker_height_m = manifest.impactor.base_marker_height_m;
  options.mat_top_z_m = manifest.forceplate.mat_top_z_m;
  options.mat_mass_kg = manifest.mat.mass_kg();
  return options;
}

forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record) {
  forceplate::ProcessOptions options;
  options.trigger_threshold_n = manifest.forceplate.trigger_threshold_n;
  options.pretrigger_fraction = manifest.forceplate.pretrigger_fraction;
  options.pretrigger_samples = record.pretrigger_samples > 0 ? record.pretrigger_samples : -1;
  options.sample_rate_hz = manifest.forceplate.sample_rate_hz;
  return options;
}

forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record) {
  // A C3D's FORCE_PLATFORM:ORIGIN replaces the manifest's geometry.
  const Eigen::Vector3d g = record.plate_geometry_m.value_or(
      Eigen::Vector3d(manifest.forceplate.a_m, manifest.forceplate.b_m, manifest.forceplate.az0_m));
  if (record.layout == ForceLayout::EightChannel) {
    return forceplate::from_eight_channels(record.t_s, record.data, {g[0], g[1], g[2]});
  }
  return forceplate::from_resultant_columns(record.t_s, record.data, 50.0, g[2]);
}

TrialOutcome process_trial(const Manifest& manifest, const TrialRecording& trial,
                           const std::vector<calibration::Camera>& cameras, double max_tilt_deg) {
  TrialOutcome outcome;
  outcome.trajectories = reconstruction::reconstruct(cameras, trial.tracks.uv_px, trial.tracks.n_points());
  auto options = trial_options(manifest, trial.spec.id);
  if (max_tilt_deg > 0.0) options.max_tilt_deg = max_tilt_deg;
  outcome.options = options;
  try {
    // A force record that cannot be converted or processed: the trial is
    // rejected with the reason; the video-only numbers are still measured.
    outcome.force = forceplate::process(raw_resultants(manifest, trial.force), force_options(manifest, trial.force));
  } catch (const Error& e) {
    outcome.result = trial::analyse_without_force(outcome.trajectories, options, e.what());
    return outcome;
  }
  outcome.result = trial::analyse(*outcome.force, outcome.trajectories, options);
  return outcome;
}

void add_trial_outputs(report::OutputSet& out, const TrialOutcome& outcome) {
  const std::string dir = "trials/" + outcome.result.id + "/";
  out.add(dir + "trial.json", report::trial_json(outcome.result));
  out.add(dir + "series.csv", report::series_csv(outcome.result.series));
  add_reconstruction_outputs(out, outcome.result.id, outcome.trajectories, outcome.options.point_names);
  // OpenSim: markers with frame i at its force-clock time (the nominal video
  // clock when synchronisation found no offset), and the plate's reaction.
  const auto& o = outcome.options;
  const double offset_s = std::isfinite(outcome.result.video_offset_s) ? outcome.result.video_offset_s : 0.0;
  Eigen::VectorXd frame_times_s(outcome.trajectories.n_frames());
  for (Eigen::Index i = 0; i < frame_times_s.size(); ++i) {
    frame_times_s[i] = (static_cast<double>(i) - o.trigger_frame) / o.frame_rate_hz - offset_s;
  }
  out.add(dir + "markers.trc", report::markers_trc(outcome.trajectories, o.point_names, frame_times_s, o.frame_rate_hz));
  if (outcome.force) out.add(dir + "grf.mot", report::grf_mot(*outcome.force));
}

fitting::TrialData fitting_trial(const Manifest& manifest, const trial::TrialResult& result) {
  fitting::TrialData data;
  data.id = result.id;
  data.accepted = result.accepted;
  data.impact_velocity_m_s = result.impact_velocity_m_s;
  data.impactor_mass_kg = manifest.impactor.mass_kg;
  data.gravity_m_s2 = manifest.gravity_m_s2;
  data.force_noise_n = result.force_noise_n;
  data.marker_noise_m = result.freefall_rms_m;
  // The inputs' error budget: the fit carries them as nuisance parameters.
  data.impact_velocity_se_m_s = result.impact_velocity_se_m_s;
  data.contact_time_se_s = result.video_contact_time_se_s;
  data.velocity_contact_time_cov = result.velocity_contact_time_cov;
  data.travel_reference_se_m = result.contact_height_se_m;
  data.calibration_scale_sd = result.calibration_scale_sd;
  const auto& s = result.series;
  // The surface markers' height at rest: their mean before contact. The
  // impactor's travel is already measured from the mat top the cameras see
  // (trial.h: contact height), which cancels the calibration's height error
  // near the mat.
  double rest_sum = 0.0;
  int rest_n = 0;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] < result.contact_time_s && std::isfinite(s.surface_z_m[i])) {
      rest_sum += s.surface_z_m[i];
      ++rest_n;
    }
  }
  const double surface_rest_m = rest_n > 0 ? rest_sum / rest_n : manifest.forceplate.mat_top_z_m;
  // From a little before the contact estimate: the fit places each trial's
  // contact on the force clock itself (fitting/fit.h).
  const double lead_s = 0.005;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] >= result.contact_time_s - lead_s) keep.push_back(i);
  }
  const auto n = static_cast<Eigen::Index>(keep.size());
  data.t_s.resize(n);
  data.grf_n.resize(n);
  data.impactor_m.resize(n);
  data.surface_m.resize(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Index i = keep[k];
    data.t_s[k] = s.t_s[i] - result.contact_time_s;
    data.grf_n[k] = s.fz_n[i];
    data.impactor_m[k] = s.deformation_m[i];
    data.surface_m[k] = surface_rest_m - s.surface_z_m[i];
  }
  return data;
}

fitting::Model5Geometry model5_geometry(const Manifest& manifest) {
  fitting::Model5Geometry g;
  g.mat_length_m = manifest.mat.length_m;
  g.mat_width_m = manifest.mat.width_m;
  g.footprint_length_m = manifest.impactor.footprint_m.x();
  g.footprint_width_m = manifest.impactor.footprint_m.y();
  return g;
}

fitting::FitOptions fit_options(const Manifest& manifest, fitting::ModelKind model) {
  fitting::FitOptions options;
  options.model = model;
  const auto& layers = manifest.mat.layers;
  if (layers.size() >= 2) {
    options.m2_kg = layers.back().mass_kg;
    options.m1_kg = manifest.mat.mass_kg() - options.m2_kg;
  } else if (layers.size() == 1) {
    options.m1_kg = options.m2_kg = layers.front().mass_kg / 2;
  }
  // Model 5's mat and face (the fitter differentiates it exactly).
  if (model == fitting::ModelKind::Model5) options.model5_geometry = model5_geometry(manifest);
  return options;
}

void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const std::vector<fitting::TrialData>& trials, double impactor_mass_kg) {
  out.add(prefix + "fit.json", report::fit_json(fit, impactor_mass_kg));
  for (const auto& report : fit.trials) {
    for (const auto& data : trials) {
      if (data.id == report.id) out.add(prefix + "series/" + data.id + ".csv", report::fit_series_csv(data, report));
    }
  }
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

trial::CalibrationQuality session_calibration_quality(const Session& session,
                                                      const calibration::CalibrationResult& calibration) {
  double z_min = std::numeric_limits<double>::infinity(), z_max = -z_min;
  for (const auto& m : session.frame) z_min = std::min(z_min, m.lab_m.z()), z_max = std::max(z_max, m.lab_m.z());
  return trial::calibration_quality(calibration, z_max - z_min);
}

diagnosis::SessionState session_state(const Session& session, const std::function<void(const std::string&)>& say) {
  const Manifest& man = session.manifest;
  diagnosis::SessionState state;
  state.name = man.name;
  state.impactor_mass_kg = man.impactor.mass_kg;
  state.gravity_m_s2 = man.gravity_m_s2;
  state.frame_rate_hz = man.video.frame_rate_hz;
  state.trigger_frame = man.video.trigger_frame;
  state.mat_top_z_m = man.forceplate.mat_top_z_m;
  const trial::TrialOptions to = trial_options(man, "");
  state.base_markers = to.base_markers;
  state.surface_markers = to.surface_markers;
  state.base_marker_height_m = to.base_marker_height_m;
  state.quiet_guard_s = forceplate::ProcessOptions{}.quiet_guard_s;
  state.baseline_fit_options = fit_options(man, fitting::ModelKind::Model4);

  if (say) say("calibrating");
  state.calibration = choose_calibration(session);
  const auto cameras = cameras_of(state.calibration.after);
  // Trials measured through a calibration that failed its own checks, or
  // whose markers reproject far beyond it, are rejected (trial.h's gates).
  const auto quality = session_calibration_quality(session, state.calibration.after);
  for (size_t i = 0; i < session.trials.size(); ++i) {
    const auto& trial = session.trials[i];
    if (say) say(fmt::format("trial {} ({}/{})", trial.spec.id, i + 1, session.trials.size()));
    TrialOutcome outcome = process_trial(man, trial, cameras);
    trial::apply_calibration_gates(outcome.result, outcome.trajectories, trial_options(man, trial.spec.id), quality);
    trial::add_calibration_uncertainty(outcome.result, quality);
    state.fit_data.push_back(fitting_trial(man, outcome.result));
    state.trials.push_back({std::move(outcome.result), std::move(outcome.trajectories), std::move(outcome.force)});
  }
  return state;
}

std::vector<std::string> fit_models(diagnosis::SessionState& state, const Manifest& manifest,
                                    const std::vector<fitting::ModelKind>& models, int threads,
                                    const std::function<void(const std::string&)>& say) {
  std::vector<std::string> notes;
  std::vector<std::optional<fitting::FitResult>> fits(models.size());
  std::vector<std::string> errors(models.size());
  auto fit_one = [&](size_t k, const fitting::FitOptions& fit_opts) {
    if (say) say("fitting " + fitting::model_name(models[k]));
    try {
      fits[k] = fitting::fit(state.fit_data, fit_opts);
    } catch (const std::exception& e) {
      errors[k] = e.what();
    }
  };
  // Model 4 first (the canonical fit), then Model 5 warm-started from its
  // optimum (their parameters mean the same thing) with one start and few
  // iterations, on one worker (its exact derivatives split over
  // FitOptions::threads); Models 1-3 on the others meanwhile. No model
  // waits for a core another has left idle.
  size_t k4 = models.size();
  for (size_t k = 0; k < models.size(); ++k)
    if (models[k] == fitting::ModelKind::Model4) k4 = k;
  std::vector<size_t> queue;
  if (k4 < models.size()) queue.push_back(k4);
  for (size_t k = 0; k < models.size(); ++k)
    if (k != k4 && models[k] != fitting::ModelKind::Model5) queue.push_back(k);
  std::vector<size_t> fives;
  for (size_t k = 0; k < models.size(); ++k)
    if (models[k] == fitting::ModelKind::Model5) fives.push_back(k);
  auto fit_five = [&](size_t k) {
    auto fit_opts = fit_options(manifest, models[k]);
    if (k4 < models.size() && fits[k4]) {
      fit_opts.initial = fits[k4]->params;
      fit_opts.starts = 1;
      fit_opts.max_iterations = 30;
      fit_opts.first_stage_iterations = 30;  // one run of 30 iterations (no second stage)
    }
    fit_one(k, fit_opts);
  };
  std::atomic<size_t> next{0};
  auto worker = [&](bool first_worker) {
    for (size_t i; (i = next++) < queue.size();) {
      fit_one(queue[i], fit_options(manifest, models[queue[i]]));
      // The worker that fitted Model 4 goes on with Model 5.
      if (queue[i] == k4)
        for (size_t k : fives) fit_five(k);
    }
    if (first_worker && k4 >= models.size())
      for (size_t k : fives) fit_five(k);
  };
  const int n_threads = std::max(1, std::min<int>(threads, static_cast<int>(std::max<size_t>(queue.size(), 1))));
  std::vector<std::thread> workers;
  for (int w = 1; w < n_threads; ++w) workers.emplace_back(worker, false);
  worker(true);
  for (auto& w : workers) w.join();
  for (size_t k = 0; k < models.size(); ++k) {
    const auto name = fitting::model_name(models[k]);
    if (!fits[k]) {
      notes.push_back(fmt::format("{} fit failed: {}", name, errors[k]));
      continue;
    }
    for (const auto& w : fits[k]->warnings) notes.push_back(name + ": " + w);
    state.fits.push_back(std::move(*fits[k]));
  }
  return notes;
}

void apply_fitted_offset(trial::TrialResult& result, const fitting::FitResult& fit) {
  if (!std::isfinite(result.video_offset_s)) return;
  for (const auto& t : fit.trials) {
    if (t.id != result.id || !std::isfinite(t.contact_shift_se_s)) continue;
    result.video_offset_onset_s = result.video_offset_s;
    result.video_offset_s -= t.contact_shift_s;
    // The fitted contact's SE and the video contact instant's own.
    result.video_offset_se_s = std::isfinite(t.offset_se_s) ? t.offset_se_s : t.contact_shift_se_s;
  }
}

RunSummary run_session(const std::string& session_dir, const RunOptions& options, report::OutputSet& out,
                       Progress* progress) {
  auto say = [&](const std::string& stage, const std::string& detail = "") {
    if (progress) progress->update(stage, detail);
  };
  say("reading", session_dir);
  const Session session = capture::read_session(session_dir);
  RunSummary summary;
  summary.session = session.manifest.name.empty() ? session_dir : session.manifest.name;
  const auto tell = [&](const std::string& detail) { say(summary.session, detail); };

  // One state, built once: calibration (the stage's choice), trials, fit
  // data; the fits; then the loop on that same state.
  diagnosis::SessionState state = session_state(session, tell);
  add_calibration_outputs(out, state.calibration.after, session.manifest.video);
  std::vector<trial::TrialResult> results;
  for (const auto& t : state.trials) {
    summary.accepted += t.result.accepted ? 1 : 0;
    results.push_back(t.result);
  }
  summary.trials = static_cast<int>(results.size());

  report::SessionReport rep;
  rep.session_name = summary.session;
  rep.session_path = session_dir;
  rep.calibration = &state.calibration.after;
  rep.trials = results;
  rep.fit_data = state.fit_data;

  if (summary.accepted == 0) {
    summary.notes.push_back("no accepted trial: nothing to fit");
  } else {
    const auto notes = fit_models(state, session.manifest, options.models, options.threads, tell);
    summary.notes.insert(summary.notes.end(), notes.begin(), notes.end());
    summary.failed_fits += static_cast<int>(options.models.size()) - static_cast<int>(state.fits.size());
    for (const auto& fit : state.fits) {
      const auto name = fitting::model_name(fit.model);
      add_fit_outputs(out, "fits/" + name + "/", fit, state.fit_data, session.manifest.impactor.mass_kg);
      if (fit.model == fitting::ModelKind::Model4) {
        add_fit_outputs(out, "", fit, state.fit_data, session.manifest.impactor.mass_kg);
      }
      if (fit.model == fitting::ModelKind::Model3 || fit.model == fitting::ModelKind::Model4) {
        out.add("mat_" + name + ".mjcf.xml", report::mjcf_xml(fit.model, fit.params, mat_geometry(session.manifest)));
      }
      rep.fits.push_back(fit);
    }
  }

  std::optional<fitting::FitResult> closed_loop;
  if (options.diagnose && summary.accepted > 0) {
    tell("closing the loop");
    try {
      const diagnosis::DiagnosisResult loop = diagnosis::diagnose(state);
      out.add("diagnosis.json", diagnosis::diagnosis_json(loop));
      if (loop.mat_fit) {
        closed_loop = loop.mat_fit;
        add_fit_outputs(out, "fits/closed_loop/", *closed_loop, state.fit_data, session.manifest.impactor.mass_kg);
      }
      rep.loop_run = true;
      rep.loop_baseline_model = loop.baseline_model;
      rep.loop_unexplained = loop.unexplained;
      for (const auto& e : loop.effects) {
        rep.loop_effects.push_back({e.stage, e.name, e.evidence, e.error_before, e.error_after});
      }
      for (const auto& stage : loop.not_assessed) {
        summary.notes.push_back(fmt::format("closing the loop: {} not assessed: upstream unresolved", stage));
      }
    } catch (const std::exception& e) {
      summary.notes.push_back(fmt::format("closing the loop failed: {}", e.what()));
    }
  }
  // Each trial's clock offset from the contact instant the mat fit placed on
  // the force clock (the closed loop's model when it kept mat effects, else
  // Model 4), replacing the plate-onset estimate, which reads late on a
  // layered mat.
  const fitting::FitResult* sync_fit = closed_loop ? &*closed_loop : state.fit(fitting::ModelKind::Model4);
  for (size_t i = 0; i < results.size(); ++i) {
    trial::TrialResult& r = results[i];
    if (sync_fit) apply_fitted_offset(r, *sync_fit);
    add_trial_outputs(out, {state.trials[i].trajectories, r, trial_options(session.manifest, r.id), state.trials[i].force});
  }
  out.add("summary.csv", report::summary_csv(results));
  rep.trials = results;
  for (const auto& r : results) {
    if (!r.accepted) summary.notes.push_back(fmt::format("trial {} rejected: {}", r.id, r.reject_reason));
  }
  rep.notes = summary.notes;
  say(summary.session, "report");
  out.add("report.html", report::session_report_html(rep));
  if (progress) progress->done();
  return summary;
}

fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact,
                                    const fitting::Model5Geometry& geometry) {
  if (fit.model == fitting::ModelKind::Model5) return fitting::simulate_model5(fit.params, geometry, impact);
  return fitting::simulate(fit.model, fit.params, impact);
}

}  // namespace dropfit::pipeline
