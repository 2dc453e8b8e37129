#pragma once
// 3-D reconstruction of points seen by two or more calibrated cameras:
// the linear DLT triangulation (Hartley & Zisserman 2003, sec. 12.2) in
// least squares over all cameras that see the point, optionally refined by
// minimising the reprojection error (Gauss-Newton). A point seen by fewer
// than two cameras in a frame is a gap (NaN), never interpolated.
#include <Eigen/Core>
#include <limits>
#include <vector>

#include "calibration/calibration.h"

namespace dropfit::reconstruction {

struct Triangulation {
  Eigen::Vector3d lab_m = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  double residual_px = std::numeric_limits<double>::quiet_NaN();  // RMS reprojection error
  int n_cameras = 0;
};

// image_px[i] is the pixel in cameras[i], NaN when not seen.
Triangulation triangulate(const std::vector<calibration::Camera>& cameras,
                          const std::vector<Eigen::Vector2d>& image_px, bool refine = true);

struct Trajectories {
  // n_frames x (3 * n_points): x, y, z of point p in columns 3p..3p+2; NaN in gaps.
  Eigen::MatrixXd lab_m;
  // n_frames x n_points RMS reprojection residual; NaN in gaps.
  Eigen::MatrixXd residual_px;
  int n_points() const { return static_cast<int>(residual_px.cols()); }
  Eigen::Vector3d point(int frame, int p) const { return lab_m.row(frame).segment<3>(3 * p).transpose(); }
};

// uv_px in the DLTdv layout of capture/session.h (MarkerTracks2D::uv_px).
Trajectories reconstruct(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                         int n_points, bool refine = true);

}  // namespace dropfit::reconstruction
