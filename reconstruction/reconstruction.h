#pragma once
// 3-D reconstruction of points seen by two or more calibrated cameras:
// the linear DLT triangulation (Hartley & Zisserman 2003, sec. 12.2) in
// least squares over all cameras that see the point, undistorting first when
// a camera has lens distortion, optionally refined by minimising the
// reprojection error (Gauss-Newton). A point seen by fewer than two cameras
// in a frame is a gap (NaN), never interpolated. The per-point method lives
// in calibration/triangulation.h (calibrate() needs it for its check
// markers, and this library depends on calibration); this stage applies it
// to whole trials.
#include <Eigen/Core>
#include <vector>

#include "calibration/calibration.h"
#include "calibration/triangulation.h"

namespace dropfit::reconstruction {

using calibration::Triangulation;  // lab_m, residual_px (RMS reprojection error), n_cameras

// image_px[i] is the pixel in cameras[i], NaN when not seen. Throws
// dropfit::Error when the two lengths differ. Same as calibration::triangulate.
Triangulation triangulate(const std::vector<calibration::Camera>& cameras,
                          const std::vector<Eigen::Vector2d>& image_px, bool refine = true);

struct Trajectories {
  // n_frames x (3 * n_points): x, y, z of point p in columns 3p..3p+2; NaN in gaps.
  Eigen::MatrixXd lab_m;
  // n_frames x n_points RMS reprojection residual; NaN in gaps.
  Eigen::MatrixXd residual_px;
  int n_frames() const { return static_cast<int>(residual_px.rows()); }
  int n_points() const { return static_cast<int>(residual_px.cols()); }
  Eigen::Vector3d point(int frame, int p) const { return lab_m.row(frame).segment<3>(3 * p).transpose(); }
};

// uv_px in the DLTdv layout of core/session.h (MarkerTracks2D::uv_px):
// n_frames x (2 * n_points * cameras.size()), u of point p in camera c in
// column 2 (p n_cameras + c), v in the next. Throws dropfit::Error when the
// column count does not match or there are no cameras.
Trajectories reconstruct(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                         int n_points, bool refine = true);

}  // namespace dropfit::reconstruction
