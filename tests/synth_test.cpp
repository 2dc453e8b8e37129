// The sample-session generator (samples/generator/synth.h): its data agree
// with the truth it reports, through the formulas a lab's tools would use.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <filesystem>
#include <string>
#include <unistd.h>

#include "capture/io.h"
#include "core/error.h"
#include "samples/generator/synth.h"

namespace dropfit::synth {
namespace {

constexpr double kG = 9.81;

SynthOptions noise_free(std::vector<double> velocities = {4.30, 6.50}) {
  SynthOptions o;
  o.seed = 7;
  o.impact_velocities_m_s = std::move(velocities);
  o.pixel_noise_px = 0.0;
  o.channel_noise_n = 0.0;
  o.channel_offset_sd_n = 0.0;
  return o;
}

struct PlateOut {
  double fx, fy, fz, mx, my, mz, ax, ay;
};

// docs/formats.md's eight-channel formulas, written out again.
PlateOut kistler(const Eigen::Matrix<double, 1, 8>& c, double a, double b, double az0) {
  PlateOut r{};
  r.fx = c(0) + c(1);
  r.fy = c(2) + c(3);
  r.fz = c(4) + c(5) + c(6) + c(7);
  r.mx = b * (c(4) + c(5) - c(6) - c(7));
  r.my = a * (-c(4) + c(5) + c(6) - c(7));
  r.mz = b * (-c(0) + c(1)) + a * (c(2) - c(3));
  r.ax = (r.fx * az0 - r.my) / r.fz;
  r.ay = (r.fy * az0 + r.mx) / r.fz;
  return r;
}

// u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1), v likewise.
Eigen::Vector2d dlt_project(const calibration::Dlt11& L, const Eigen::Vector3d& X) {
  const double w = L(8) * X.x() + L(9) * X.y() + L(10) * X.z() + 1.0;
  return {(L(0) * X.x() + L(1) * X.y() + L(2) * X.z() + L(3)) / w,
          (L(4) * X.x() + L(5) * X.y() + L(6) * X.z() + L(7)) / w};
}

// Linear DLT triangulation from every camera (Hartley & Zisserman 12.2).
Eigen::Vector3d triangulate(const std::vector<calibration::Dlt11>& dlts, const std::vector<Eigen::Vector2d>& uv) {
  Eigen::MatrixXd A(2 * dlts.size(), 3);
  Eigen::VectorXd rhs(2 * dlts.size());
  for (std::size_t c = 0; c < dlts.size(); ++c) {
    const calibration::Dlt11& L = dlts[c];
    const double u = uv[c].x(), v = uv[c].y();
    A.row(2 * c) << L(0) - u * L(8), L(1) - u * L(9), L(2) - u * L(10);
    rhs(2 * c) = u - L(3);
    A.row(2 * c + 1) << L(4) - v * L(8), L(5) - v * L(9), L(6) - v * L(10);
    rhs(2 * c + 1) = v - L(7);
  }
  return A.colPivHouseholderQr().solve(rhs);
}

std::vector<calibration::Dlt11> truth_dlts(const SynthTruth& t) {
  std::vector<calibration::Dlt11> d;
  for (const TrueCamera& c : t.cameras) d.push_back(c.camera.dlt);
  return d;
}

int first_crossing(const ForceRecord& f, const Eigen::Matrix<double, 8, 1>& offsets, double threshold) {
  for (Eigen::Index j = 0; j < f.data.rows(); ++j)
    if (f.data.row(j).tail<4>().sum() - offsets.tail<4>().sum() >= threshold) return static_cast<int>(j);
  return -1;
}

TEST(SynthKistler, ChannelsGiveBackForceCopAndNoTwist) {
  const double a = 0.120, b = 0.200, az0 = -0.040;
  const Eigen::Vector3d f(-35.0, 12.5, 7054.0);
  const Eigen::Vector2d cop(0.013, -0.021);
  const Eigen::Matrix<double, 8, 1> ch = kistler_channels(f, cop, a, b, az0);
  const PlateOut r = kistler(ch.transpose(), a, b, az0);
  EXPECT_NEAR(r.fx, f.x(), 1e-9);
  EXPECT_NEAR(r.fy, f.y(), 1e-9);
  EXPECT_NEAR(r.fz, f.z(), 1e-9);
  EXPECT_NEAR(r.ax, cop.x(), 1e-12);
  EXPECT_NEAR(r.ay, cop.y(), 1e-12);
  EXPECT_NEAR(r.mz, 0.0, 1e-9);
  EXPECT_NEAR(ch(4) - ch(5) + ch(6) - ch(7), 0.0, 1e-9);  // zero twist
}

TEST(SynthKistler, SessionChannelsGiveBackTrueFzAndCop) {
  const SyntheticSession s = make_session(noise_free());
  const ForcePlateSpec& p = s.session.manifest.forceplate;
  for (std::size_t i = 0; i < s.session.trials.size(); ++i) {
    const ForceRecord& f = s.session.trials[i].force;
    const TrialTruth& t = s.truth.trials[i];
    ASSERT_EQ(f.data.rows(), t.grf_n.size());
    int checked = 0;
    for (Eigen::Index j = 0; j < f.data.rows(); ++j) {
      const PlateOut r = kistler(f.data.row(j), p.a_m, p.b_m, p.az0_m);
      // Within 1e-6 of the peak (the writers' six decimals are 1e-6 N).
      EXPECT_NEAR(r.fz, t.grf_n(j), 1e-6 * t.peak_force_n + 4e-6) << t.id << " sample " << j;
      if (t.grf_n(j) < 50.0) continue;
      EXPECT_NEAR(r.ax, t.cop_m.x(), 1e-6 * std::abs(t.cop_m.x()) + 1e-9) << t.id << " sample " << j;
      EXPECT_NEAR(r.ay, t.cop_m.y(), 1e-6 * std::abs(t.cop_m.y()) + 1e-9) << t.id << " sample " << j;
      EXPECT_NEAR(r.fx / r.fz, t.shear_fraction.x(), 1e-6);
      ++checked;
    }
    EXPECT_GT(checked, 30) << t.id;
  }
}

TEST(SynthForce, TriggerSampleIsThePretriggerCount) {
  SynthOptions o;  // default noise and offsets
  o.seed = 11;
  o.n_samples = 1500;
  const SyntheticSession s = make_session(o);
  const int npre = 150;  // lround(0.10 * 1500)
  for (std::size_t i = 0; i < s.session.trials.size(); ++i) {
    const ForceRecord& f = s.session.trials[i].force;
    const TrialTruth& t = s.truth.trials[i];
    EXPECT_EQ(f.pretrigger_samples, npre);
    EXPECT_EQ(t.trigger_index, npre);
    EXPECT_EQ(f.t_s(npre), 0.0);
    EXPECT_EQ(first_crossing(f, t.channel_offsets_n, 25.0), npre) << t.id;
    // First contact lies within one sample before the noise-free crossing.
    EXPECT_LT(t.contact_time_s, 0.0);
    EXPECT_GT(t.contact_time_s, -0.02);
    // The noise-free GRF crosses 25 N between the previous sample and the trigger.
    EXPECT_LT(t.grf_n(npre - 1), 25.0);
    EXPECT_GE(t.grf_n(npre), 25.0);
  }
}

TEST(SynthVideo, ImpactorFallsFreelyAtTheStatedVelocity) {
  const SyntheticSession s = make_session(noise_free());
  const auto dlts = truth_dlts(s.truth);
  const double dt = 1.0 / s.session.manifest.video.frame_rate_hz;
  for (std::size_t i = 0; i < s.session.trials.size(); ++i) {
    const MarkerTracks2D& tr = s.session.trials[i].tracks;
    const TrialTruth& t = s.truth.trials[i];
    // Height of the base markers' midpoint per frame (NaN where not seen).
    Eigen::VectorXd z = Eigen::VectorXd::Constant(tr.n_frames(), std::nan(""));
    for (int f = 0; f < tr.n_frames(); ++f) {
      Eigen::Vector3d base[2];
      bool ok = true;
      for (int p = 0; p < 2; ++p) {
        std::vector<Eigen::Vector2d> uv;
        for (int c = 0; c < tr.n_cameras(); ++c) uv.push_back(tr.uv(f, p, c));
        for (const auto& x : uv) ok = ok && x.allFinite();
        if (ok) base[p] = triangulate(dlts, uv);
      }
      if (!ok) continue;
      z(f) = 0.5 * (base[0].z() + base[1].z());
      // The front-back line shows the tilt about Y (+: the front, +X, lower).
      const Eigen::Vector3d d = base[0] - base[1];
      EXPECT_NEAR(std::atan2(-d.z(), d.x()) * 180.0 / M_PI, t.tilt_about_y_deg, 1e-5) << t.id << " frame " << f;
    }
    int used = 0;
    double worst = 0.0;
    for (int f = 1; f + 1 < tr.n_frames(); ++f) {
      const double tau_next = t.frame_force_time_s(f + 1) - t.contact_time_s;
      const double tau_prev = t.frame_force_time_s(f - 1) - t.contact_time_s;
      if (tau_next >= 0.0 || tau_prev < -t.impact_velocity_m_s / kG) continue;  // free fall only
      if (!std::isfinite(z(f - 1)) || !std::isfinite(z(f + 1))) continue;
      const double v_down = -(z(f + 1) - z(f - 1)) / (2.0 * dt);
      // Extrapolated to first contact with g.
      const double v_contact = v_down + kG * (t.contact_time_s - t.frame_force_time_s(f));
      worst = std::max(worst, std::abs(v_contact - t.impact_velocity_m_s));
      ++used;
    }
    EXPECT_GT(used, 60) << t.id;
    EXPECT_LT(worst, 0.01) << t.id;
  }
}

TEST(SynthCalibration, TruthDltReprojectsTheMarkersToTheNoiseFreePixels) {
  const SyntheticSession s = make_session(noise_free({5.25}));
  ASSERT_EQ(s.session.frame.size(), 20u);
  int fit = 0;
  for (const CalibrationMarker& m : s.session.frame) fit += m.role == MarkerRole::Fit;
  EXPECT_EQ(fit, 10);
  for (std::size_t c = 0; c < s.truth.cameras.size(); ++c) {
    const CalibrationImage& im = s.session.images[c];
    EXPECT_EQ(im.observations.size(), 20u);
    for (const CameraObservation& ob : im.observations) {
      const auto it = std::find_if(s.session.frame.begin(), s.session.frame.end(),
                                   [&](const CalibrationMarker& m) { return m.id == ob.id; });
      ASSERT_NE(it, s.session.frame.end());
      const Eigen::Vector2d px = dlt_project(s.truth.cameras[c].camera.dlt, it->lab_m);
      EXPECT_LT((px - ob.image_px).norm(), 1e-6) << ob.id << " in " << im.camera;
      EXPECT_GE(px.minCoeff(), 0.0);
      EXPECT_LT(px.maxCoeff(), 1024.0);
    }
  }
  // The structure is not planar: the smallest principal extent is large.
  Eigen::MatrixXd X(20, 3);
  for (int i = 0; i < 20; ++i) X.row(i) = s.session.frame[i].lab_m.transpose();
  const Eigen::MatrixXd centred = X.rowwise() - X.colwise().mean();
  EXPECT_GT(Eigen::JacobiSVD<Eigen::MatrixXd>(centred).singularValues()(2), 0.5);
  // The optical axes are 86 degrees apart.
  const Eigen::Vector3d d1 = s.truth.cameras[0].cam_from_lab_r.row(2), d2 = s.truth.cameras[1].cam_from_lab_r.row(2);
  EXPECT_NEAR(std::acos(d1.dot(d2)) * 180.0 / M_PI, 86.0, 1e-9);
}

TEST(SynthCapture, WriteThenReadGivesTheInMemorySession) {
  SynthOptions o;
  o.seed = 3;
  o.impact_velocities_m_s = {4.8, 5.75};
  o.gaps.push_back({1, "mat_e", 0, 250, 20});
  const SyntheticSession s = make_session(o);
  const std::string root =
      (std::filesystem::temp_directory_path() / ("synth_test_" + std::to_string(::getpid()))).string();
  std::filesystem::remove_all(root);
  capture::write_session(root, s.session);
  const Session r = capture::read_session(root);
  std::filesystem::remove_all(root);

  const Manifest &a = s.session.manifest, &b = r.manifest;
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.gravity_m_s2, b.gravity_m_s2);
  EXPECT_EQ(a.impactor.base_markers, b.impactor.base_markers);
  EXPECT_EQ(a.impactor.base_marker_height_m, b.impactor.base_marker_height_m);
  EXPECT_EQ(a.mat.surface_markers, b.mat.surface_markers);
  ASSERT_EQ(a.mat.layers.size(), b.mat.layers.size());
  for (std::size_t i = 0; i < a.mat.layers.size(); ++i) {
    EXPECT_EQ(a.mat.layers[i].name, b.mat.layers[i].name);
    EXPECT_EQ(a.mat.layers[i].mass_kg, b.mat.layers[i].mass_kg);
    EXPECT_EQ(a.mat.layers[i].thickness_m, b.mat.layers[i].thickness_m);
  }
  EXPECT_EQ(a.video.points, b.video.points);
  EXPECT_EQ(a.video.cameras, b.video.cameras);
  EXPECT_EQ(a.video.trigger_frame, b.video.trigger_frame);
  EXPECT_EQ(a.forceplate.mat_top_z_m, b.forceplate.mat_top_z_m);
  EXPECT_EQ(a.forceplate.az0_m, b.forceplate.az0_m);
  ASSERT_EQ(s.session.frame.size(), r.frame.size());
  for (std::size_t i = 0; i < r.frame.size(); ++i) {
    EXPECT_EQ(s.session.frame[i].id, r.frame[i].id);
    EXPECT_EQ(s.session.frame[i].lab_m, r.frame[i].lab_m);
    EXPECT_EQ(s.session.frame[i].role, r.frame[i].role);
  }
  ASSERT_EQ(s.session.images.size(), r.images.size());
  for (std::size_t c = 0; c < r.images.size(); ++c) {
    ASSERT_EQ(s.session.images[c].observations.size(), r.images[c].observations.size());
    for (std::size_t i = 0; i < r.images[c].observations.size(); ++i) {
      EXPECT_EQ(s.session.images[c].observations[i].id, r.images[c].observations[i].id);
      EXPECT_EQ(s.session.images[c].observations[i].image_px, r.images[c].observations[i].image_px);
    }
  }
  ASSERT_EQ(s.session.trials.size(), r.trials.size());
  for (std::size_t i = 0; i < r.trials.size(); ++i) {
    const TrialRecording &x = s.session.trials[i], &y = r.trials[i];
    EXPECT_EQ(x.spec.id, y.spec.id);
    EXPECT_EQ(x.spec.dir, y.spec.dir);
    // Bit for bit, NaN where NaN.
    ASSERT_EQ(x.tracks.uv_px.rows(), y.tracks.uv_px.rows());
    ASSERT_EQ(x.tracks.uv_px.cols(), y.tracks.uv_px.cols());
    EXPECT_TRUE((x.tracks.uv_px.array().isNaN() == y.tracks.uv_px.array().isNaN()).all());
    EXPECT_TRUE((x.tracks.uv_px.array() == y.tracks.uv_px.array() || x.tracks.uv_px.array().isNaN()).all());
    EXPECT_EQ(x.force.pretrigger_samples, y.force.pretrigger_samples);
    EXPECT_EQ(x.force.sample_rate_hz, y.force.sample_rate_hz);
    EXPECT_EQ(x.force.trigger, y.force.trigger);
    EXPECT_EQ(x.force.t_s, y.force.t_s);
    EXPECT_EQ(x.force.data, y.force.data);
  }
  // The gap is there: mat_e (point 5) hidden in camera 1 for frames 250-269 of trial 2.
  const MarkerTracks2D& t2 = r.trials[1].tracks;
  EXPECT_TRUE(std::isnan(t2.uv(260, 4, 0).x()));
  EXPECT_TRUE(std::isfinite(t2.uv(260, 4, 1).x()));
  EXPECT_TRUE(std::isfinite(t2.uv(270, 4, 0).x()));
}

TEST(SynthEffects, TimeOffsetShiftsTheVideoByTheStatedMilliseconds) {
  SynthOptions o = noise_free({5.25});
  const SyntheticSession base = make_session(o);
  o.effects.time_offset_ms = 3.0;
  const SyntheticSession shifted = make_session(o);
  ASSERT_EQ(shifted.truth.effects.size(), 1u);
  EXPECT_EQ(shifted.truth.effects[0].name, "time_offset");
  EXPECT_DOUBLE_EQ(shifted.truth.trials[0].video_offset_s, 0.003);
  // The force record does not move; the video is 3 frames later.
  EXPECT_EQ(base.session.trials[0].force.data, shifted.session.trials[0].force.data);
  const Eigen::MatrixXd& a = base.session.trials[0].tracks.uv_px;
  const Eigen::MatrixXd& b = shifted.session.trials[0].tracks.uv_px;
  double worst = 0.0;
  int compared = 0;
  for (int f = 0; f + 3 < a.rows(); ++f)
    for (int c = 0; c < a.cols(); ++c)
      if (std::isfinite(a(f, c)) && std::isfinite(b(f + 3, c))) {
        worst = std::max(worst, std::abs(a(f, c) - b(f + 3, c)));
        ++compared;
      }
  EXPECT_GT(compared, 5000);
  EXPECT_LT(worst, 1e-4);
  // Unshifted they differ around the impact (markers move by pixels per ms).
  EXPECT_GT((a.row(250) - b.row(250)).cwiseAbs().maxCoeff(), 0.5);
}

TEST(SynthEffects, ForceScaleAndDriftChangeFzAsStated) {
  SynthOptions o = noise_free({5.25});
  o.effects.force_scale = 1.05;
  o.effects.baseline_drift_n_s = 20.0;
  const SyntheticSession s = make_session(o);
  const ForcePlateSpec& p = s.session.manifest.forceplate;
  const TrialTruth& t = s.truth.trials[0];
  for (Eigen::Index j = 0; j < t.t_s.size(); ++j) {
    const double fz = kistler(s.session.trials[0].force.data.row(j), p.a_m, p.b_m, p.az0_m).fz;
    const double drift = t.t_s(j) > 0.0 ? 20.0 * t.t_s(j) : 0.0;
    EXPECT_NEAR(fz, 1.05 * t.grf_n(j) + drift, 1e-5) << "sample " << j;
  }
  EXPECT_EQ(s.truth.effects.size(), 2u);
}

TEST(SynthEffects, MatEffectsGoIntoTheTruthParametersNotTheManifest) {
  const SyntheticSession base = make_session(noise_free({5.25}));
  SynthOptions o = noise_free({5.25});
  o.effects.k1_cubic_n_m3 = 2.0e7;
  o.effects.layer_mass_shift_kg = 0.5;
  const SyntheticSession s = make_session(o);
  EXPECT_EQ(s.truth.params.k1_cubic_n_m3, 2.0e7);
  EXPECT_NEAR(s.truth.params.m1_kg, 2.94, 1e-12);
  EXPECT_NEAR(s.truth.params.m2_kg, 3.16, 1e-12);
  EXPECT_NEAR(s.truth.params.m1_kg + s.truth.params.m2_kg, 6.10, 1e-12);
  EXPECT_EQ(s.session.manifest.mat.layers[1].mass_kg, 2.44);
  EXPECT_EQ(s.session.manifest.mat.layers[2].mass_kg, 3.66);
  // Hardening raises the peak and shortens the travel.
  EXPECT_GT(s.truth.trials[0].peak_force_n, 1.05 * base.truth.trials[0].peak_force_n);
  EXPECT_LT(s.truth.trials[0].max_deformation_m, base.truth.trials[0].max_deformation_m);
  // layer_mass needs a layered model.
  SynthOptions m1 = noise_free({5.25});
  m1.model = ModelKind::Model1;
  m1.effects.layer_mass_shift_kg = 0.5;
  EXPECT_THROW(make_session(m1), Error);
  Effects e;
  EXPECT_THROW(set_effect(e, "gravity_wobble", 1.0), Error);
  set_effect(e, "hysteresis", 120.0);
  EXPECT_EQ(e.r1_unload_n_s_m, 120.0);
}

TEST(SynthEffects, LensDistortionFollowsTheCalibrationConvention) {
  SynthOptions o = noise_free({5.25});
  o.effects.lens_distortion_k1 = -0.25;
  const SyntheticSession s = make_session(o);
  double largest = 0.0;
  for (std::size_t c = 0; c < s.truth.cameras.size(); ++c) {
    const TrueCamera& cam = s.truth.cameras[c];
    ASSERT_EQ(cam.camera.distortion.size(), 5u);
    for (const CameraObservation& ob : s.session.images[c].observations) {
      const auto it = std::find_if(s.session.frame.begin(), s.session.frame.end(),
                                   [&](const CalibrationMarker& m) { return m.id == ob.id; });
      // calibration::Camera::project (the pipeline's dlt16) gives the pixel back.
      EXPECT_LT((cam.camera.project(it->lab_m) - ob.image_px).norm(), 1e-6);
      // Radial: the pinhole pixel moves towards the principal point by k1 r^2.
      const Eigen::Vector2d ideal = dlt_project(cam.camera.dlt, it->lab_m);
      const Eigen::Vector2d x = (ideal - cam.camera.principal_point_px) / cam.camera.focal_px;
      const Eigen::Vector2d expect = cam.camera.principal_point_px +
                                     cam.camera.focal_px * x * (1.0 - 0.25 * x.squaredNorm());
      EXPECT_LT((expect - ob.image_px).norm(), 1e-6);
      largest = std::max(largest, (ideal - ob.image_px).norm());
    }
  }
  EXPECT_GT(largest, 2.0);  // a visible effect at the image edge
}

TEST(SynthEffects, OutlierMarkerMislabelsOneMarkerInOneCamera) {
  SynthOptions o = noise_free({5.25});
  o.effects.outlier_marker_px = 40.0;
  const SyntheticSession s = make_session(o);
  int outliers = 0;
  double error = 0.0;
  std::string moved;
  for (std::size_t c = 0; c < s.truth.cameras.size(); ++c)
    for (const CameraObservation& ob : s.session.images[c].observations) {
      const auto it = std::find_if(s.session.frame.begin(), s.session.frame.end(),
                                   [&](const CalibrationMarker& m) { return m.id == ob.id; });
      const double e = (dlt_project(s.truth.cameras[c].camera.dlt, it->lab_m) - ob.image_px).norm();
      if (e > 1e-3) {
        ++outliers;
        error = e;
        moved = ob.id;
        EXPECT_EQ(c, 1u);
        EXPECT_EQ(it->role, MarkerRole::Fit);
      }
    }
  EXPECT_EQ(outliers, 1);
  EXPECT_NEAR(error, 40.0, 1e-5);
  ASSERT_FALSE(moved.empty());

  // Asked for the distance to another marker, the row holds that marker's pixel.
  const calibration::Dlt11& L = s.truth.cameras[1].camera.dlt;
  Eigen::Vector2d moved_px(0, 0), other_px(0, 0);
  double nearest = 1e9;
  for (const CalibrationMarker& m : s.session.frame)
    if (m.id == moved) moved_px = dlt_project(L, m.lab_m);
  for (const CalibrationMarker& m : s.session.frame) {
    const double d = (dlt_project(L, m.lab_m) - moved_px).norm();
    if (m.id != moved && d < nearest) {
      nearest = d;
      other_px = dlt_project(L, m.lab_m);
    }
  }
  o.effects.outlier_marker_px = nearest;
  const SyntheticSession mislabelled = make_session(o);
  for (const CameraObservation& ob : mislabelled.session.images[1].observations) {
    if (ob.id == moved) {
      EXPECT_LT((ob.image_px - other_px).norm(), 1e-5);
    }
  }
}

// Model 5 (area-elastic, geometric) is not generated by the generator's own
// physics: asking for it is a clear error, not a silent substitute.
TEST(SynthModel5, IsRefusedWithAReason) {
  SynthOptions o = noise_free({5.25});
  o.model = ModelKind::Model5;
  try {
    make_session(o);
    ADD_FAILURE() << "Model 5 was generated";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("Model 5"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace dropfit::synth
