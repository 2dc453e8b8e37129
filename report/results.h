#pragma once
// Results as text, exactly as in docs/formats.md: JSON for
// programs, CSV for spreadsheets. Pure formatting: nothing here touches the
// disk (see report/output.h for writing).
#include <string>
#include <utility>
#include <vector>

#include "calibration/calibration.h"
#include "fitting/fit.h"
#include "fitting/models.h"
#include "reconstruction/reconstruction.h"
#include "trial/trial.h"

namespace dropfit::report {

// OUT/calibration.json ("dlt11", or "dlt16" when any camera has distortion).
std::string calibration_json(const calibration::CalibrationResult& result);

// A camera's DLT coefficients (top-left origin, v down) re-expressed for an
// image whose v is measured upwards from the bottom edge, v' = H - v (Argus,
// DLTdv 7). With D = L9 X + L10 Y + L11 Z + 1,
//   v' = H - (L5 X + L6 Y + L7 Z + L8) / D
//      = ((H L9 - L5) X + (H L10 - L6) Y + (H L11 - L7) Z + (H - L8)) / D,
// so L5' = H L9 - L5, L6' = H L10 - L6, L7' = H L11 - L7, L8' = H - L8; u and
// the denominator are unchanged. The map is its own inverse.
calibration::Dlt11 dlt_bottom_left(const calibration::Dlt11& top_left, double image_height_px);

// The DLT coefficients as an 11 x N headerless CSV, one column per camera
// (the DLTdv / easyWand / Argus convention), in the top-left image origin,
// or in the bottom-left one when bottom_left_height_px > 0 (the height H of
// the images, [video].image_height_px). Lens distortion is not in this file.
std::string dlt_coefficients_csv(const std::vector<calibration::Camera>& cameras,
                                 double bottom_left_height_px = 0.0);

// 3-D trajectories with DLTdv's xyzpts column naming (pt1_X, pt1_Y, pt1_Z,
// ...), metres in the lab frame; gaps as NaN.
std::string xyzpts_csv(const reconstruction::Trajectories& trajectories);
// Per-point RMS reprojection residual, pixels (pt1_res_px, ...).
std::string residuals_csv(const reconstruction::Trajectories& trajectories);
// DLTdv's xyzres.csv: the same residuals (pixels) with DLTdv's column names
// NAME_dltres, NAME from `point_names` (ptK when a name is missing); NaN in gaps.
std::string xyzres_csv(const reconstruction::Trajectories& trajectories,
                       const std::vector<std::string>& point_names);

// Where a trial's force record came from, for trial.json: how its trigger
// sample was found (the export's own mark, the manifest's
// pretrigger_fraction, or the data: capture's ForceRecord::trigger) and why
// it has no centre of pressure ("" when it has one); and where its 3-D
// markers came from: markers_file names the optoelectronic system's file
// (markers.c3d) read in place of reconstructing them, "" when the cameras'
// tracks were reconstructed.
struct TrialSource {
  std::string trigger;
  bool trigger_from_data = false;
  std::string cop_unavailable;
  std::string markers_file;
};
// The notes the trials' sources give the report (trial id, source): one
// line per kind of note, naming the trials it holds for.
std::vector<std::string> trial_source_notes(const std::vector<std::pair<std::string, TrialSource>>& trials);

// OUT/trials/T/trial.json and series.csv (t_s,fz_n,impactor_z_m,deformation_m,surface_z_m).
// With a source: "trigger" (text), "trigger_from_data" and
// "centre_of_pressure" (null when the record has one, else why not: grf.mot's
// point columns are then NaN) and "markers" ("reconstructed from the cameras"
// or the 3-D marker file read).
std::string trial_json(const trial::TrialResult& result, const TrialSource* source = nullptr);
std::string series_csv(const trial::Series& series);
// The session summary in the shape of the paper's Table 1, one row a trial:
// trial,accepted,impact_velocity_m_s,impact_velocity_ci_m_s,max_deformation_m,
// peak_force_n,time_to_peak_s,tilt_deg,video_offset_ms,reject_reason
std::string summary_csv(const std::vector<trial::TrialResult>& trials);

// OUT/fit.json: the model, its label (the model's name, or "closed_loop" for
// Model 4 with the effects the loop kept), training trials, canonical
// parameters (named with units, report/export.h) and per-trial errors, plus
// standard errors, identifiability and bound warnings, key characteristics
// and sensitivity.
std::string fit_json(const fitting::FitResult& fit, double impactor_mass_kg, const std::string& label = "");
// Measured and simulated series of one trial from contact:
// t_s,measured_fz_n,simulated_fz_n,measured_impactor_m,simulated_impactor_m,measured_surface_m,simulated_surface_m,
// simulated_layer1_m,simulated_layer2_m (the layers' travel, zero for a model without layers)
std::string fit_series_csv(const fitting::TrialData& measured, const fitting::TrialReport& report);

// A simulated impact: t_s,grf_n,impactor_m,surface_m.
std::string simulation_csv(const fitting::Simulation& sim);

// Number formatting shared by every CSV writer: NaN written as "NaN".
std::string csv_number(double value, int significant = 9);

}  // namespace dropfit::report
