// Trial analysis against a synthetic drop with known truth: a 24 kg impactor
// in free fall lands on a Hunt-Crossley spring-damper mat (massless, so the
// plate reads the contact force), integrated finely; the plate samples the
// force through eight noisy channels, the cameras see noisy markers at
// 1000 Hz on a clock 3 ms off the declared one.
#include <gtest/gtest.h>
#include <fmt/format.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "core/error.h"
#include "forceplate/forceplate.h"
#include "trial/trial.h"

namespace fp = dropfit::forceplate;
namespace tr = dropfit::trial;

namespace {

constexpr double kPi = 3.14159265358979323846;

struct WorldOptions {
  double impact_speed_m_s = 5.25;
  double mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  // Mat: F = max(0, k x^1.5 (1 + alpha xdot)), x the penetration.
  double k_n_m15 = 2.8e5;
  double alpha_s_m = 0.3;
  double mat_top_z_m = 0.205;
  double base_marker_height_m = 0.03;
  int n_base_markers = 2;
  double tilt_deg = 0.0;               // about the lab y axis
  double true_offset_s = 0.003;        // video clock minus force clock
  double marker_noise_m = 0.5e-3;
  double height_bias_m = 0.0;          // every marker's z (a calibration's height error near the mat)
  double channel_noise_n = 1.0;        // Fz (four channels) has 2 N
  double fs_hz = 1000.0, fps_hz = 1000.0;
  int force_samples = 1500, pretrigger = 150;
  int frames = 1000, trigger_frame = 500;
  double phase_s = 0.37e-3;            // force sampling off the contact instant
  unsigned seed = 11;
};

struct World {
  WorldOptions o;
  // Truth on a fine grid from contact (tau = 0).
  double h_s = 5e-6;
  std::vector<double> pen_m, force_n;
  double peak_force_n = 0.0, max_penetration_m = 0.0;
  double tau_trigger_s = 0.0;  // the trigger sample's time after contact
  // Measurements.
  fp::Resultants raw;
  dropfit::reconstruction::Trajectories markers;
  std::vector<std::string> names;

  double contact_force_clock_s() const { return -tau_trigger_s; }
  double penetration(double tau) const {  // truth, any time after contact (free fall before)
    if (tau <= 0.0) return -(o.impact_speed_m_s * (-tau) - 0.5 * o.gravity_m_s2 * tau * tau);
    const double u = tau / h_s;
    const std::size_t i = std::min(static_cast<std::size_t>(u), pen_m.size() - 2);
    const double w = u - static_cast<double>(i);
    return (1.0 - w) * pen_m[i] + w * pen_m[i + 1];
  }
  double force(double tau) const {
    if (tau <= 0.0) return 0.0;
    const double u = tau / h_s;
    const std::size_t i = std::min(static_cast<std::size_t>(u), force_n.size() - 2);
    const double w = u - static_cast<double>(i);
    return (1.0 - w) * force_n[i] + w * force_n[i + 1];
  }
  double face_z(double tau) const { return o.mat_top_z_m - penetration(tau); }
  double surface_z(double tau) const { return o.mat_top_z_m - 0.15 * std::max(0.0, penetration(tau)); }
  // Video frame i sees the world at this time after contact.
  double tau_of_frame(int i) const {
    return (i - o.trigger_frame) / o.fps_hz - o.true_offset_s + tau_trigger_s;
  }
};

double mat_force(const WorldOptions& o, double x, double xdot) {
  if (x <= 0.0) return 0.0;
  return std::max(0.0, o.k_n_m15 * std::pow(x, 1.5) * (1.0 + o.alpha_s_m * xdot));
}

World make_world(const WorldOptions& o) {
  World w;
  w.o = o;
  // RK4 of m xddot = m g - F(x, xdot) from contact to the end of the force record.
  const double tau_end = (o.force_samples - o.pretrigger) / o.fs_hz + 0.05;
  const auto steps = static_cast<std::size_t>(tau_end / w.h_s) + 2;
  w.pen_m.resize(steps);
  w.force_n.resize(steps);
  double x = 0.0, v = o.impact_speed_m_s;
  auto acc = [&](double xx, double vv) { return o.gravity_m_s2 - mat_force(o, xx, vv) / o.mass_kg; };
  for (std::size_t i = 0; i < steps; ++i) {
    w.pen_m[i] = x;
    w.force_n[i] = mat_force(o, x, v);
    w.peak_force_n = std::max(w.peak_force_n, w.force_n[i]);
    w.max_penetration_m = std::max(w.max_penetration_m, x);
    const double h = w.h_s;
    const double k1x = v, k1v = acc(x, v);
    const double k2x = v + 0.5 * h * k1v, k2v = acc(x + 0.5 * h * k1x, v + 0.5 * h * k1v);
    const double k3x = v + 0.5 * h * k2v, k3v = acc(x + 0.5 * h * k2x, v + 0.5 * h * k2v);
    const double k4x = v + h * k3v, k4v = acc(x + h * k3x, v + h * k3v);
    x += h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x);
    v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v);
  }
  std::mt19937 rng(o.seed);
  std::normal_distribution<double> unit(0.0, 1.0);

  // Force plate: samples at tau = phase + k / fs; the trigger is the first at 25 N.
  int k_trig = 0;
  while (w.force(o.phase_s + k_trig / o.fs_hz) < 25.0) ++k_trig;
  w.tau_trigger_s = o.phase_s + k_trig / o.fs_hz;
  const fp::PlateGeometry plate;
  Eigen::VectorXd t(o.force_samples);
  Eigen::MatrixXd ch(o.force_samples, 8);
  const double offsets[8] = {0.4, -0.2, 0.1, 0.3, 2.0, -1.5, 1.0, 0.5};
  for (int i = 0; i < o.force_samples; ++i) {
    const int k = k_trig - o.pretrigger + i;
    t[i] = (k - k_trig) / o.fs_hz;
    const double fz = w.force(o.phase_s + k / o.fs_hz);
    const double fx = 0.01 * fz, fy = 0.0, ax = 0.01, ay = -0.02;
    const double my = fx * plate.az0_m - ax * fz, mx = ay * fz - fy * plate.az0_m;
    const double a = plate.a_m, b = plate.b_m;
    const double c[8] = {fx / 2, fx / 2, fy / 2, fy / 2, (fz + mx / b - my / a) / 4, (fz + mx / b + my / a) / 4,
                         (fz - mx / b + my / a) / 4, (fz - mx / b - my / a) / 4};
    for (int j = 0; j < 8; ++j) ch(i, j) = c[j] + offsets[j] + o.channel_noise_n * unit(rng);
  }
  w.raw = fp::from_eight_channels(t, ch, plate);

  // Markers: base markers around the face centre, tilted about y; four
  // surface markers following the mat top. Not digitised before release.
  const double th = o.tilt_deg * kPi / 180.0;
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(th, Eigen::Vector3d::UnitY()).toRotationMatrix();
  std::vector<Eigen::Vector3d> local;
  if (o.n_base_markers == 2) {
    local = {{0.1, 0.0, o.base_marker_height_m}, {-0.1, 0.0, o.base_marker_height_m}};
    w.names = {"imp_base_front", "imp_base_back"};
  } else {
    for (int k = 0; k < o.n_base_markers; ++k) {
      const double phi = 2.0 * kPi * k / o.n_base_markers;
      local.emplace_back(0.1 * std::cos(phi), 0.1 * std::sin(phi), o.base_marker_height_m);
      w.names.push_back("imp_base_" + std::to_string(k + 1));
    }
  }
  const std::vector<Eigen::Vector2d> surface_xy{{0.0, 0.25}, {0.0, -0.25}, {0.4, 0.0}, {-0.4, 0.0}};
  for (const char* n : {"mat_n", "mat_s", "mat_e", "mat_w"}) w.names.push_back(n);
  const int n_points = o.n_base_markers + 4;
  w.markers.lab_m.setConstant(o.frames, 3 * n_points, std::numeric_limits<double>::quiet_NaN());
  w.markers.residual_px.setConstant(o.frames, n_points, 0.3);
  const Eigen::Vector3d centre_xy(0.01, -0.02, 0.0);
  const double release = -o.impact_speed_m_s / o.gravity_m_s2;
  for (int i = 0; i < o.frames; ++i) {
    const double tau = w.tau_of_frame(i);
    if (tau < release) continue;
    const Eigen::Vector3d face = centre_xy + Eigen::Vector3d(0.0, 0.0, w.face_z(tau));
    for (int p = 0; p < o.n_base_markers; ++p) {
      const Eigen::Vector3d q = face + rot * local[p];
      for (int d = 0; d < 3; ++d) w.markers.lab_m(i, 3 * p + d) = q[d] + o.marker_noise_m * unit(rng);
      w.markers.lab_m(i, 3 * p + 2) += o.height_bias_m;
    }
    for (int s = 0; s < 4; ++s) {
      const int p = o.n_base_markers + s;
      const Eigen::Vector3d q(surface_xy[s].x(), surface_xy[s].y(), w.surface_z(tau));
      for (int d = 0; d < 3; ++d) w.markers.lab_m(i, 3 * p + d) = q[d] + o.marker_noise_m * unit(rng);
      w.markers.lab_m(i, 3 * p + 2) += o.height_bias_m;
    }
  }
  return w;
}

fp::ProcessOptions force_options(const World& w) {
  fp::ProcessOptions po;
  po.pretrigger_samples = w.o.pretrigger;
  po.sample_rate_hz = w.o.fs_hz;
  return po;
}

tr::TrialOptions trial_options(const World& w) {
  tr::TrialOptions t;
  t.id = "synthetic";
  t.impactor_mass_kg = w.o.mass_kg;
  t.gravity_m_s2 = w.o.gravity_m_s2;
  t.frame_rate_hz = w.o.fps_hz;
  t.trigger_frame = w.o.trigger_frame;
  for (int p = 0; p < w.o.n_base_markers; ++p) t.base_markers.push_back(p);
  for (int s = 0; s < 4; ++s) t.surface_markers.push_back(w.o.n_base_markers + s);
  t.point_names = w.names;
  t.base_marker_height_m = w.o.base_marker_height_m;
  t.mat_top_z_m = w.o.mat_top_z_m;
  return t;
}

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

}  // namespace

TEST(Trial, MeasuresVelocityDeformationForceAndClockOffset) {
  for (double speed : {4.3, 5.25, 6.5}) {
    SCOPED_TRACE("impact speed " + std::to_string(speed));
    WorldOptions wo;
    wo.impact_speed_m_s = speed;
    wo.seed = static_cast<unsigned>(speed * 100);
    const World w = make_world(wo);
    const fp::ForceTrial force = fp::process(w.raw, force_options(w));
    const tr::TrialResult r = tr::analyse(force, w.markers, trial_options(w));

    EXPECT_TRUE(r.accepted) << r.reject_reason;
    EXPECT_NEAR(r.impact_velocity_m_s, speed, 0.02);
    EXPECT_GT(r.impact_velocity_ci_m_s, 0.0005);
    EXPECT_LT(r.impact_velocity_ci_m_s, 0.02);
    EXPECT_NEAR(r.max_deformation_m, w.max_penetration_m, 1e-3);
    EXPECT_NEAR(r.peak_force_n, w.peak_force_n, 0.005 * w.peak_force_n);
    EXPECT_NEAR(r.video_offset_s, wo.true_offset_s, 0.2e-3);
    EXPECT_NEAR(r.video_offset_trajectory_s, wo.true_offset_s, 0.3e-3);
    // Contact from the force itself: before the 25 N crossing, within 1 ms of truth.
    EXPECT_LT(r.contact_time_s, force.plate.t_s[force.trigger_index]);
    EXPECT_NEAR(r.contact_time_s, w.contact_force_clock_s(), 1e-3);
    EXPECT_LT(r.tilt_deg, 1.0);
    EXPECT_NEAR(r.impulse_ratio, 1.0, 0.03);

    // The series: the impactor placed on the force clock with the found offset.
    const tr::Series& s = r.series;
    ASSERT_GT(s.t_s.size(), 50);
    EXPECT_LT(s.t_s[0], r.contact_time_s);
    int compared = 0;
    for (Eigen::Index k = 0; k < s.t_s.size(); ++k) {
      const double tau = s.t_s[k] + w.tau_trigger_s;
      ASSERT_TRUE(std::isfinite(s.impactor_z_m[k])) << "sample " << k;
      EXPECT_NEAR(s.impactor_z_m[k], w.face_z(tau), 1.5e-3) << "sample " << k;
      EXPECT_NEAR(s.deformation_m[k], w.penetration(tau), 1.5e-3) << "sample " << k;
      EXPECT_NEAR(s.surface_z_m[k], w.surface_z(tau), 1.0e-3) << "sample " << k;
      EXPECT_NEAR(s.fz_n[k], w.force(tau), 10.0) << "sample " << k;
      ++compared;
    }
    EXPECT_GT(compared, 50);
  }
}

// The cameras see every marker 2 mm low near the mat (what a lens-distortion
// fit leaves there): against the surveyed mat top the face arrives 0.38 ms
// early at 5.25 m/s; against the surface markers at rest, which share the
// error, it does not. Markers 8 mm off the surveyed top are not on the
// surface, and the surveyed height is kept.
TEST(Trial, ContactHeightIsTheMatTopTheCamerasSee) {
  WorldOptions wo;
  wo.height_bias_m = -0.002;
  const World w = make_world(wo);
  const fp::ForceTrial force = fp::process(w.raw, force_options(w));

  const tr::TrialResult seen = tr::analyse(force, w.markers, trial_options(w));
  ASSERT_TRUE(seen.accepted) << seen.reject_reason;
  EXPECT_NEAR(seen.contact_height_m, wo.mat_top_z_m + wo.height_bias_m, 0.2e-3);
  EXPECT_NEAR(seen.video_offset_s, wo.true_offset_s, 0.1e-3);
  EXPECT_NEAR(seen.max_deformation_m, w.max_penetration_m, 0.5e-3);
  EXPECT_NEAR(seen.impact_velocity_m_s, wo.impact_speed_m_s, 0.02);

  tr::TrialOptions surveyed_only = trial_options(w);
  surveyed_only.surface_markers.clear();
  const tr::TrialResult surveyed = tr::analyse(force, w.markers, surveyed_only);
  EXPECT_DOUBLE_EQ(surveyed.contact_height_m, wo.mat_top_z_m);
  EXPECT_GT(std::abs(surveyed.video_offset_s - wo.true_offset_s), 0.25e-3);

  tr::TrialOptions far = trial_options(w);
  far.mat_top_z_m = wo.mat_top_z_m + 0.008;
  const tr::TrialResult off_surface = tr::analyse(force, w.markers, far);
  EXPECT_DOUBLE_EQ(off_surface.contact_height_m, far.mat_top_z_m);
}

TEST(Trial, ThreeBaseMarkersGiveThePlaneTilt) {
  WorldOptions wo;
  wo.n_base_markers = 3;
  wo.tilt_deg = 2.6;
  const World w = make_world(wo);
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), w.markers, trial_options(w));
  EXPECT_TRUE(r.accepted) << r.reject_reason;
  EXPECT_NEAR(r.tilt_deg, 2.6, 0.6);
  EXPECT_NEAR(r.impact_velocity_m_s, wo.impact_speed_m_s, 0.02);
}

TEST(Trial, TiltedImpactorIsRejected) {
  WorldOptions wo;
  wo.tilt_deg = 10.0;
  const World w = make_world(wo);
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), w.markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, "tilt")) << r.reject_reason;
  EXPECT_NEAR(r.tilt_deg, 10.0, 1.0);
  // Still measured.
  EXPECT_NEAR(r.impact_velocity_m_s, wo.impact_speed_m_s, 0.02);
}

TEST(Trial, MissingMarkersAroundContactAreRejectedByName) {
  const World w = make_world(WorldOptions{});
  dropfit::reconstruction::Trajectories markers = w.markers;
  for (int i = 0; i < w.o.frames; ++i) {
    const double tau = w.tau_of_frame(i);
    if (tau > -0.005 && tau < 0.030) markers.lab_m.block(i, 3, 1, 3).setConstant(std::nan(""));  // imp_base_back
  }
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, "imp_base_back")) << r.reject_reason;
  EXPECT_FALSE(contains(r.reject_reason, "imp_base_front")) << r.reject_reason;
  EXPECT_NEAR(r.peak_force_n, w.peak_force_n, 0.005 * w.peak_force_n);
}

namespace {
// The instant of the impactor's lowest point, after contact.
double bottom_time_s(const World& w) {
  std::size_t k_max = 0;
  for (std::size_t k = 0; k < w.pen_m.size(); ++k) {
    if (w.pen_m[k] > w.pen_m[k_max]) k_max = k;
  }
  return static_cast<double>(k_max) * w.h_s;
}

// Blanks `marker` (a base marker index) in the frames that see the world
// from `from_s` to before `to_s` after contact; returns how many.
int blank(dropfit::reconstruction::Trajectories& markers, const World& w, int marker, double from_s, double to_s) {
  int n = 0;
  for (int i = 0; i < w.o.frames; ++i) {
    const double tau = w.tau_of_frame(i);
    if (tau >= from_s && tau < to_s) {
      markers.lab_m.block(i, 3 * marker, 1, 3).setConstant(std::nan(""));
      ++n;
    }
  }
  return n;
}
}  // namespace

// Digitised tracks as labs have them: 4-5-frame gaps in the contact window,
// in either base marker, and two gaps in a row (8 frames, as when a gap in
// one camera abuts one in the other): 13 of imp_base_back's frames, 18 % of
// the window. The trial is kept and measured as if whole; the old rule
// (90 % of frames, no gap over 5 ms) threw such trials away (validation
// v2's fastest trial).
TEST(Trial, LabDigitisingGapsKeepTheTrial) {
  const World w = make_world(WorldOptions{});
  const double t_bottom_s = bottom_time_s(w);
  dropfit::reconstruction::Trajectories markers = w.markers;
  const int back = blank(markers, w, 1, 0.008, 0.013) + blank(markers, w, 1, t_bottom_s + 0.008, t_bottom_s + 0.016);
  const int front = blank(markers, w, 0, t_bottom_s - 0.012, t_bottom_s - 0.008);
  ASSERT_EQ(back, 13);
  ASSERT_EQ(front, 4);
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), markers, trial_options(w));
  EXPECT_TRUE(r.accepted) << r.reject_reason;
  EXPECT_NEAR(r.max_deformation_m, w.max_penetration_m, 1e-3);
  EXPECT_NEAR(r.impact_velocity_m_s, w.o.impact_speed_m_s, 0.02);
  // The same gaps under the old rule (90 % of frames, no gap over 5 ms).
  tr::TrialOptions strict = trial_options(w);
  strict.min_marker_coverage = 0.90;
  strict.max_marker_gap_s = 0.005;
  const tr::TrialResult old = tr::analyse(fp::process(w.raw, force_options(w)), markers, strict);
  EXPECT_FALSE(old.accepted);
  EXPECT_TRUE(contains(old.reject_reason, "imp_base_back (82 % of frames, longest gap 8 ms)")) << old.reject_reason;
}

// A 5-frame gap ending at the bottom: the parabola bridges it (its window
// doubles) and the trial is kept with the bottom measured.
TEST(Trial, GapBesideTheLowestPointIsBridged) {
  const World w = make_world(WorldOptions{});
  const double t_bottom_s = bottom_time_s(w);
  dropfit::reconstruction::Trajectories markers = w.markers;
  ASSERT_EQ(blank(markers, w, 0, t_bottom_s - 0.0055, t_bottom_s - 0.0005), 5);  // imp_base_front
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), markers, trial_options(w));
  EXPECT_TRUE(r.accepted) << r.reject_reason;
  EXPECT_NEAR(r.max_deformation_m, w.max_penetration_m, 1e-3);
  EXPECT_NEAR(r.max_deformation_time_s + w.tau_trigger_s, t_bottom_s, 1.5e-3);
}

// The impactor's lowest point inside a gap cannot be measured: the trial is
// rejected with that reason, not given the edge of the gap as its bottom.
TEST(Trial, LowestPointInAGapIsRejected) {
  const World w = make_world(WorldOptions{});
  const double t_bottom_s = bottom_time_s(w);
  dropfit::reconstruction::Trajectories markers = w.markers;
  ASSERT_EQ(blank(markers, w, 0, t_bottom_s - 0.0045, t_bottom_s + 0.0045), 9);  // imp_base_front
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, "lowest point")) << r.reject_reason;
  EXPECT_FALSE(contains(r.reject_reason, "markers missing")) << r.reject_reason;
}

// A short gap is tolerated, and the series shows it as NaN, never filled.
TEST(Trial, ShortGapStaysAGapInTheSeries) {
  const World w = make_world(WorldOptions{});
  dropfit::reconstruction::Trajectories markers = w.markers;
  std::set<int> gap;
  for (int i = 0; i < w.o.frames; ++i) {
    const double tau = w.tau_of_frame(i);
    if (tau > 0.020 && tau < 0.023) {
      markers.lab_m(i, 2) = std::nan("");
      gap.insert(i);
    }
  }
  ASSERT_EQ(gap.size(), 3u);
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), markers, trial_options(w));
  EXPECT_TRUE(r.accepted) << r.reject_reason;
  int nan_rows = 0;
  for (Eigen::Index k = 0; k < r.series.t_s.size(); ++k) {
    const double u = (r.series.t_s[k] + r.video_offset_s) * w.o.fps_hz + w.o.trigger_frame;
    const int i = static_cast<int>(std::floor(u));
    const bool touches_gap = gap.count(i) > 0 || (u > i && gap.count(i + 1) > 0);
    EXPECT_EQ(std::isnan(r.series.impactor_z_m[k]), touches_gap) << "sample " << k;
    nan_rows += std::isnan(r.series.impactor_z_m[k]);
  }
  EXPECT_GE(nan_rows, 3);
}

// The plate's Fz cable unplugged: no trigger. Rejected with the forceplate's
// reason, video measurements still there.
TEST(Trial, NoTriggerIsRejectedWithVideoStillMeasured) {
  const World w = make_world(WorldOptions{});
  fp::Resultants raw = w.raw;
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 1.0);
  Eigen::MatrixXd ch = raw.channels_n;
  for (int i = 0; i < ch.rows(); ++i) {
    for (int c = 4; c < 8; ++c) ch(i, c) = noise(rng);
  }
  raw = fp::from_eight_channels(raw.t_s, ch, fp::PlateGeometry{});
  const tr::TrialResult r = tr::analyse(raw, force_options(w), w.markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, "no trigger")) << r.reject_reason;
  EXPECT_NEAR(r.impact_velocity_m_s, w.o.impact_speed_m_s, 0.02);
  EXPECT_NEAR(r.max_deformation_m, w.max_penetration_m, 1e-3);
  EXPECT_TRUE(std::isnan(r.peak_force_n));
}

TEST(Trial, WithoutForceTheVideoIsStillMeasured) {
  const World w = make_world(WorldOptions{});
  const tr::TrialResult r = tr::analyse_without_force(w.markers, trial_options(w), "force record: 7 channels");
  EXPECT_FALSE(r.accepted);
  EXPECT_EQ(r.reject_reason, "force record: 7 channels");
  EXPECT_NEAR(r.impact_velocity_m_s, w.o.impact_speed_m_s, 0.02);
  EXPECT_NEAR(r.max_deformation_m, w.max_penetration_m, 1e-3);
  EXPECT_LT(r.tilt_deg, 1.0);
  EXPECT_EQ(r.series.t_s.size(), 0);
}

TEST(Trial, SaturatedChannelIsRejected) {
  const World w = make_world(WorldOptions{});
  Eigen::MatrixXd ch = w.raw.channels_n;
  ch.col(5) = ch.col(5).cwiseMin(0.7 * ch.col(5).maxCoeff());
  const fp::Resultants raw = fp::from_eight_channels(w.raw.t_s, ch, fp::PlateGeometry{});
  const tr::TrialResult r = tr::analyse(raw, force_options(w), w.markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, "saturated") && contains(r.reject_reason, "Fz2")) << r.reject_reason;
  EXPECT_NEAR(r.impact_velocity_m_s, w.o.impact_speed_m_s, 0.02);
}

// One sample 20 % of the peak above its neighbours, 3 ms after the peak
// (about 1.6 kN on this world's 8.2 kN peak): no mat force does that within
// a millisecond; rejected, naming the sample. The 50 % gate this replaced
// let it through.
TEST(Trial, ASpikeOfAFifthOfThePeakIsRejected) {
  const World w = make_world(WorldOptions{});
  Eigen::MatrixXd ch = w.raw.channels_n;
  const Eigen::VectorXd fz = ch.middleCols(4, 4).rowwise().sum();
  Eigen::Index k_peak = 0;
  fz.maxCoeff(&k_peak);
  const Eigen::Index k = k_peak + 3;
  for (int c = 4; c < 8; ++c) ch(k, c) += 0.2 * fz(k_peak) / 4.0;
  const fp::Resultants raw = fp::from_eight_channels(w.raw.t_s, ch, fp::PlateGeometry{});
  const tr::TrialResult r = tr::analyse(raw, force_options(w), w.markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, fmt::format("single-sample spike at sample {}", k))) << r.reject_reason;
  const tr::TrialResult clean = tr::analyse(w.raw, force_options(w), w.markers, trial_options(w));
  EXPECT_TRUE(clean.accepted) << clean.reject_reason;
}

// The same spike 15 ms into the free flight after the contact: it would add
// its impulse to the plate's balance against the impactor's momentum (a
// false force scale of about 1 % on the independent world's linear control
// with 3 kN), so it rejects too, saying where it is.
TEST(Trial, ASpikeInTheFreeFlightAfterTheContactIsRejected) {
  const World w = make_world(WorldOptions{});
  Eigen::MatrixXd ch = w.raw.channels_n;
  const Eigen::VectorXd fz = ch.middleCols(4, 4).rowwise().sum();
  Eigen::Index k_end = 0;
  for (Eigen::Index k = 0; k < fz.size(); ++k)
    if (fz(k) > 0.05 * fz.maxCoeff()) k_end = k;
  const Eigen::Index k = k_end + 15;
  ASSERT_LT(k, fz.size() - 1);
  for (int c = 4; c < 8; ++c) ch(k, c) += 0.2 * fz.maxCoeff() / 4.0;
  const fp::Resultants raw = fp::from_eight_channels(w.raw.t_s, ch, fp::PlateGeometry{});
  const tr::TrialResult r = tr::analyse(raw, force_options(w), w.markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, fmt::format("single-sample spike at sample {}", k))) << r.reject_reason;
  EXPECT_TRUE(contains(r.reject_reason, "after the contact")) << r.reject_reason;
}

// A wrong trigger_frame: the clocks disagree by far more than a camera can
// drift; rejected, with the offset still measured.
TEST(Trial, ClocksFarApartAreRejected) {
  WorldOptions wo;
  wo.true_offset_s = 0.080;
  const World w = make_world(wo);
  const tr::TrialResult r = tr::analyse(fp::process(w.raw, force_options(w)), w.markers, trial_options(w));
  EXPECT_FALSE(r.accepted);
  EXPECT_TRUE(contains(r.reject_reason, "trigger_frame")) << r.reject_reason;
  EXPECT_NEAR(r.video_offset_s, 0.080, 0.2e-3);
}

TEST(Trial, BadOptionsThrow) {
  const World w = make_world(WorldOptions{});
  const fp::ForceTrial force = fp::process(w.raw, force_options(w));
  tr::TrialOptions o = trial_options(w);
  o.base_markers = {0, 9};
  EXPECT_THROW(tr::analyse(force, w.markers, o), dropfit::Error);
  o.base_markers.clear();
  EXPECT_THROW(tr::analyse(force, w.markers, o), dropfit::Error);
}

// Student t quantiles against the tabulated values.
TEST(Trial, StudentTQuantiles) {
  EXPECT_NEAR(tr::student_t_quantile(0.975, 1), 12.706205, 1e-5);
  EXPECT_NEAR(tr::student_t_quantile(0.975, 10), 2.228139, 1e-5);
  EXPECT_NEAR(tr::student_t_quantile(0.95, 5), 2.015048, 1e-5);
  EXPECT_NEAR(tr::student_t_quantile(0.975, 1e6), 1.959966, 1e-5);
  EXPECT_NEAR(tr::student_t_quantile(0.025, 10), -2.228139, 1e-5);
}

// The 95 % interval of the impact speed covers the truth about 95 % of the time.
TEST(Trial, ImpactSpeedIntervalCoversTheTruth) {
  std::mt19937 rng(3);
  std::normal_distribution<double> noise(0.0, 0.5e-3);
  const double g = 9.81, v = 5.0, top = 0.2;
  int covered = 0;
  const int runs = 400;
  for (int run = 0; run < runs; ++run) {
    const double phase = (run % 10) * 1e-4;
    Eigen::VectorXd t(40), z(40);
    for (int i = 0; i < 40; ++i) {
      t[i] = -0.040 + i * 1e-3 + phase;  // contact at t = 0
      z[i] = top - v * t[i] - 0.5 * g * t[i] * t[i] + noise(rng);
    }
    const tr::FreeFallFit f = tr::fit_free_fall(t, z, g, top, 0.0);
    ASSERT_TRUE(f.ok);
    covered += std::abs(f.contact_speed_m_s - v) <= f.contact_speed_ci_m_s;
    EXPECT_NEAR(f.contact_time_s, 0.0, 0.5e-3);
  }
  EXPECT_GT(covered, 0.90 * runs);
  EXPECT_LT(covered, 0.99 * runs);
}

TEST(Trial, ImpactSpeedIntervalWithTheCalibrationsScaleCoversTheTruth) {
  // Each session's calibration scales vertical lengths by 1 + e, e ~ N(0,
  // s), s = the check markers' z RMS over the markers' z span (0.3 mm over
  // 0.75 m: 4e-4, 2 mm/s at 5 m/s): the free-fall fit's interval alone
  // misses that; widened by it, it covers the truth 95 % of the time.
  dropfit::calibration::CalibrationResult calibration;
  calibration.check_rms_m = Eigen::Vector3d(0.4e-3, 0.35e-3, 0.3e-3);
  const tr::CalibrationQuality quality = tr::calibration_quality(calibration, 0.75);
  ASSERT_NEAR(quality.vertical_scale_sd, 4e-4, 1e-12);
  EXPECT_TRUE(std::isnan(tr::calibration_quality(calibration).vertical_scale_sd));  // no span: unknown
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.1e-3), scale(0.0, quality.vertical_scale_sd);
  const double g = 9.81, v = 5.0, top = 0.2;
  int fit_only = 0, widened = 0;
  const int runs = 400;
  for (int run = 0; run < runs; ++run) {
    const double e = scale(rng);
    Eigen::VectorXd t(40), z(40);
    for (int i = 0; i < 40; ++i) {
      t[i] = -0.040 + i * 1e-3;
      z[i] = top + (1.0 + e) * (-v * t[i] - 0.5 * g * t[i] * t[i]) + noise(rng);
    }
    const tr::FreeFallFit f = tr::fit_free_fall(t, z, g, top, 0.0);
    ASSERT_TRUE(f.ok);
    tr::TrialResult r;
    r.impact_velocity_m_s = f.contact_speed_m_s;
    r.impact_velocity_ci_m_s = f.contact_speed_ci_m_s;
    fit_only += std::abs(r.impact_velocity_m_s - v) <= r.impact_velocity_ci_m_s;
    tr::add_calibration_uncertainty(r, quality);
    EXPECT_GT(r.impact_velocity_ci_m_s, f.contact_speed_ci_m_s);
    widened += std::abs(r.impact_velocity_m_s - v) <= r.impact_velocity_ci_m_s;
  }
  std::printf("interval covers the truth: fit alone %d, with the calibration's scale %d of %d\n", fit_only, widened,
              runs);
  EXPECT_LT(fit_only, 0.85 * runs);
  EXPECT_GT(widened, 0.91 * runs);
  EXPECT_LT(widened, 0.99 * runs);
}

// The free-fall fit's contact instant and speed errors: their stated SEs
// and covariance match their spread over 1000 noisy fits (within 8 % for
// the SEs, 0.1 for the correlation).
TEST(Trial, ContactInstantAndSpeedErrorsMatchTheirSpread) {
  std::mt19937 rng(17);
  std::normal_distribution<double> noise(0.0, 0.3e-3);
  const double g = 9.81, v = 5.0, top = 0.2;
  const int runs = 1000;
  double st = 0, st2 = 0, sv = 0, sv2 = 0, stv = 0, se_t2 = 0, se_v2 = 0, cov = 0;
  for (int run = 0; run < runs; ++run) {
    Eigen::VectorXd t(60), z(60);
    for (int i = 0; i < 60; ++i) {
      t[i] = -0.061 + i * 1e-3;  // contact at t = 0
      z[i] = top - v * t[i] - 0.5 * g * t[i] * t[i] + noise(rng);
    }
    const tr::FreeFallFit f = tr::fit_free_fall(t, z, g, top, -0.001);
    ASSERT_TRUE(f.ok);
    st += f.contact_time_s, st2 += f.contact_time_s * f.contact_time_s;
    sv += f.contact_speed_m_s - v, sv2 += (f.contact_speed_m_s - v) * (f.contact_speed_m_s - v);
    stv += f.contact_time_s * (f.contact_speed_m_s - v);
    se_t2 += f.contact_time_se_s * f.contact_time_se_s, se_v2 += f.contact_speed_se_m_s * f.contact_speed_se_m_s;
    cov += f.speed_time_cov;
  }
  const double sd_t = std::sqrt(st2 / runs - st * st / runs / runs), sd_v = std::sqrt(sv2 / runs - sv * sv / runs / runs);
  const double corr = (stv / runs - st * sv / runs / runs) / (sd_t * sd_v);
  EXPECT_NEAR(std::sqrt(se_t2 / runs) / sd_t, 1.0, 0.08);
  EXPECT_NEAR(std::sqrt(se_v2 / runs) / sd_v, 1.0, 0.08);
  EXPECT_NEAR(cov / runs / (std::sqrt(se_t2 / runs) * std::sqrt(se_v2 / runs)), corr, 0.1);
  EXPECT_LT(corr, -0.5);  // a fit reading the speed high puts the contact early
}

// A calibration that was not checked (coefficients given, no check
// markers) keeps a calibration term: the declared scale accuracy, said so.
TEST(Trial, UncheckedCalibrationKeepsADeclaredTerm) {
  const tr::CalibrationQuality unchecked;  // no check markers: vertical_scale_sd NaN
  tr::TrialResult r;
  r.impact_velocity_m_s = 5.0;
  r.impact_velocity_ci_m_s = 0.0023;
  r.contact_height_m = 0.205;
  tr::add_calibration_uncertainty(r, unchecked);
  EXPECT_NEAR(r.impact_velocity_ci_m_s, std::hypot(0.0023, 1.96 * 5.0 * tr::kDeclaredCalibrationScaleSd), 1e-12);
  EXPECT_EQ(r.calibration_scale_sd, tr::kDeclaredCalibrationScaleSd);
  EXPECT_EQ(r.calibration_uncertainty.rfind("declared", 0), 0u) << r.calibration_uncertainty;
  EXPECT_NEAR(r.contact_height_se_m, 0.205 * tr::kDeclaredCalibrationScaleSd, 1e-12);  // the manifest's mat top

  dropfit::calibration::CalibrationResult checked_calibration;
  checked_calibration.check_rms_m = Eigen::Vector3d(0.4e-3, 0.35e-3, 0.3e-3);
  tr::TrialResult c;
  c.impact_velocity_m_s = 5.0;
  c.impact_velocity_ci_m_s = 0.0023;
  tr::add_calibration_uncertainty(c, tr::calibration_quality(checked_calibration, 0.75));
  EXPECT_EQ(c.calibration_uncertainty, "check markers");
  EXPECT_NEAR(c.calibration_scale_sd, 4e-4, 1e-12);
}

TEST(Trial, BaseTiltFromTwoOrMoreMarkers) {
  const double a = 7.0 * kPi / 180.0;
  EXPECT_NEAR(tr::base_tilt_deg({{0, 0, 0}, {0.2 * std::cos(a), 0.1, 0.2 * std::sin(a)}}),
              std::asin(0.2 * std::sin(a) / std::hypot(0.2 * std::cos(a), 0.1, 0.2 * std::sin(a))) * 180.0 / kPi,
              1e-9);
  const Eigen::Matrix3d rot = Eigen::AngleAxisd(a, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  EXPECT_NEAR(tr::base_tilt_deg({rot * Eigen::Vector3d(0.1, 0, 0), rot * Eigen::Vector3d(0, 0.1, 0),
                                 rot * Eigen::Vector3d(-0.1, -0.05, 0)}),
              7.0, 1e-9);
  EXPECT_TRUE(std::isnan(tr::base_tilt_deg({{0, 0, 0}, {std::nan(""), 0, 0}})));
}

// The trajectory match on its own: a force ramping from zero at t = 0 on a
// 1 kHz record, the face's lag behind free fall its double integral over the
// mass, seen 1.37 ms late on the video clock; the shift comes back within
// 0.01 ms (the grid's step; the parabola does better on a smooth cost), and
// fewer than ten lag points give NaN.
TEST(TrajectoryShift, FindsTheShiftOfTheForcesDoubleIntegral) {
  const double m = 24.0, a = 4e5, shift = 1.37e-3;  // force a t (N) from t = 0
  const int n = 200;
  Eigen::VectorXd t(n), f(n);
  for (int k = 0; k < n; ++k) {
    t[k] = -0.02 + 1e-3 * k;
    f[k] = t[k] > 0.0 ? a * t[k] : 0.0;
  }
  std::vector<double> lt, lag;
  for (int i = 0; i < 60; ++i) {
    const double tv = 0.002 + 1e-3 * i, tf = tv - shift;  // video time, force time
    lt.push_back(tv);
    lag.push_back(tf > 0.0 ? a * tf * tf * tf / (6.0 * m) : 0.0);
  }
  EXPECT_NEAR(dropfit::trial::trajectory_shift_s(t, f, 0, m, lt, lag, 0.0), shift, 1e-5);
  EXPECT_NEAR(dropfit::trial::trajectory_shift_s(t, f, 0, m, lt, lag, 0.002), shift, 1e-5);
  lt.resize(9);
  lag.resize(9);
  EXPECT_TRUE(std::isnan(dropfit::trial::trajectory_shift_s(t, f, 0, m, lt, lag, 0.0)));
}

namespace dropfit::trial {
namespace {

// The free fall's own acceleration: exact on a noise-free parabola; on 4000
// noisy ones (0.5 mm, 100 frames over 0.1 s) its SE matches its scatter
// (RMS z within 0.93-1.07) and 95 +- 1.5 % of the intervals hold the truth
// (the binomial SE is 0.34 %).
TEST(FallAcceleration, RecoversTheFallWithAnHonestSE) {
  const int n = 100;
  Eigen::VectorXd t(n), z(n);
  for (int i = 0; i < n; ++i) t[i] = -0.1 + 1e-3 * i;
  const auto path = [&](double a, double v0) {
    for (int i = 0; i < n; ++i) z[i] = 0.7 - v0 * t[i] - 0.5 * a * t[i] * t[i];
  };
  path(9.81, 4.5);
  const FallAcceleration exact = fit_fall_acceleration(t, z);
  ASSERT_TRUE(exact.ok);
  EXPECT_NEAR(exact.accel_m_s2, 9.81, 1e-9);
  EXPECT_EQ(exact.n_frames, n);
  EXPECT_NEAR(exact.span_s, 0.099, 1e-12);

  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 5e-4);
  double sz2 = 0.0;
  int covered = 0;
  const int reps = 4000;
  for (int k = 0; k < reps; ++k) {
    path(9.81, 4.5);
    for (int i = 0; i < n; ++i) z[i] += noise(rng);
    const FallAcceleration f = fit_fall_acceleration(t, z);
    ASSERT_TRUE(f.ok);
    const double zk = (f.accel_m_s2 - 9.81) / f.se_m_s2;
    sz2 += zk * zk;
    covered += std::abs(zk) <= 1.96;
  }
  EXPECT_NEAR(std::sqrt(sz2 / reps), 1.0, 0.07);
  EXPECT_NEAR(covered / static_cast<double>(reps), 0.95, 0.015);
}

// The gate: a fall at g passes; one at g (1050 / 1000)^2 (a 1000 Hz video
// declared at 1050 Hz) is rejected naming the 1000 Hz that makes it free; a
// guide's friction (10 % slow) passes; a fall that is no fall names the rate.
TEST(FallAcceleration, GateNamesTheFrameRateThatMakesTheFallFree) {
  TrialOptions o;
  o.frame_rate_hz = 1050.0;
  FallAcceleration f;
  f.ok = true;
  f.n_frames = 99;
  f.span_s = 0.094;
  f.se_m_s2 = 0.06;
  f.accel_m_s2 = 9.81;
  EXPECT_EQ(fall_acceleration_reason(f, o), "");
  f.accel_m_s2 = 0.9 * 9.81;
  EXPECT_EQ(fall_acceleration_reason(f, o), "");
  f.accel_m_s2 = 9.81 * 1.05 * 1.05;
  const std::string r = fall_acceleration_reason(f, o);
  EXPECT_NE(r.find("falls at 10.82 +- 0.06 m/s^2"), std::string::npos) << r;
  EXPECT_NE(r.find("frame_rate_hz = 1050 Hz would have to be 1000 Hz"), std::string::npos) << r;
  f.accel_m_s2 = -0.5;
  EXPECT_NE(fall_acceleration_reason(f, o).find("does not fall"), std::string::npos);
}

}  // namespace
}  // namespace dropfit::trial
