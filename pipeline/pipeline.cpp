#include "pipeline/pipeline.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

#include "capture/io.h"
#include "core/error.h"
#include "core/parallel.h"
#include "diagnosis/model_choice.h"
#include "pipeline/contact_height.h"
#include "pipeline/outputs.h"
#include "pipeline/wiring.h"

namespace dropfit::pipeline {
namespace {

void require(const SessionState& state, Stage before, const char* what) {
  if (static_cast<int>(state.reached) < static_cast<int>(before))
    throw Error(fmt::format("pipeline: {} needs the stage before it built first", what));
}

// 3-D markers an optoelectronic system measured (markers.c3d) as the
// reconstruction stage's trajectories: positions as given, gaps where the
// system lost a marker; no reprojection residual (NaN: there are no
// camera images to reproject into).
reconstruction::Trajectories markers_as_trajectories(const Eigen::MatrixXd& xyz_m) {
  reconstruction::Trajectories t;
  t.lab_m = xyz_m;
  t.residual_px = Eigen::MatrixXd::Constant(xyz_m.rows(), xyz_m.cols() / 3, std::numeric_limits<double>::quiet_NaN());
  return t;
}

}  // namespace

int SessionState::accepted() const {
  int n = 0;
  for (const auto& t : trials) n += t.result.accepted ? 1 : 0;
  return n;
}

const fitting::FitResult* SessionState::final_fit() const {
  if (loop && loop->mat_fit) return &*loop->mat_fit;
  if (const auto* f = fit(fitting::ModelKind::Model4)) return f;
  return fits.empty() ? nullptr : &fits.back();
}

const fitting::Model6FitResult* SessionState::final_model6() const {
  return model6 && model6->chosen && model6->fit ? &*model6->fit : nullptr;
}

std::vector<std::string> SessionState::all_notes() const {
  const auto at = notes.begin() + static_cast<std::ptrdiff_t>(std::min(fit_notes_at, notes.size()));
  std::vector<std::string> all(notes.begin(), at);
  all.insert(all.end(), fit_notes.begin(), fit_notes.end());
  all.insert(all.end(), at, notes.end());
  return all;
}

std::string SessionState::final_label() const {
  if (final_model6()) return "model6";
  if (loop && loop->mat_fit) return "closed_loop";
  const auto* f = final_fit();
  return f ? fitting::model_name(f->model) : "";
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

void calibrate(SessionState& state) {
  const Manifest& man = state.session.manifest;
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
  if (state.session.calibration_needed()) {
    state.calibration = choose_calibration(state.session);
  } else {
    // Every trial brings its own 3-D markers (markers.c3d) and the session
    // holds no calibration: there are no cameras to calibrate.
    state.notes.push_back(
        "calibration: none; every trial brings 3-D markers from an optoelectronic system (markers.c3d)");
  }
  state.reached = Stage::Calibration;
}

namespace {

// The manifest's name of tracked point p, or its number.
std::string point_label(const Manifest& man, int p) {
  const auto& names = man.video.points;
  return static_cast<std::size_t>(p) < names.size() ? names[static_cast<std::size_t>(p)]
                                                   : fmt::format("point {}", p + 1);
}

// Cameras a fraction of a frame apart (reconstruction::SubframeOffset):
// camera 2's pixels are moved to camera 1's instants, their epipolar series
// with them, and the note says by how much. Not where a whole-frame lag is
// found (the trial is rejected for it, trial::apply_calibration_gates), nor
// where the rays do not meet at all (reconstruction::rays_meet), nor with
// more than two cameras.
void align_subframe(SessionState& state, const TrialRecording& trial,
                    const std::vector<calibration::Camera>& cameras,
                    const std::vector<reconstruction::CameraLag>& lags, Eigen::MatrixXd& uv_px,
                    std::vector<reconstruction::EpipolarSeries>& series) {
  if (cameras.size() != 2 || !reconstruction::rays_meet(series)) return;
  for (const auto& lag : lags)
    if (lag.desynchronised() || lag.changes_part_way()) return;
  const int n_points = trial.tracks.n_points();
  const reconstruction::SubframeOffset offset = reconstruction::subframe_offset(series);
  if (!offset.significant()) return;
  uv_px = reconstruction::resample_camera(uv_px, n_points, 2, 1, offset.rows);
  series = reconstruction::epipolar_series(cameras, uv_px, n_points);
  const reconstruction::SubframeOffset after = reconstruction::subframe_offset(series);
  state.notes.push_back(fmt::format(
      "trial {}: camera {} shows each instant {:.2f} +- {:.2f} frames {} camera {} (the cameras are not genlocked: the "
      "rays through the moving markers miss by that fraction of their image velocity, {:.2f} px RMS from the epipolar "
      "lines, {:.2f} px without it); its pixels are interpolated to camera {}'s instants ({:.2f} px RMS after)",
      trial.spec.id, cameras[1].name, std::abs(offset.rows), offset.se_rows, offset.rows > 0.0 ? "after" : "before",
      cameras[0].name, offset.rms_before_px, offset.rms_after_px, cameras[0].name, after.rms_before_px));
}

// A marker digitised on the wrong point in one camera for a stretch
// (reconstruction::MarkerSlip): its positions there are not where it was, in
// 3-D, whichever camera slipped; they become gaps, and the note says so.
void leave_slips_as_gaps(SessionState& state, const TrialRecording& trial,
                         const std::vector<reconstruction::EpipolarSeries>& series,
                         reconstruction::Trajectories& markers) {
  const double rate_hz = state.session.manifest.video.frame_rate_hz;
  const int trigger = state.session.manifest.video.trigger_frame;
  for (const auto& slip : reconstruction::marker_slips(series)) {
    const int n = slip.last_row - slip.first_row + 1;
    markers.lab_m.block(slip.first_row, 3 * slip.point, n, 3).setConstant(std::numeric_limits<double>::quiet_NaN());
    markers.residual_px.block(slip.first_row, slip.point, n, 1).setConstant(std::numeric_limits<double>::quiet_NaN());
    markers.slips.push_back(slip);
    const std::string name = point_label(state.session.manifest, slip.point);
    state.notes.push_back(fmt::format(
        "trial {}: {} is digitised off its point in one of the cameras in rows {}-{} ({:+.1f} to {:+.1f} ms on the "
        "video clock): the rays through it step {:+.2f} px off each other there and back after (the distance from "
        "the epipolar line, noise {:.2f} px; {:.0f} SEs), so a click or a tracker slipped; its positions in those "
        "rows are left as gaps",
        trial.spec.id, name, slip.first_row + 1, slip.last_row + 1, 1e3 * (slip.first_row - trigger) / rate_hz,
        1e3 * (slip.last_row - trigger) / rate_hz, slip.step_px, slip.noise_px, std::abs(slip.z)));
  }
}

}  // namespace

void reconstruct(SessionState& state) {
  require(state, Stage::Calibration, "reconstruction");
  const auto cameras = cameras_of(state.calibration.after);
  state.trials.clear();
  for (const auto& trial : state.session.trials) {
    diagnosis::TrialState& t = state.trials.emplace_back();
    t.result.id = trial.spec.id;
    if (trial.has_3d_markers()) {
      t.trajectories = markers_as_trajectories(trial.markers_xyz_m);
      continue;
    }
    const int n_points = trial.tracks.n_points();
    // Whether the cameras' rows are the same instants, on the impactor's
    // markers (the ones that move): trial::apply_calibration_gates judges a
    // whole-frame lag; a fraction of a frame is taken out here.
    std::vector<reconstruction::CameraLag> lags;
    Eigen::MatrixXd uv = trial.tracks.uv_px;
    std::vector<reconstruction::EpipolarSeries> series;  // the rays' checks, cameras 1 and 2
    if (cameras.size() >= 2) {
      lags = reconstruction::camera_lags(cameras, uv, n_points,
                                         trial_options(state.session.manifest, trial.spec.id).base_markers);
      series = reconstruction::epipolar_series(cameras, uv, n_points);
      align_subframe(state, trial, cameras, lags, uv, series);
    }
    t.trajectories = reconstruction::reconstruct(cameras, uv, n_points);
    t.trajectories.camera_lags = std::move(lags);
    leave_slips_as_gaps(state, trial, series, t.trajectories);
  }
  state.reached = Stage::Reconstruction;
}

void analyse_trials(SessionState& state, double max_tilt_deg, const std::function<void(const std::string&)>& say) {
  require(state, Stage::Reconstruction, "trial analysis");
  const Manifest& man = state.session.manifest;
  // Trials measured through a calibration that failed its own checks, or
  // whose markers reproject far beyond it, are rejected (trial.h's gates);
  // every velocity interval carries the calibration's vertical scale.
  double z_min = std::numeric_limits<double>::infinity(), z_max = -z_min;
  for (const auto& m : state.session.frame) z_min = std::min(z_min, m.lab_m.z()), z_max = std::max(z_max, m.lab_m.z());
  const auto quality = trial::calibration_quality(state.calibration.after, z_max - z_min);
  trial::CalibrationQuality no_cameras;
  no_cameras.unchecked_reason =
      "the markers come from an optoelectronic system (markers.c3d) whose calibration dropfit cannot check";
  no_cameras.declared_term = false;
  state.fit_data.clear();
  for (std::size_t i = 0; i < state.session.trials.size(); ++i) {
    const TrialRecording& recording = state.session.trials[i];
    diagnosis::TrialState& t = state.trials[i];
    if (say) say(fmt::format("trial {} ({}/{})", recording.spec.id, i + 1, state.session.trials.size()));
    trial::TrialOptions options = trial_options(man, recording.spec.id);
    if (max_tilt_deg > 0.0) options.max_tilt_deg = max_tilt_deg;
    TrialOutcome outcome = analyse_trial(man, recording, t.trajectories, options);
    // A trial with its own 3-D markers was not measured through the cameras:
    // the calibration's gates and scale error are not its own (trial.json's
    // calibration_uncertainty says so).
    const trial::CalibrationQuality& trial_quality = recording.has_3d_markers() ? no_cameras : quality;
    trial::apply_calibration_gates(outcome.result, t.trajectories, options, trial_quality);
    trial::add_calibration_uncertainty(outcome.result, trial_quality);
    t.result = std::move(outcome.result);
    t.force = std::move(outcome.force);
    if (!t.result.accepted && !t.trajectories.slips.empty()) {
      std::string slipped;
      for (const auto& slip : t.trajectories.slips)
        slipped += fmt::format("{}{} in rows {}-{}", slipped.empty() ? "" : ", ", point_label(man, slip.point),
                               slip.first_row + 1, slip.last_row + 1);
      t.result.reject_reason = fmt::format("markers digitised off their point in one camera, left as gaps ({}); {}",
                                           slipped, t.result.reject_reason);
    }
    state.fit_data.push_back(fitting_trial(man, t.result));
  }
  // Trials that cannot be measurements of the drops they claim (one
  // recording under two ids, a free-flight impulse balance unlike the
  // others') are rejected before anything is fitted.
  const diagnosis::ScreenResult screen = diagnosis::screen_trials(state);
  state.notes.insert(state.notes.end(), screen.notes.begin(), screen.notes.end());
  state.reached = Stage::Trials;
}

namespace {

// Fits `models` on the state's fit data, none of them among state.fits yet:
// Model 4 first (the loop's baseline), then Model 5 warm-started from its
// optimum (their parameters mean the same thing; Model 4's fit already in
// the state when it is not among `models`) with one start and few
// iterations, on the same worker (its exact derivatives split over
// FitOptions::threads); the others on the other workers meanwhile. The
// fits and failures join the state's in the order the fits stage was
// asked for, with their notes.
void add_fits(SessionState& state, const std::vector<fitting::ModelKind>& models, int threads,
              const std::function<void(const std::string&)>& say) {
  const Manifest& manifest = state.session.manifest;
  std::vector<std::optional<fitting::FitResult>> fits(models.size());
  std::vector<std::string> errors(models.size());
  auto fit_one = [&](std::size_t k, const fitting::FitOptions& options) {
    if (say) say("fitting " + fitting::model_name(models[k]));
    try {
      fits[k] = fitting::fit(state.fit_data, options);
    } catch (const std::exception& e) {
      errors[k] = e.what();
    }
  };
  std::size_t k4 = models.size();
  for (std::size_t k = 0; k < models.size(); ++k)
    if (models[k] == fitting::ModelKind::Model4) k4 = k;
  const fitting::FitResult* fitted4 = state.fit(fitting::ModelKind::Model4);
  std::vector<std::size_t> queue, fives;
  if (k4 < models.size()) queue.push_back(k4);
  for (std::size_t k = 0; k < models.size(); ++k) {
    if (models[k] == fitting::ModelKind::Model5) fives.push_back(k);
    else if (k != k4) queue.push_back(k);
  }
  auto fit_five = [&](std::size_t k) {
    auto options = fit_options(manifest, models[k]);
    const fitting::FitResult* four = k4 < models.size() ? (fits[k4] ? &*fits[k4] : nullptr) : fitted4;
    if (four) {
      options.initial = four->params;
      options.starts = 1;
      options.max_iterations = 30;
      options.first_stage_iterations = 30;  // one run of 30 iterations (no second stage)
    }
    fit_one(k, options);
  };
  // Model 5 follows Model 4 on its worker; without Model 4 to fit it runs last.
  if (k4 >= models.size())
    for (std::size_t k : fives) queue.push_back(k);
  parallel_for(queue.size(), std::max(1, threads), [&](std::size_t i) {
    const std::size_t k = queue[i];
    if (models[k] == fitting::ModelKind::Model5) {
      fit_five(k);
      return;
    }
    fit_one(k, fit_options(manifest, models[k]));
    if (k == k4)
      for (std::size_t f : fives) fit_five(f);
  });
  // Merged in the asked order; each fit's warnings and each failure noted.
  std::vector<fitting::FitResult> merged;
  std::vector<std::string> notes;
  for (const fitting::ModelKind m : state.models_asked) {
    const auto name = fitting::model_name(m);
    const auto k = static_cast<std::size_t>(std::find(models.begin(), models.end(), m) - models.begin());
    if (k < models.size() && !fits[k]) {
      notes.push_back(fmt::format("{} fit failed: {}", name, errors[k]));
      ++state.failed_fits;
      continue;
    }
    fitting::FitResult* f = k < models.size() ? &*fits[k] : nullptr;
    for (auto& earlier : state.fits)
      if (!f && earlier.model == m) f = &earlier;
    if (!f) {
      // Asked, not fitted now, and not among the fits: it failed before.
      for (const auto& n : state.fit_notes)
        if (n.rfind(name + " fit failed: ", 0) == 0) notes.push_back(n);
      continue;
    }
    for (const auto& w : f->warnings) notes.push_back(name + ": " + w);
    merged.push_back(std::move(*f));
  }
  state.fits = std::move(merged);
  state.fit_notes = std::move(notes);
}

}  // namespace

void fit_models(SessionState& state, const std::vector<fitting::ModelKind>& models, int threads,
                const std::function<void(const std::string&)>& say) {
  require(state, Stage::Trials, "fitting");
  // A refit (e.g. on plate-corrected force) replaces the earlier fits: their
  // warnings and failures go with them.
  state.fit_notes.clear();
  state.fit_notes_at = state.notes.size();
  state.failed_fits = 0;
  state.models_asked = models;
  state.models_after_loop.clear();
  state.fits.clear();
  state.reached = Stage::Fits;
  if (state.accepted() == 0) {
    state.fit_notes.push_back("no accepted trial: nothing to fit");
    return;
  }
  add_fits(state, models, threads, say);
}

namespace {

// With the loop to follow, only its baseline (Model 4) is fitted before it:
// the other models asked are fitted after it (fit_after_loop), on the force
// the loop leaves, so a plate gain or drift it removes does not make them
// twice.
void fit_baseline_first(SessionState& state, const std::vector<fitting::ModelKind>& models, int threads,
                        const std::function<void(const std::string&)>& say) {
  const bool has4 = std::find(models.begin(), models.end(), fitting::ModelKind::Model4) != models.end();
  if (!has4 || models.size() == 1) {
    fit_models(state, models, threads, say);
    return;
  }
  fit_models(state, {fitting::ModelKind::Model4}, threads, say);
  state.models_asked = models;
  for (const fitting::ModelKind m : models)
    if (m != fitting::ModelKind::Model4) state.models_after_loop.push_back(m);
}

// The models fit_baseline_first left for after the loop (none when the
// loop's plate correction refitted them all, or no trial stands).
void fit_after_loop(SessionState& state, int threads, const std::function<void(const std::string&)>& say) {
  const std::vector<fitting::ModelKind> models = std::move(state.models_after_loop);
  state.models_after_loop.clear();
  if (models.empty() || state.accepted() == 0) return;
  add_fits(state, models, threads, say);
}

}  // namespace

void close_loop(SessionState& state) {
  require(state, Stage::Fits, "closing the loop");
  state.reached = Stage::Loop;
  // Model 6 fitted beside the loop's later rounds when the lumped model
  // stays far from the noise (model6_stage.h); cancelled on leaving here
  // when not used.
  EarlyModel6 early;
  if (state.accepted() > 0) {
    try {
      diagnosis::DiagnosisOptions options;
      options.after_mat_round = [&](const fitting::FitResult& current, double force_sd, double impactor_sd,
                                    const diagnosis::PlateCorrection& correction) {
        start_model6_early(state, early, current, force_sd, impactor_sd, correction);
      };
      state.loop = diagnosis::diagnose(state, options);
      for (const auto& stage : state.loop->not_assessed)
        state.notes.push_back(fmt::format("closing the loop: {} not assessed: upstream unresolved", stage));
    } catch (const std::exception& e) {
      state.notes.push_back(fmt::format("closing the loop failed: {}", e.what()));
    }
  }
  // An instrument clock the loop showed wrong: nothing measured on it stands.
  reject_on_wrong_time_base(state);
  // What the loop found, the results use: a plate gain or drift it kept
  // corrects every trial's force and every fit (the plate's own reading
  // kept beside it), so no result stands on data the loop showed wrong.
  if (state.loop) apply_plate_correction(state, state.loop->plate_correction);
  // A mat that changes between trials: each trial predicted with its own
  // stiffness (before Model 6 is judged against the final lumped model).
  predict_changing_mat(state);
  // A final lumped model short of the noise: Model 6 may replace it.
  consider_model6(state, &early);
  // Each trial's clock offset from the contact instant the final mat model
  // placed on the force clock, replacing the plate-onset estimate, which
  // reads late on a layered mat.
  if (state.final_model6())
    apply_model6_offsets(state);
  else if (const fitting::FitResult* final_fit = state.final_fit())
    for (auto& t : state.trials) {
      apply_fitted_offset(t.result, *final_fit);
      if (final_fit->force_lowpass_hz > 0.0 && t.result.force_lowpass_source.empty()) {
        t.result.force_lowpass_hz = final_fit->force_lowpass_hz;
        t.result.force_lowpass_source = "named";
      }
    }
  check_contact_height(state);
  map_final_residuals(state);
}

void reject_on_wrong_time_base(SessionState& state) {
  if (!state.loop) return;
  std::string reason;
  for (const auto& r : state.loop->remaining)
    if (r.name == "force_time_base" || r.name == "video_time_base")
      reason += fmt::format("{}{} ({}): {}", reason.empty() ? "" : "; ", r.name,
                            r.name == "force_time_base" ? "the force record's sample rate" : "the video's frame rate",
                            r.description);
  if (reason.empty()) return;
  // Velocities, impulses, contact instants and every fitted parameter are
  // read on that clock: every trial is rejected, no model is kept.
  int rejected = 0;
  for (std::size_t i = 0; i < state.trials.size(); ++i) {
    trial::TrialResult& r = state.trials[i].result;
    if (!r.accepted) continue;
    r.accepted = false;
    r.reject_reason = "an instrument's time base is wrong, found by closing the loop over the session: " + reason;
    if (i < state.fit_data.size()) state.fit_data[i].accepted = false;
    ++rejected;
  }
  if (rejected == 0) return;
  state.fits.clear();
  state.loop->mat_fit.reset();
  state.fit_notes.clear();
  state.fit_notes.push_back("no model kept: every trial was measured on a wrong time base (" + reason + ")");
}

void predict_changing_mat(SessionState& state) {
  if (!state.loop || state.loop->trial_stiffness_scale.empty()) return;
  const fitting::FitResult* final_fit = state.final_fit();
  if (!final_fit || final_fit->train_ids.size() != 1 || final_fit->model == fitting::ModelKind::Model5) return;
  const auto& scales = state.loop->trial_stiffness_scale;
  auto scale_of = [&](const std::string& id) {
    for (const auto& [k, s] : scales)
      if (k == id) return s;
    return std::numeric_limits<double>::quiet_NaN();
  };
  // The mat effects are not judged on a changing mat, so the final lumped
  // model is the baseline's (on the plate-corrected force when corrected).
  fitting::FitOptions options = state.baseline_fit_options;
  options.model = final_fit->model;
  options.force_lowpass_hz = final_fit->force_lowpass_hz;
  fitting::FitResult changed = *final_fit;
  const std::string warning = predict_with_stiffness_scales(
      changed.trials, state.fit_data, final_fit->train_ids.front(), scale_of,
      [&](const fitting::TrialData& d, double s) {
        return fitting::predict(d, diagnosis::scaled_stiffness(final_fit->params, s), options);
      },
      "every stiffness", state.notes);
  if (warning.empty()) return;
  changed.warnings.push_back(warning);
  state.loop->mat_fit = std::move(changed);
}

void check_contact_height(SessionState& state) {
  if (!state.loop) return;
  // The final model's contact instants carry no onset lag, so the floor is
  // the 5 mm within which the surface markers' rest height is taken as the
  // mat top (trial.h).
  const std::string reason = diagnosis::contact_height_reason(state, 0.005, 4.0);
  if (reason.empty()) return;
  state.loop->remaining.push_back({"sync", "contact_height", reason});
  state.loop->unexplained = true;
  state.notes.push_back("closing the loop: " + reason);
}

void map_final_residuals(SessionState& state) {
  if (!state.loop) return;
  auto& maps = state.loop->residual_maps;
  maps.clear();
  // The final lumped model's held-out residual (what Model 6 is judged
  // against), then Model 6's own when it was fitted.
  if (const fitting::FitResult* lumped = state.final_fit()) {
    const std::string label = state.loop->mat_fit ? "closed_loop" : fitting::model_name(lumped->model);
    maps.emplace_back(label, diagnosis::map_residual(state.fit_data, lumped->trials));
  }
  if (state.model6 && state.model6->fit)
    maps.emplace_back("model6", diagnosis::map_residual(state.fit_data, state.model6->fit->trials));
}

namespace {

// What apply_plate_correction says it removed.
std::string correction_text(const diagnosis::PlateCorrection& correction) {
  return correction.drift
             ? fmt::format("plate gain {:.4g} and baseline drift {:.3g} N/s removed by closing the loop",
                           correction.gain, correction.drift_n_s)
             : fmt::format("plate gain {:.4g} removed by closing the loop", correction.gain);
}

// One trial's result with the plate's gain and drift taken out; false
// when it has no force series to correct.
bool correct_trial(trial::TrialResult& r, const diagnosis::PlateCorrection& correction) {
  if (!std::isfinite(r.contact_time_s) || r.series.t_s.size() == 0) return false;
  r.series.fz_n = correction.apply(r.series.t_s, r.series.fz_n, r.contact_time_s);
  r.peak_force_uncorrected_n = r.peak_force_n;
  if (std::isfinite(r.time_to_peak_s)) {
    const Eigen::VectorXd at = Eigen::VectorXd::Constant(1, r.contact_time_s + r.time_to_peak_s);
    r.peak_force_n = correction.apply(at, Eigen::VectorXd::Constant(1, r.peak_force_n), r.contact_time_s)[0];
  } else {
    r.peak_force_n /= correction.gain;
  }
  r.force_noise_n /= correction.gain;
  r.force_correction = correction_text(correction);
  return true;
}

}  // namespace

std::vector<fitting::TrialData> corrected_fit_data(const SessionState& state,
                                                   const diagnosis::PlateCorrection& correction) {
  std::vector<fitting::TrialData> data = state.fit_data;
  if (!correction.drift && correction.gain == 1.0) return data;
  for (std::size_t i = 0; i < state.trials.size() && i < data.size(); ++i) {
    trial::TrialResult r = state.trials[i].result;
    if (correct_trial(r, correction)) data[i] = fitting_trial(state.session.manifest, r);
  }
  return data;
}

void apply_plate_correction(SessionState& state, const diagnosis::PlateCorrection& correction) {
  if (!correction.drift && correction.gain == 1.0) return;
  const std::string what = correction_text(correction);
  for (std::size_t i = 0; i < state.trials.size(); ++i) {
    trial::TrialResult& r = state.trials[i].result;
    if (correct_trial(r, correction)) state.fit_data[i] = fitting_trial(state.session.manifest, r);
  }
  state.notes.push_back("every trial's force and every fit: " + what);
  // The fits made before the loop stood on the plate's reading: refitted.
  const std::vector<fitting::ModelKind> models = state.models_asked;
  if (!models.empty() && state.accepted() > 0) {
    const int failed_before = state.failed_fits;
    state.failed_fits = 0;
    fit_models(state, models, 2);
    state.failed_fits = std::max(failed_before, state.failed_fits);
    state.reached = Stage::Loop;
  }
}

namespace {

// The stages up to options.upto, in order.
SessionState build_stages(Session session, const BuildOptions& options) {
  SessionState state;
  state.session = std::move(session);
  const auto say = options.say;
  auto upto = [&](Stage s) { return static_cast<int>(options.upto) >= static_cast<int>(s); };
  if (upto(Stage::Calibration)) {
    if (say) say("calibrating");
    calibrate(state);
  }
  if (upto(Stage::Reconstruction)) reconstruct(state);
  if (upto(Stage::Trials)) analyse_trials(state, options.max_tilt_deg, say);
  if (upto(Stage::Loop)) {
    fit_baseline_first(state, options.models, options.threads, say);
    if (say) say("closing the loop");
    close_loop(state);
    fit_after_loop(state, options.threads, say);
  } else if (upto(Stage::Fits)) {
    fit_models(state, options.models, options.threads, say);
  }
  return state;
}

// Each rejected trial's reason, and where each trial's inputs came from.
void add_trial_notes(SessionState& state) {
  if (static_cast<int>(state.reached) >= static_cast<int>(Stage::Trials)) {
    std::vector<std::pair<std::string, report::TrialSource>> sources;
    for (std::size_t i = 0; i < state.trials.size(); ++i) {
      const trial::TrialResult& r = state.trials[i].result;
      if (!r.accepted) state.notes.push_back(fmt::format("trial {} rejected: {}", r.id, r.reject_reason));
      sources.emplace_back(r.id, trial_source(state, i));
    }
    for (auto& note : report::trial_source_notes(sources)) state.notes.push_back(std::move(note));
  }
}

}  // namespace

SessionState build(Session session, const BuildOptions& options) {
  SessionState state = build_stages(std::move(session), options);
  // A declared mat top that the surface markers and the clock offsets'
  // 1 / speed trend both contradict (contact_height.h): every trial measured
  // again from the surface markers' height, once, the correction recorded
  // as the loop's effect with the errors before and after it.
  if (const auto c = confirmed_mat_top(state)) {
    if (options.say) options.say("measuring the trials again from the mat top the surface markers show");
    Session corrected = state.session;
    corrected.manifest.forceplate.mat_top_z_m = c->surface_m;
    SessionState again = build_stages(std::move(corrected), options);
    if (again.loop) {
      const diagnosis::Effect e = mat_top_effect(*c, state, again);
      again.notes.push_back("closing the loop: " + e.evidence);
      again.loop->effects.insert(again.loop->effects.begin(), e);
      state = std::move(again);
    }
  }
  add_trial_notes(state);
  return state;
}

SessionState build(const std::string& session_dir, const BuildOptions& options) {
  if (options.say) options.say("reading " + session_dir);
  return build(capture::read_session(session_dir), options);
}

RunSummary summarise(const SessionState& state) {
  RunSummary s;
  s.session = state.session.manifest.name.empty() ? state.session.root : state.session.manifest.name;
  s.trials = static_cast<int>(state.trials.size());
  s.accepted = state.accepted();
  s.failed_fits = state.failed_fits;
  s.final_model = state.final_fit() != nullptr;
  s.notes = state.all_notes();
  return s;
}

fitting::Simulation simulate_fitted(fitting::ModelKind model, const fitting::MatParams& params,
                                    const fitting::Impact& impact, const fitting::Model5Geometry& geometry) {
  if (model == fitting::ModelKind::Model5) return fitting::simulate_model5(params, geometry, impact);
  return fitting::simulate(model, params, impact);
}

fitting::Simulation simulate_fitted(const fitting::Model6Params& params, const fitting::Model6Geometry& geometry,
                                    const fitting::Impact& impact) {
  return fitting::simulate_model6(params, geometry, impact);
}

}  // namespace dropfit::pipeline
