// The generator's cameras and calibration: the true pinhole cameras seen
// from the mat's -Y side, the calibration structure's markers, their noisy
// images and the calibration effects (samples/generator/synth.h).
#include <Eigen/Geometry>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "samples/generator/synth_internal.h"

namespace dropfit::synth {
namespace detail {
namespace {

// Top of the calibrated volume: the base markers over the impactor's last
// 0.5 m of fall.
double calibrated_top_m(const SynthOptions& o, double mat_top_m) {
  return mat_top_m + 0.5 + std::max(0.0, o.base_marker_height_m);
}

std::vector<TrueCamera> make_cameras(const SynthOptions& o, double mat_top_m, const std::vector<double>& distortion) {
  const double z_top = calibrated_top_m(o, mat_top_m);
  const Eigen::Vector3d target(0.0, 0.0, 0.5 * z_top);
  // Optical axes d = (cos e sin az, cos e cos az, -sin e) at az = -+a: the
  // angle g between them obeys cos g = cos^2 e cos 2a + sin^2 e.
  const double e = o.camera_elevation_deg * kDeg;
  const double cos2a = (std::cos(o.camera_angle_deg * kDeg) - std::pow(std::sin(e), 2)) / std::pow(std::cos(e), 2);
  require(std::abs(cos2a) <= 1.0, "camera angle and elevation are incompatible");
  const double a = 0.5 * std::acos(cos2a);
  const double rolls_deg[2] = {1.5, -1.0};
  const Eigen::Vector2d pp_offset[2] = {{3.7, -2.9}, {-4.1, 3.3}};

  std::vector<TrueCamera> cams(2);
  for (int i = 0; i < 2; ++i) {
    const double az = i == 0 ? -a : a;
    const Eigen::Vector3d d(std::cos(e) * std::sin(az), std::cos(e) * std::cos(az), -std::sin(e));
    const Eigen::Vector3d centre = target - o.camera_distance_m * d;
    const Eigen::Vector3d x_axis = d.cross(Eigen::Vector3d::UnitZ()).normalized();  // image u to the right
    const Eigen::Vector3d y_axis = d.cross(x_axis);                                  // image v downwards
    Eigen::Matrix3d r0;
    r0.row(0) = x_axis.transpose();
    r0.row(1) = y_axis.transpose();
    r0.row(2) = d.transpose();
    const double roll = rolls_deg[i] * kDeg;
    Eigen::Matrix3d rz;
    rz << std::cos(roll), -std::sin(roll), 0.0, std::sin(roll), std::cos(roll), 0.0, 0.0, 0.0, 1.0;
    TrueCamera& c = cams[i];
    c.cam_from_lab_r = rz * r0;
    c.centre_lab_m = centre;
    c.cam_from_lab_t = -c.cam_from_lab_r * centre;
    c.width_px = o.image_width_px;
    c.height_px = o.image_height_px;
  }
  // One focal length for both: the calibrated volume's corners reach
  // image_fill of the half-image in the tighter camera and direction.
  const double hx = 0.5 * o.mat_length_m, hy = 0.5 * o.mat_width_m;
  double focal = std::numeric_limits<double>::infinity();
  for (const TrueCamera& c : cams)
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d p((corner & 1) ? hx : -hx, (corner & 2) ? hy : -hy, (corner & 4) ? z_top : 0.0);
      const Eigen::Vector3d q = c.cam_from_lab_r * p + c.cam_from_lab_t;
      require(q.z() > 0.1, "the calibrated volume is behind a camera");
      focal = std::min(focal, o.image_fill * 0.5 * o.image_width_px / std::abs(q.x() / q.z()));
      focal = std::min(focal, o.image_fill * 0.5 * o.image_height_px / std::abs(q.y() / q.z()));
    }
  const bool distorted = std::any_of(distortion.begin(), distortion.end(), [](double k) { return k != 0.0; });
  for (int i = 0; i < 2; ++i) {
    TrueCamera& c = cams[i];
    const Eigen::Vector2d pp = Eigen::Vector2d(0.5 * o.image_width_px, 0.5 * o.image_height_px) + pp_offset[i];
    c.k << focal, 0.0, pp.x(), 0.0, focal, pp.y(), 0.0, 0.0, 1.0;
    Eigen::Matrix<double, 3, 4> rt;
    rt << c.cam_from_lab_r, c.cam_from_lab_t;
    c.camera.name = fmt::format("cam{}", i + 1);
    c.camera.dlt = dlt_from_projection(c.k * rt);
    c.camera.principal_point_px = pp;
    c.camera.focal_px = focal;
    if (distorted) c.camera.distortion = distortion;
  }
  return cams;
}

// ---- Calibration structure ------------------------------------------------
// Four corner columns of four markers each (bottom to top), then four inner
// markers at staggered heights; odd ids fit, even ids check, so that both
// halves span every column and height.
std::vector<CalibrationMarker> calibration_layout(const SynthOptions& o, double mat_top_m) {
  const double z_top = calibrated_top_m(o, mat_top_m);
  const double hx = 0.5 * o.mat_length_m - 0.03, hy = 0.5 * o.mat_width_m - 0.03;
  const double levels[4] = {0.03, 0.35 * z_top, 0.65 * z_top, z_top};
  const double columns[4][2] = {{-1, -1}, {1, -1}, {1, 1}, {-1, 1}};
  std::vector<Eigen::Vector3d> p;
  for (const auto& col : columns)
    for (int l = 0; l < 4; ++l) {
      // A few millimetres of stagger, as a real structure's rods have.
      const double jitter = 0.004 * ((l % 2) ? 1.0 : -1.0);
      p.emplace_back(col[0] * hx + jitter, col[1] * hy - jitter, std::round(levels[l] * 1000.0) / 1000.0);
    }
  p.emplace_back(0.4 * hx, 0.3 * hy, 0.5 * z_top);
  p.emplace_back(-0.4 * hx, -0.3 * hy, 0.3 * z_top);
  p.emplace_back(-0.3 * hx, 0.4 * hy, 0.8 * z_top);
  p.emplace_back(0.3 * hx, -0.4 * hy, 0.15 * z_top);
  std::vector<CalibrationMarker> markers;
  for (std::size_t i = 0; i < p.size(); ++i) {
    CalibrationMarker m;
    m.id = fmt::format("c{:02d}", i + 1);
    m.lab_m = (p[i] * 1000.0).array().round() / 1000.0;  // surveyed to the millimetre
    m.role = (i % 2 == 0) ? MarkerRole::Fit : MarkerRole::Check;
    markers.push_back(m);
  }
  return markers;
}

}  // namespace

// The true cameras, with the lens_distortion effect (k1 from its pixel size when given).
void make_true_cameras(const SynthOptions& o, double mat_top_m, const MarkerLayout& layout, SynthTruth& truth) {
  const Effects& fx = o.effects;
  const double h_base = o.base_marker_height_m;
  const Eigen::Vector3d(&base_offset)[2] = layout.base_offset;
  const Eigen::Vector2d(&mat_xy)[4] = layout.mat_xy;
  std::vector<double> distortion;
  truth.cameras = make_cameras(o, mat_top_m, {});
  double k1_lens = fx.lens_distortion_k1;
  if (fx.lens_distortion_px > 0.0) {
    // The k1 that moves the trial marker farthest from an image centre (at
    // contact: mat markers at rest, base markers over the mat top) by
    // lens_distortion_px, barrel (k1 < 0) as real lenses mostly are.
    double r_max = 0.0, focal = truth.cameras[0].camera.focal_px;
    std::vector<Eigen::Vector3d> pts{Eigen::Vector3d(base_offset[0].x(), base_offset[0].y(), mat_top_m + h_base),
                                     Eigen::Vector3d(base_offset[1].x(), base_offset[1].y(), mat_top_m + h_base)};
    for (const Eigen::Vector2d& xy : mat_xy) pts.emplace_back(xy.x(), xy.y(), mat_top_m);
    for (const TrueCamera& c : truth.cameras)
      for (const Eigen::Vector3d& p : pts)
        r_max = std::max(r_max, (pinhole_px(c, p) - c.camera.principal_point_px).norm() / c.camera.focal_px);
    require(r_max > 1e-3, "lens_distortion_px: the markers sit on the optical axis");
    // |du| = f |k1| r^3 to first order; solve f |k1| r^3 (1 + k1 r^2) = px by a few fixed-point steps.
    double k1 = -fx.lens_distortion_px / (focal * r_max * r_max * r_max);
    for (int it = 0; it < 5; ++it)
      k1 = -fx.lens_distortion_px / (focal * r_max * r_max * r_max * (1.0 + k1 * r_max * r_max));
    k1_lens = k1;
  }
  if (k1_lens != 0.0) {
    distortion = {k1_lens, o.extra_distortion[0], o.extra_distortion[1], o.extra_distortion[2],
                  o.extra_distortion[3]};
    for (TrueCamera& c : truth.cameras) c.camera.distortion = distortion;
    truth.effects.push_back(
        {"calibration", "lens_distortion", k1_lens, "k1",
         fmt::format("Bouguet k1 k2 p1 p2 k3 = {} on both cameras{}", fmt::join(distortion, " "),
                     fx.lens_distortion_px > 0.0
                         ? fmt::format(" ({} px at the trial marker farthest from an image centre)",
                                       fx.lens_distortion_px)
                         : std::string())});
  }
}

// The calibration frame and its noisy images, with the outlier_marker and outlier_swap effects.
void make_calibration(const SynthOptions& o, double mat_top_m, SynthTruth& truth, Session& session) {
  const Effects& fx = o.effects;
  const int n_cam = static_cast<int>(truth.cameras.size());
  session.frame = calibration_layout(o, mat_top_m);
  {
    Rng noise(o.seed, kStreamCalibrationNoise);
    const double calib_noise_px = o.calibration_pixel_noise_px >= 0.0 ? o.calibration_pixel_noise_px : o.pixel_noise_px;
    truth.calibration_pixel_noise_px = calib_noise_px;
    std::vector<std::vector<Eigen::Vector2d>> noisy(n_cam);
    std::vector<std::vector<bool>> seen(n_cam);
    for (const CalibrationMarker& m : session.frame) {
      TrueCalibrationMarker t{m.id, m.lab_m, m.role, {}};
      for (int c = 0; c < n_cam; ++c) {
        double depth = 0.0;
        pinhole_px(truth.cameras[c], m.lab_m, &depth);
        const Eigen::Vector2d clean = project_px(truth.cameras[c], m.lab_m);
        const Eigen::Vector2d e(noise.normal(), noise.normal());
        t.image_px.push_back(clean);
        noisy[c].push_back(clean + calib_noise_px * e);
        seen[c].push_back(in_image(truth.cameras[c], clean, depth));
      }
      truth.calibration_markers.push_back(t);
    }
    // outlier_marker: one fit marker's row in the last camera holds another
    // marker's pixel (a mislabelled click), the one whose image distance is
    // closest to the requested size.
    if (fx.outlier_marker_px > 0.0) {
      Rng pick(o.seed, kStreamOutlier);
      std::vector<int> fit;
      for (int i = 0; i < static_cast<int>(session.frame.size()); ++i)
        if (session.frame[i].role == MarkerRole::Fit && seen[n_cam - 1][i]) fit.push_back(i);
      require(fit.size() >= 2, "outlier_marker needs visible fit markers");
      const int a = fit[std::min<std::size_t>(fit.size() - 1, static_cast<std::size_t>(pick.uniform() * fit.size()))];
      const auto& clean = truth.calibration_markers;
      int best = -1;
      double best_gap = std::numeric_limits<double>::infinity();
      for (int j = 0; j < static_cast<int>(clean.size()); ++j) {
        if (j == a || !seen[n_cam - 1][j]) continue;
        const double d = (clean[j].image_px[n_cam - 1] - clean[a].image_px[n_cam - 1]).norm();
        if (std::abs(d - fx.outlier_marker_px) < best_gap) {
          best_gap = std::abs(d - fx.outlier_marker_px);
          best = j;
        }
      }
      // Displaced by exactly the requested size towards that marker: a
      // mislabel when its distance matches, a misdigitisation otherwise.
      const Eigen::Vector2d towards = clean[best].image_px[n_cam - 1] - clean[a].image_px[n_cam - 1];
      const double dist = towards.norm();
      noisy[n_cam - 1][a] += fx.outlier_marker_px * towards / dist;
      truth.effects.push_back(
          {"calibration", "outlier_marker", fx.outlier_marker_px, "px",
           fmt::format("{} in {} is off by {} px towards {} ({:.1f} px away{})", clean[a].id,
                       truth.cameras[n_cam - 1].camera.name, fx.outlier_marker_px, clean[best].id, dist,
                       std::abs(dist - fx.outlier_marker_px) < 0.5 ? ": mislabelled as it" : "")});
    }
    // outlier_swap: two fit markers' image points swapped in the last camera
    // (a labelling slip when clicking them).
    if (fx.outlier_swap) {
      Rng pick(o.seed, kStreamOutlier + 7);
      std::vector<int> fit;
      for (int i = 0; i < static_cast<int>(session.frame.size()); ++i)
        if (session.frame[i].role == MarkerRole::Fit && seen[n_cam - 1][i]) fit.push_back(i);
      require(fit.size() >= 2, "outlier_swap needs two visible fit markers");
      const std::size_t ia = std::min<std::size_t>(fit.size() - 1, static_cast<std::size_t>(pick.uniform() * fit.size()));
      std::size_t ib = std::min<std::size_t>(fit.size() - 2, static_cast<std::size_t>(pick.uniform() * (fit.size() - 1)));
      if (ib >= ia) ++ib;
      const int a = fit[ia], b = fit[ib];
      std::swap(noisy[n_cam - 1][a], noisy[n_cam - 1][b]);
      const double dist = (truth.calibration_markers[a].image_px[n_cam - 1] -
                           truth.calibration_markers[b].image_px[n_cam - 1]).norm();
      truth.effects.push_back({"calibration", "outlier_marker", dist, "px",
                               fmt::format("{} and {} swapped in {} (a labelling slip; {:.1f} px apart)",
                                           session.frame[a].id, session.frame[b].id,
                                           truth.cameras[n_cam - 1].camera.name, dist)});
    }
    for (int c = 0; c < n_cam; ++c) {
      CalibrationImage image;
      image.camera = truth.cameras[c].camera.name;
      for (std::size_t i = 0; i < session.frame.size(); ++i)
        if (seen[c][i])
          image.observations.push_back(
              {session.frame[i].id, {six_decimals(noisy[c][i].x()), six_decimals(noisy[c][i].y())}});
      session.images.push_back(image);
    }
  }
}

}  // namespace detail

calibration::Dlt11 dlt_from_projection(const Eigen::Matrix<double, 3, 4>& p) {
  const double s = p(2, 3);
  if (!(std::abs(s) > 1e-12 * p.norm()))
    throw Error("dlt_from_projection: P(3,4) is zero (the lab origin lies in the camera's focal plane)");
  calibration::Dlt11 l;
  l << p(0, 0), p(0, 1), p(0, 2), p(0, 3), p(1, 0), p(1, 1), p(1, 2), p(1, 3), p(2, 0), p(2, 1), p(2, 2);
  return l / s;
}

Eigen::Vector2d distort_px(const Eigen::Vector2d& ideal_px, const Eigen::Vector2d& pp, double focal_px,
                           const std::vector<double>& k) {
  if (k.empty()) return ideal_px;
  if (k.size() != 5) throw Error("distort_px: distortion needs k1 k2 p1 p2 k3");
  const double x = (ideal_px.x() - pp.x()) / focal_px, y = (ideal_px.y() - pp.y()) / focal_px;
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]));
  const double xd = x * radial + 2.0 * k[2] * x * y + k[3] * (r2 + 2.0 * x * x);
  const double yd = y * radial + k[2] * (r2 + 2.0 * y * y) + 2.0 * k[3] * x * y;
  return pp + focal_px * Eigen::Vector2d(xd, yd);
}

Eigen::Vector2d project_px(const TrueCamera& camera, const Eigen::Vector3d& lab_m) {
  return distort_px(detail::pinhole_px(camera, lab_m), camera.camera.principal_point_px, camera.camera.focal_px,
                    camera.camera.distortion);
}

}  // namespace dropfit::synth
