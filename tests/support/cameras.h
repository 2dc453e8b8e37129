#pragma once
// A small synthetic two-camera calibration scene with known truth, for tests
// and benchmarks: two pinhole cameras about 86 degrees apart (as in Mills,
// Pain & Yeadon 2006), 1024 x 1024 px, looking down at the mat volume around
// the lab origin (x along the mat's length, y across, z up, metres), and a
// 20-marker calibration structure of five vertical rods over x in
// [-0.45, 0.45], y in [-0.3, 0.3], z in [0, 0.8] m whose markers alternate
// fit, check, fit, ... in id order.
//
// The truth projection is written here independently of calibration/:
// K [R | -R C] with Bouguet's distortion (k1 k2 p1 p2 k3, OpenCV's order and
// signs, radius normalised by the focal length) about the true principal
// point. Optional Gaussian digitising noise with a fixed seed.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <algorithm>
#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "calibration/calibration.h"

namespace dropfit::testsupport {

struct TrueCamera {
  std::string name;
  Eigen::Vector3d centre_m;
  Eigen::Matrix3d cam_from_lab;  // rows: image right, image down, viewing direction
  double focal_px = 1100.0;
  Eigen::Vector2d principal_px{512.0, 512.0};
  std::array<double, 5> distortion{};  // k1 k2 p1 p2 k3
  int width_px = 1024;
  int height_px = 1024;

  // The pinhole part, K [R | -R C].
  Eigen::Matrix<double, 3, 4> image_from_lab() const {
    Eigen::Matrix3d K;
    K << focal_px, 0.0, principal_px.x(), 0.0, focal_px, principal_px.y(), 0.0, 0.0, 1.0;
    Eigen::Matrix<double, 3, 4> Rt;
    Rt << cam_from_lab, -cam_from_lab * centre_m;
    return K * Rt;
  }

  // Pixel of a lab point, distortion included.
  Eigen::Vector2d project(const Eigen::Vector3d& lab_m) const {
    const Eigen::Vector3d c = cam_from_lab * (lab_m - centre_m);
    const double x = c.x() / c.z(), y = c.y() / c.z();
    const double r2 = x * x + y * y;
    const auto& [k1, k2, p1, p2, k3] = distortion;
    const double radial = 1.0 + k1 * r2 + k2 * r2 * r2 + k3 * r2 * r2 * r2;
    const double xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    const double yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    return principal_px + focal_px * Eigen::Vector2d(xd, yd);
  }

  bool in_image(const Eigen::Vector2d& px) const {
    return px.x() >= 0.0 && px.y() >= 0.0 && px.x() <= width_px && px.y() <= height_px;
  }

  // The same camera as calibration/ stores it (exact DLT and distortion).
  calibration::Camera as_camera() const {
    calibration::Camera camera = calibration::Camera::from_image_from_lab(name, image_from_lab());
    if (distortion != std::array<double, 5>{}) {
      camera.distortion.assign(distortion.begin(), distortion.end());
      camera.principal_point_px = principal_px;
      camera.focal_px = focal_px;
    }
    return camera;
  }
};

// A camera at `centre_m` looking at `target_m`, lab z up.
inline TrueCamera look_at(std::string name, const Eigen::Vector3d& centre_m, const Eigen::Vector3d& target_m) {
  TrueCamera camera;
  camera.name = std::move(name);
  camera.centre_m = centre_m;
  const Eigen::Vector3d forward = (target_m - centre_m).normalized();
  const Eigen::Vector3d right = forward.cross(Eigen::Vector3d::UnitZ()).normalized();
  const Eigen::Vector3d down = forward.cross(right);
  camera.cam_from_lab.row(0) = right.transpose();
  camera.cam_from_lab.row(1) = down.transpose();
  camera.cam_from_lab.row(2) = forward.transpose();
  return camera;
}

// Two cameras whose optical axes are 86 degrees apart, 1.4 m (horizontally)
// from the middle of the volume and 0.9 m above it, focal lengths 1150 and
// 1130 px (48 degree fields of view), principal points a few pixels off
// centre; the volume fills the image to within about 40 px of its edges, so
// 1 px is about 1.3 mm in the lab. k1 (and k2) set the same radial
// distortion on both; -0.2 pulls the image edges in by about 4 % (20 px) and
// the corners by 8 % (58 px), a wide-angle lens.
inline std::vector<TrueCamera> two_cameras(double k1 = 0.0, double k2 = 0.0) {
  const Eigen::Vector3d target(0.0, 0.0, 0.30);
  const double distance = 1.4, height = 0.9;
  // Half the azimuth difference that puts the optical axes 86 degrees apart:
  // cos 86 = cos^2(e) cos(2 a) + sin^2(e), e the elevation of the view.
  const double elevation = std::atan2(height, distance);
  const double cos_2a = (std::cos(86.0 * std::numbers::pi / 180.0) - std::pow(std::sin(elevation), 2)) /
                        std::pow(std::cos(elevation), 2);
  const double half_angle = 0.5 * std::acos(cos_2a);
  std::vector<TrueCamera> cameras;
  for (int side : {-1, 1}) {
    const Eigen::Vector3d centre =
        target + Eigen::Vector3d(side * distance * std::sin(half_angle), -distance * std::cos(half_angle), height);
    TrueCamera camera = look_at(side < 0 ? "cam1" : "cam2", centre, target);
    camera.principal_px = side < 0 ? Eigen::Vector2d(509.0, 516.0) : Eigen::Vector2d(515.5, 507.0);
    camera.focal_px = side < 0 ? 1150.0 : 1130.0;
    camera.distortion = {k1, k2, 0.0, 0.0, 0.0};
    cameras.push_back(camera);
  }
  return cameras;
}

// The 20-marker structure: five vertical rods (the four corners of the mat
// area and the middle of its far edge), four markers each at heights
// staggered so that the alternating fit markers (c01, c03, ...) and check
// markers (c02, c04, ...) both span the whole height.
inline std::vector<calibration::Marker> calibration_markers() {
  const std::array<Eigen::Vector2d, 5> rods = {Eigen::Vector2d(-0.45, -0.30), Eigen::Vector2d(0.45, -0.30),
                                               Eigen::Vector2d(0.45, 0.30), Eigen::Vector2d(-0.45, 0.30),
                                               Eigen::Vector2d(0.0, 0.30)};
  const std::array<std::array<double, 4>, 2> heights = {{{0.0, 0.25, 0.55, 0.8}, {0.8, 0.55, 0.25, 0.0}}};
  std::vector<calibration::Marker> markers;
  for (int r = 0; r < 5; ++r) {
    for (int k = 0; k < 4; ++k) {
      const int i = static_cast<int>(markers.size());
      const double z = heights[r % 2][k] + 0.02 * r;  // rods' markers not all at the same heights
      const std::string id = (i + 1 < 10 ? "c0" : "c") + std::to_string(i + 1);
      markers.push_back({id, Eigen::Vector3d(rods[r].x(), rods[r].y(), std::min(z, 0.8)), i % 2 == 1});
    }
  }
  return markers;
}

// Gaussian pixel noise with a fixed seed.
class PixelNoise {
 public:
  PixelNoise(double sigma_px, unsigned seed) : sigma_px_(sigma_px), engine_(seed) {}
  Eigen::Vector2d operator()() {
    if (sigma_px_ <= 0.0) return Eigen::Vector2d::Zero();
    return {sigma_px_ * normal_(engine_), sigma_px_ * normal_(engine_)};
  }

 private:
  double sigma_px_;
  std::mt19937 engine_;
  std::normal_distribution<double> normal_;
};

// Every marker as each camera sees it, with noise.
inline std::vector<calibration::CameraView> observe(const std::vector<TrueCamera>& cameras,
                                                    const std::vector<calibration::Marker>& markers,
                                                    double noise_px = 0.0, unsigned seed = 1) {
  PixelNoise noise(noise_px, seed);
  std::vector<calibration::CameraView> views;
  for (const auto& camera : cameras) {
    calibration::CameraView view{camera.name, {}};
    for (const auto& m : markers) view.observations.emplace_back(m.id, camera.project(m.lab_m) + noise());
    views.push_back(view);
  }
  return views;
}

// Points on an n x n x n grid over the calibrated volume.
inline std::vector<Eigen::Vector3d> volume_grid(int n = 5) {
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j)
      for (int k = 0; k < n; ++k) {
        const double a = static_cast<double>(i) / (n - 1), b = static_cast<double>(j) / (n - 1),
                     c = static_cast<double>(k) / (n - 1);
        points.emplace_back(-0.45 + 0.9 * a, -0.30 + 0.6 * b, 0.8 * c);
      }
  return points;
}

}  // namespace dropfit::testsupport
