#pragma once
// One session, one state, built stage by stage.
//
//   read -> calibration -> reconstruction -> trials -> fits -> loop
//
// Every command is a view of this state: `reconstruct` stops after the
// reconstruction, `process`, `fit`, `diagnose` and `run` build it through the
// loop, so a trial gets the same verdict, impact-velocity interval and clock
// offset from every command. The state is plain data; nothing here writes a
// file (pipeline/outputs.h turns a state into an OutputSet, which the
// commands commit).
//
// What each stage adds:
//   calibration     the calibration stage's choice of camera model (outliers
//                   and lens distortion decided by cross-validation), or the
//                   manifest's DLT coefficients checked on the frame
//   reconstruction  every trial's 3-D trajectories with that camera model
//   trials          the force plate, synchronisation, impact velocity with its
//                   95 % interval (calibration scale included), deformation,
//                   tilt, the calibration gates and acceptance
//   fits            the mat models on the accepted trials
//   loop            closing the loop (diagnosis/): effects named and their
//                   corrections; when the loop's final model (the closed
//                   loop's when it kept mat effects, else Model 4) does not
//                   reach the noise, Model 6 is fitted and chosen when it
//                   predicts the held-out trials better (model6_stage.h);
//                   the final model places each trial's contact on the
//                   force clock, which gives the trial's clock offset
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "capture/session.h"
#include "core/progress.h"
#include "diagnosis/diagnosis.h"
#include "fitting/fit.h"
#include "fitting/models.h"
#include "pipeline/model6_stage.h"

namespace dropfit::pipeline {

enum class Stage { Read = 0, Calibration, Reconstruction, Trials, Fits, Loop };

// The whole session: what capture read, and what every stage made of it
// (diagnosis::SessionData is the part the loop reads).
struct SessionState : diagnosis::SessionData {
  Session session;              // the inputs as read (manifest, calibration files, tracks, force records)
  Stage reached = Stage::Read;  // the last stage built
  std::vector<fitting::ModelKind> models_asked;  // the fits stage's models
  // Those of them build() fits after the loop, on the force it leaves (only
  // the loop's baseline, Model 4, is fitted before it).
  std::vector<fitting::ModelKind> models_after_loop;
  std::optional<diagnosis::DiagnosisResult> loop;  // when the loop ran
  // Model 6 when the loop's final model did not reach the noise (model6_stage.h).
  std::optional<Model6Stage> model6;
  std::vector<std::string> notes;  // rejected trials, stages that could not run, corrections made
  // The current fits' own notes (failed fits, fit warnings), held apart so a
  // refit replaces them; fit_notes_at is where they fall among `notes`.
  std::vector<std::string> fit_notes;
  std::size_t fit_notes_at = 0;
  int failed_fits = 0;
  // Every note in the order the stages made them (the fits' at fit_notes_at).
  std::vector<std::string> all_notes() const;

  int accepted() const;
  // The final lumped model: the closed loop's fit when the loop kept mat
  // effects, else the Model 4 fit, else the last model fitted; null before
  // the fits. It is the session's final model unless final_model6() is set.
  const fitting::FitResult* final_fit() const;
  // Model 6 when it was chosen over final_fit() by held-out prediction (the
  // session's final model then), else null.
  const fitting::Model6FitResult* final_model6() const;
  // "model6" when Model 6 is the final model, "closed_loop" when the loop's
  // fit is, else the final fit's model name.
  std::string final_label() const;
};

struct BuildOptions {
  Stage upto = Stage::Loop;
  std::vector<fitting::ModelKind> models = {fitting::ModelKind::Model1, fitting::ModelKind::Model2,
                                            fitting::ModelKind::Model3, fitting::ModelKind::Model4,
                                            fitting::ModelKind::Model5};
  int threads = 1;            // fits in parallel
  double max_tilt_deg = 0.0;  // > 0: reject trials tilting more (else the trial stage's default)
  std::function<void(const std::string&)> say = {};  // progress (may be empty)
};

// Reads the session folder and builds it up to `options.upto`. Throws
// dropfit::Error when the session as a whole cannot be processed
// (unreadable input, no calibration); a bad trial is rejected with its
// reason and the rest goes on; a failed fit is a note.
SessionState build(const std::string& session_dir, const BuildOptions& options = {});
// The same from a session already read.
SessionState build(Session session, const BuildOptions& options = {});

// The stages one at a time (each needs the one before; build() calls them).
void calibrate(SessionState& state);
void reconstruct(SessionState& state);
void analyse_trials(SessionState& state, double max_tilt_deg = 0.0,
                    const std::function<void(const std::string&)>& say = {});
void fit_models(SessionState& state, const std::vector<fitting::ModelKind>& models, int threads = 1,
                const std::function<void(const std::string&)>& say = {});
void close_loop(SessionState& state);
// When the loop left a wrong time base in its remaining (force_time_base:
// the force record's declared sample rate; video_time_base: the video's
// frame rate): every accepted trial is rejected with that reason and the
// fits are dropped, since every number was read on that clock.
void reject_on_wrong_time_base(SessionState& state);
// When the loop found the mat changing between trials: the final lumped
// model becomes the loop's, each held-out trial predicted with the final
// model's stiffnesses times its own scale over the training trial's (the
// recording-order trend fitted without it, DiagnosisResult::
// trial_stiffness_scale); its contact then gives the trial's clock offset.
void predict_changing_mat(SessionState& state);
// With the final model's clock offsets in place: when they change with
// 1 / impact speed (a face or mat-top height error, not a clock; the
// screen's check, diagnosis::contact_height_reason, with a 5 mm floor) the
// loop is left unexplained with the reason, and a note says it.
void check_contact_height(SessionState& state);
// The held-out residual of the final lumped model (and of Model 6 when it
// was fitted) mapped against deflection, its rate, the time since contact
// and recording order (diagnosis::map_residual) into state.loop; close_loop
// calls it last.
void map_final_residuals(SessionState& state);
// Corrects every trial's force (series, peak, noise; the plate's own peak
// kept beside it) and the fits' data by a plate gain or drift, and refits the
// models asked on it. Nothing happens for the identity correction.
void apply_plate_correction(SessionState& state, const diagnosis::PlateCorrection& correction);

// The fit data as apply_plate_correction leaves them (every trial, in the
// state's order), without changing the state.
std::vector<fitting::TrialData> corrected_fit_data(const SessionState& state,
                                                   const diagnosis::PlateCorrection& correction);

// The fitter's options for `model` with the manifest's layer masses (top =
// every layer above the last, bottom = the last) and Model 5's geometry.
fitting::FitOptions fit_options(const Manifest& manifest, fitting::ModelKind model);

// The main job on one session (build through the loop), for `run`, the
// Python module and the benchmarks.
struct RunSummary {
  std::string session;
  int trials = 0, accepted = 0;
  int failed_fits = 0;
  bool final_model = false;  // a canonical model was fitted
  std::vector<std::string> notes;
};
RunSummary summarise(const SessionState& state);

// Simulates an impact with a fitted parameter file's model (Models 1-5;
// Model 5 with its default geometry).
fitting::Simulation simulate_fitted(fitting::ModelKind model, const fitting::MatParams& params,
                                    const fitting::Impact& impact, const fitting::Model5Geometry& geometry = {});
// ... and with a Model 6 fit's parameters and column.
fitting::Simulation simulate_fitted(const fitting::Model6Params& params, const fitting::Model6Geometry& geometry,
                                    const fitting::Impact& impact);

}  // namespace dropfit::pipeline
