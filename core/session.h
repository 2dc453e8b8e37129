#pragma once
// The session as read from disk (docs/formats.md), in plain
// values. Everything SI; image coordinates in pixels with the origin at the
// top-left pixel corner, v downwards (bottom-left files are converted on
// reading). Missing measurements are NaN, never zero.
#include <Eigen/Core>
#include <optional>
#include <string>
#include <vector>

namespace dropfit {

struct LayerSpec {
  std::string name;
  double thickness_m = 0.0;
  double mass_kg = 0.0;
};

struct ImpactorSpec {
  double mass_kg = 24.0;
  Eigen::Vector2d footprint_m{0.25, 0.25};
  std::vector<std::string> base_markers;
  double base_marker_height_m = 0.0;  // above the contact face
};

struct MatSpec {
  double length_m = 0.90;
  double width_m = 0.60;
  std::vector<std::string> surface_markers;
  std::vector<LayerSpec> layers;  // top to bottom
  double thickness_m() const;
  double mass_kg() const;
};

enum class ImageOrigin { TopLeft, BottomLeft };

struct VideoSpec {
  std::vector<std::string> cameras;
  double frame_rate_hz = 1000.0;
  std::vector<std::string> points;  // ptK in xypts.csv is points[K-1]
  int trigger_frame = 0;            // 0-based row of xypts.csv at the plate trigger
  ImageOrigin image_origin = ImageOrigin::TopLeft;
  std::optional<double> image_height_px;
};

struct ForcePlateSpec {
  std::string model;
  double sample_rate_hz = 1000.0;
  double trigger_threshold_n = 25.0;
  // Share of the record before the trigger sample, for exports that carry
  // no trigger (BioWare text, C3D). Absent: each such record's trigger is
  // found in its own data (capture::trigger_sample_from_data).
  std::optional<double> pretrigger_fraction;
  double a_m = 0.120;
  double b_m = 0.200;
  double az0_m = -0.040;
  double mat_top_z_m = 0.205;  // undeformed mat top in the lab frame
  int plate = 1;  // 1-based: the plate of a several-plate export (BioWare blocks, C3D FORCE_PLATFORM)
  // The charge amplifier's low-pass filter when the lab declares one (0:
  // none declared): a Butterworth of this order and corner frequency delays
  // the force by its group delay (forceplate::butterworth_delay_s).
  double lowpass_hz = 0.0;
  int lowpass_order = 2;
};

struct TrialSpec {
  std::string id;
  std::string dir;  // relative to the session folder
};

// [calibration]: an existing calibration instead of a frame (version 2).
struct CalibrationSpec {
  // Relative to the session folder; empty: calibrate from
  // calibration/frame.csv and camN.csv.
  std::string dlt_coefficients;
};

struct Manifest {
  std::string name;
  double gravity_m_s2 = 9.81;
  // Fields the lab declares outside their physical range on purpose
  // ([session] outside_physical_range, dotted names as in errors).
  std::vector<std::string> outside_physical_range;
  ImpactorSpec impactor;
  MatSpec mat;
  VideoSpec video;
  ForcePlateSpec forceplate;
  std::vector<TrialSpec> trials;
  CalibrationSpec calibration;
};

// calibration/frame.csv
enum class MarkerRole { Fit, Check };
struct CalibrationMarker {
  std::string id;
  Eigen::Vector3d lab_m;
  MarkerRole role = MarkerRole::Fit;
};

// calibration/camN.csv: one camera's digitised calibration markers.
struct CameraObservation {
  std::string id;
  Eigen::Vector2d image_px;
};
struct CalibrationImage {
  std::string camera;
  std::vector<CameraObservation> observations;
};

// trials/T/xypts.csv: digitised 2-D tracks. Column layout of `uv_px` is the
// DLTdv one: for point p (0-based) and camera c (0-based) the u column is
// 2 * (p * n_cameras + c) and v the next. NaN where not digitised.
struct MarkerTracks2D {
  std::vector<std::string> points;
  std::vector<std::string> cameras;
  Eigen::MatrixXd uv_px;  // n_frames x (2 * n_points * n_cameras)

  int n_frames() const { return static_cast<int>(uv_px.rows()); }
  int n_points() const { return static_cast<int>(points.size()); }
  int n_cameras() const { return static_cast<int>(cameras.size()); }
  int column(int point, int camera) const { return 2 * (point * n_cameras() + camera); }
  Eigen::Vector2d uv(int frame, int point, int camera) const {
    const int c = column(point, camera);
    return {uv_px(frame, c), uv_px(frame, c + 1)};
  }
};

// trials/T/force.txt, as read; converted to forces by forceplate/.
enum class ForceLayout { EightChannel, Resultants };
struct ForceRecord {
  ForceLayout layout = ForceLayout::EightChannel;
  double sample_rate_hz = 0.0;
  int pretrigger_samples = 0;   // from the header (eight-channel) or the manifest share
  std::string trigger;          // header text, e.g. "Fz > 25 N", or how the trigger sample was found; may be empty
  bool trigger_from_data = false;  // the export carried no trigger and the manifest no pretrigger_fraction
  Eigen::VectorXd t_s;          // 0 at the trigger sample: the file's times (eight-channel), or the
                                // absolute times minus that of sample pretrigger_samples (BioWare)
  // EightChannel: columns Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4 in newtons.
  // Resultants: columns Fx Fy Fz (N) Mx My Mz (N m) Ax Ay (m, converted from mm).
  // A column the export does not have (BioWare subsets, C3D TYPE 2's Ax Ay) is NaN throughout.
  Eigen::MatrixXd data;
  // The plate's a, b, az0 (m) when the file gives them (C3D FORCE_PLATFORM:ORIGIN): they
  // replace the manifest's forceplate.a_m, b_m, az0_m for this record (TYPE 2: a, b NaN).
  std::optional<Eigen::Vector3d> plate_geometry_m;
};

// DLTdv's camera frame offsets: row r of camera c in the marker table was
// digitised in that camera's video frame r + offset. DLTdv writes its rows
// already aligned, so the tracks are never shifted by them; they are kept to
// say which video frame each row came from.
struct FrameOffsets {
  // One row per marker-table row (per_frame) or one row for the whole trial;
  // one column per camera in [video].cameras order. Empty when no file.
  Eigen::MatrixXi frames;
  bool per_frame = false;
  bool empty() const { return frames.size() == 0; }
  int at(int row, int camera) const { return frames(per_frame ? row : 0, camera); }
};

// One trial's recordings as read from its folder (marker table, force file,
// DLTdv offsets), before any stage has worked on them. Not fitting::TrialData,
// the fitter's view of a processed trial.
struct TrialRecording {
  TrialSpec spec;
  MarkerTracks2D tracks;
  ForceRecord force;
  std::string xypts_path;  // the marker table read (xypts.csv or a prefixed *xypts.csv)
  // DLTdv's offsets.csv beside the marker table (empty when absent).
  FrameOffsets frame_offsets;
  // markers.c3d in place of the marker table: 3-D trajectories from an
  // optoelectronic system, lab frame, metres; n_frames x (3 n_points) with
  // point p's X Y Z in columns 3p..3p+2 ([video].points order), NaN where
  // the system lost the marker. Empty (0 rows) when the trial has a marker
  // table; then `tracks` holds it. With markers.c3d, `tracks` has the
  // manifest's points and cameras and no rows.
  std::string markers_path;
  Eigen::MatrixXd markers_xyz_m;
  bool has_3d_markers() const { return !markers_path.empty(); }
};

// 11 DLT coefficients L1..L11 of one camera, top-left image origin.
using DltCoefficients = Eigen::Matrix<double, 11, 1>;

struct Session {
  std::string root;  // folder it was read from
  Manifest manifest;
  // Empty when the manifest gives DLT coefficients and the session has no
  // calibration/frame.csv (nothing to check them with).
  std::vector<CalibrationMarker> frame;
  std::vector<CalibrationImage> images;  // one per camera, in manifest order (empty with frame)
  // From [calibration] dlt_coefficients, converted to the top-left origin:
  // one per camera in manifest order; empty when the session is calibrated
  // from its frame.
  std::vector<DltCoefficients> dlt_coefficients;
  std::vector<TrialRecording> trials;
  // True when every trial brings its own 3-D markers (markers.c3d) and the
  // session has no calibration: nothing to calibrate or reconstruct.
  bool calibration_needed() const {
    for (const TrialRecording& t : trials)
      if (!t.has_3d_markers()) return true;
    return !frame.empty() || !dlt_coefficients.empty();
  }
};

}  // namespace dropfit
