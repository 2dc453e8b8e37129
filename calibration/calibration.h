#pragma once
// Camera calibration by the 11-parameter direct linear transformation (DLT)
// (Abdel-Aziz & Karara 1971), solved linearly with Hartley's coordinate
// normalisation (Hartley 1997, "In defense of the eight-point algorithm")
// and refined by minimising the reprojection error with Ceres.
//
//   u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)
//   v = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)
//
// so image_from_lab = [L1..L4; L5..L8; L9 L10 L11 1] (3 x 4, homogeneous).
// Pixels top-left origin, v down; lab in metres.
//
// Optional lens distortion (the "dlt16" model): Bouguet's k1, k2, p1, p2, k3
// applied to the DLT-projected point about the principal point (u0, v0)
// estimated from the DLT, with the radius normalised by the focal length.
#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

namespace dropfit::calibration {

using Dlt11 = Eigen::Matrix<double, 11, 1>;

struct Camera {
  std::string name;
  Dlt11 dlt = Dlt11::Zero();
  // Empty, or k1 k2 p1 p2 k3 (see above).
  std::vector<double> distortion;
  Eigen::Vector2d principal_point_px = Eigen::Vector2d::Zero();  // used with distortion
  double focal_px = 1.0;                                          // used with distortion

  Eigen::Matrix<double, 3, 4> image_from_lab() const;
  // Projects a lab point to pixels (with distortion when present).
  Eigen::Vector2d project(const Eigen::Vector3d& lab_m) const;
  // Removes the lens distortion from a measured pixel (identity without it).
  Eigen::Vector2d undistort(const Eigen::Vector2d& image_px) const;
};

// One correspondence of a calibration marker in one camera.
struct Correspondence {
  std::string id;
  Eigen::Vector3d lab_m;
  Eigen::Vector2d image_px;
};

struct DltOptions {
  bool refine = true;            // Ceres refinement of the reprojection error
  bool fit_distortion = false;   // add k1 k2 p1 p2 k3 (dlt16)
};

struct DltFit {
  Camera camera;
  double fit_rms_px = 0.0;
  int n_fit_points = 0;
  std::vector<Eigen::Vector2d> residuals_px;  // per fit correspondence, measured minus projected
};

// Throws dropfit::Error when fewer than 6 points are given or they are
// (nearly) coplanar, saying which.
DltFit fit_dlt(const std::string& camera_name, const std::vector<Correspondence>& points,
               const DltOptions& options = {});

// ---- The whole calibration with its accuracy report ----------------------

struct Marker {
  std::string id;
  Eigen::Vector3d lab_m;
  bool is_check = false;  // held out from the fit
};

struct CameraView {
  std::string name;
  // Observed markers: id -> pixel. Markers a camera cannot see are absent.
  std::vector<std::pair<std::string, Eigen::Vector2d>> observations;
};

struct CheckPoint {
  std::string id;
  Eigen::Vector3d error_m;  // reconstructed minus known, lab frame
};

struct LeaveOneOut {
  std::string id;
  double residual_m = 0.0;  // 3-D error of this fit marker when left out of the fit
};

struct CalibrationOptions {
  DltOptions dlt;
  // A fit marker is named as an outlier when its leave-one-out residual
  // exceeds this many times the median of the others (and 2 mm).
  double outlier_ratio = 5.0;
};

struct CalibrationResult {
  std::vector<DltFit> cameras;
  std::vector<CheckPoint> check_points;
  Eigen::Vector3d check_rms_m = Eigen::Vector3d::Zero();
  double check_max_m = 0.0;  // largest per-axis absolute error
  std::vector<LeaveOneOut> leave_one_out;
  std::vector<std::string> outliers;  // fit markers whose LOO residual stands out

  std::string report() const;  // a few human lines
};

CalibrationResult calibrate(const std::vector<Marker>& markers, const std::vector<CameraView>& views,
                            const CalibrationOptions& options = {});

}  // namespace dropfit::calibration
