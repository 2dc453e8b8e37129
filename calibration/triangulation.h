#pragma once
// Triangulation of one point seen by two or more calibrated cameras, shared
// by calibrate() (check markers, leave-one-out) and reconstruction/ (which
// depends on this library and re-exports it as reconstruction::triangulate).
//
// 1. Each measured pixel is undistorted (Camera::undistort) when its camera
//    has lens distortion.
// 2. Linear least squares: the inhomogeneous DLT reconstruction
//    (Abdel-Aziz & Karara 1971; Hartley & Zisserman 2003, sec. 12.2) with
//    P = image_from_lab, two equations per camera,
//      (P0 - u P2) . [X; 1] = 0,   (P1 - v P2) . [X; 1] = 0,
//    solved for X by the 3 x 3 normal equations (by cofactors: fast).
// 3. Optional Gauss-Newton refinement of the sum of squared reprojection
//    errors (in distortion-free pixels), which weights the cameras by their
//    depth as the linear form does not (H&Z sec. 12.4's "gold standard"
//    objective); it stops when a step is below 1e-7 m or after 10 steps.
//
// residual_px is the RMS over the cameras used of the distance between the
// measured pixel and the point's projection (Camera::project, distortion
// included). A camera whose pixel is not finite is not used; fewer than two
// used cameras, or (nearly) parallel rays, give a gap: NaN position and
// residual. Plain Eigen, fixed-size, no allocation for up to 16 cameras.
#include <Eigen/Core>
#include <limits>
#include <span>

#include "calibration/calibration.h"

namespace dropfit::calibration {

struct Triangulation {
  Eigen::Vector3d lab_m = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  double residual_px = std::numeric_limits<double>::quiet_NaN();  // RMS reprojection error
  int n_cameras = 0;  // cameras with a finite pixel
};

// image_px[i] is the measured pixel in cameras[i], NaN when not seen; the two
// spans must have the same length (asserted).
Triangulation triangulate(std::span<const Camera> cameras, std::span<const Eigen::Vector2d> image_px,
                          bool refine = true);

}  // namespace dropfit::calibration
