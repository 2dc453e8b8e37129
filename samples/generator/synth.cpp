// Synthetic drop-test sessions with known truth: see synth.h for the world
// it simulates. Everything here is plain computation; the only file this
// file writes is the truth JSON (write_truth_json, at the end).
//
// Default Model 4 parameters: a quick scan about the paper's Table 2 Model 4
// set (k1 72075, k2 1061532, k3 748625 N/m; r1 263, r2 761, r3 1007 N s/m;
// m1 2.44, m2 3.66 kg): k1 x {0.9, 1.0, 1.1, 1.2, 1.3}, k2 and k3 x {0.8, 1,
// 1.25}, each r x {0.5, 1, 2, 3}, scored by the summed squared relative
// errors of peak GRF and largest impactor travel against the paper's Table 1
// over its five velocities. Kept: k1 x 1.1, k2 x 0.8, k3 x 1, every r x 0.5:
//   k1 79282.5, k2 849226, k3 748625 N/m; r1 131.5, r2 380.5, r3 503.5 N s/m
//   v (m/s)          4.30    4.80    5.25    5.75    6.50
//   peak GRF (N)     5718    6355    6929    7566    8523   (Table 1: 5593-9597)
//   deformation (m)  0.0804  0.0894  0.0975  0.1064  0.1199 (Table 1: 0.088-0.118)
//   time to peak 29 ms, separation after 60 ms.
// (A linear model cannot follow the real mat's stiffening: its peak force
// and deformation both grow in proportion to v; the scan's optimum with
// damping x 0.25 fitted slightly better but bounced back more than a landing
// mat does.)
#include "samples/generator/synth.h"

#include <Eigen/Geometry>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iterator>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>

#include "core/atomic_file.h"
#include "core/error.h"

namespace dropfit::synth {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
constexpr double kSimDt = 1e-5;  // output step of the physics (simulate_chain), interpolated linearly

// ---- Random numbers: deterministic on every platform --------------------
// mt19937_64's output is fixed by the standard; the distributions of
// <random> are not, so uniform and normal are written out here. Each use has
// its own stream (seed, stream id), so that switching an effect on does not
// change the draws of anything else.
std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

class Rng {
 public:
  Rng(std::uint64_t seed, std::uint64_t stream) : engine_(splitmix64(seed ^ splitmix64(stream + 0x51ED2701ull))) {}
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }  // [0, 1)
  double normal() {                                                             // Box-Muller
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    double u1 = uniform();
    while (u1 <= 0.0) u1 = uniform();
    const double u2 = uniform();
    const double r = std::sqrt(-2.0 * std::log(u1));
    spare_ = r * std::sin(2.0 * kPi * u2);
    has_spare_ = true;
    return r * std::cos(2.0 * kPi * u2);
  }

 private:
  std::mt19937_64 engine_;
  bool has_spare_ = false;
  double spare_ = 0.0;
};

// Stream ids.
constexpr std::uint64_t kStreamCalibrationNoise = 1;
constexpr std::uint64_t kStreamOutlier = 2;
constexpr std::uint64_t kStreamLayout = 3;
constexpr std::uint64_t kStreamGaps = 3000;  // + trial index
constexpr std::uint64_t kStreamTrial = 100;       // + trial index: tilt, impact point, shear, offsets
constexpr std::uint64_t kStreamForceNoise = 1000;  // + trial index: contact phase and channel noise
constexpr std::uint64_t kStreamPixelNoise = 2000;  // + trial index

// Rounds to the writers' six decimals, so that what read_session returns
// equals the in-memory session bit for bit (N / 1e6 is correctly rounded,
// as strtod is).
double six_decimals(double v) { return std::isfinite(v) ? std::round(v * 1e6) / 1e6 : v; }

// Linear interpolation of a series sampled every dt from 0; clamps at the ends.
double interp(const Eigen::VectorXd& y, double t, double dt) {
  const Eigen::Index n = y.size();
  if (n == 0) return 0.0;
  const double x = t / dt;
  if (x <= 0.0) return y(0);
  const auto k = static_cast<Eigen::Index>(std::floor(x));
  if (k >= n - 1) return y(n - 1);
  const double f = x - static_cast<double>(k);
  return (1.0 - f) * y(k) + f * y(k + 1);
}

std::string model_key(ModelChoice kind) { return fmt::format("model{}", kind.number); }

void require(bool ok, const std::string& reason) {
  if (!ok) throw Error("dropfit-synth: " + reason);
}

void validate(const SynthOptions& o) {
  require(!o.impact_velocities_m_s.empty(), "no trials: impact_velocities_m_s is empty");
  for (double v : o.impact_velocities_m_s)
    require(std::isfinite(v) && v > 0.0, fmt::format("impact velocity {} m/s must be positive", v));
  require(o.gravity_m_s2 > 0.0, "gravity must be positive");
  require(o.impactor_mass_kg > 0.0, "impactor mass must be positive");
  require(o.footprint_m.minCoeff() > 0.0, "impactor footprint must be positive");
  require(o.mat_length_m > 0.0 && o.mat_width_m > 0.0, "mat size must be positive");
  require(!o.layers.empty(), "the mat needs at least one layer");
  for (const LayerSpec& l : o.layers)
    require(l.thickness_m > 0.0 && l.mass_kg >= 0.0, fmt::format("layer '{}' needs a positive thickness", l.name));
  require(o.image_width_px > 0 && o.image_height_px > 0, "image size must be positive");
  require(o.camera_angle_deg > 10.0 && o.camera_angle_deg < 170.0, "camera angle must be within 10-170 deg");
  require(o.camera_distance_m > 0.5, "cameras must stand at least 0.5 m from the volume");
  require(o.image_fill > 0.0 && o.image_fill <= 1.0, "image_fill must be within (0, 1]");
  require(o.pixel_noise_px >= 0.0, "pixel noise must not be negative");
  require(o.extra_distortion.size() == 4, "extra_distortion holds k2 p1 p2 k3 (4 values)");
  require(o.frame_rate_hz > 0.0 && o.force_rate_hz > 0.0, "frame and sample rates must be positive");
  require(o.n_frames >= 2, "at least two video frames");
  require(o.trigger_frame >= 0 && o.trigger_frame < o.n_frames,
          fmt::format("trigger_frame {} outside the {} frames", o.trigger_frame, o.n_frames));
  require(o.n_samples >= 2, "at least two force samples");
  require(o.pretrigger_fraction > 0.0 && o.pretrigger_fraction < 1.0, "pretrigger_fraction must be within (0, 1)");
  const long npre = std::lround(o.pretrigger_fraction * o.n_samples);
  require(npre >= 1 && npre < o.n_samples,
          fmt::format("pretrigger fraction {} of {} samples leaves no pre-trigger part", o.pretrigger_fraction,
                      o.n_samples));
  require(o.trigger_threshold_n > 0.0, "trigger threshold must be positive");
  require(o.channel_noise_n >= 0.0 && o.channel_offset_sd_n >= 0.0, "channel noise and offsets must not be negative");
  require(o.effects.force_scale > 0.0, "force_scale must be positive");
  require(o.digitised_from_s < o.digitised_to_s, "the digitised window must end after it starts");
  require(o.random_gaps_per_trial >= 0 && o.gap_max_frames >= 1, "random gaps: a count >= 0 and lengths >= 1 frame");
  require(o.mat_marker_min_radius_m > 0.0 && o.mat_marker_max_radius_m >= o.mat_marker_min_radius_m &&
              o.mat_marker_max_radius_m < 0.5 * std::max(o.mat_length_m, o.mat_width_m) &&
              o.mat_marker_min_radius_m < 0.5 * std::min(o.mat_length_m, o.mat_width_m),
          "mat marker radii must be positive, ordered and on the mat");
  require(o.dish_width_m > 0.0, "dish width must be positive");
  require(o.effects.lens_distortion_px >= 0.0, "lens_distortion_px must not be negative");
  require(o.effects.hysteresis_h >= 0.0 && o.effects.hysteresis_h < 1.0, "hysteresis_elastic h must lie in [0, 1)");
  require(o.effects.outlier_marker_px >= 0.0, "outlier_marker must not be negative");
  const InstrumentFaults& f = o.faults;
  for (int c : {f.dead_channel, f.reversed_channel, f.exchange_a, f.exchange_b})
    require(c >= -1 && c < 8, fmt::format("fault channel {} is not one of 0-7", c));
  require(f.saturation_n >= 0.0 && f.amplifier_lowpass_hz >= 0.0 && f.declared_mass_kg >= 0.0,
          "saturation, low-pass corner and declared mass must not be negative");
  require(f.amplifier_lowpass_order == 2 || f.amplifier_lowpass_order == 4, "the low-pass order is 2 or 4");
  require(f.softening_per_trial >= 0.0 && f.softening_per_trial < 1.0, "softening per trial must lie in [0, 1)");
  for (const Gap& g : o.gaps)
    require(g.trial >= 0 && g.trial < static_cast<int>(o.impact_velocities_m_s.size()) && g.n_frames >= 0 &&
                g.first_frame >= 0,
            fmt::format("gap of trial {} frames {}+{}: no such trial or a negative frame", g.trial + 1,
                        g.first_frame, g.n_frames));
}

// ---- Cameras ------------------------------------------------------------

Eigen::Vector2d pinhole_px(const TrueCamera& cam, const Eigen::Vector3d& lab_m, double* depth_m = nullptr) {
  const Eigen::Vector3d c = cam.cam_from_lab_r * lab_m + cam.cam_from_lab_t;
  if (depth_m) *depth_m = c.z();
  const Eigen::Vector3d h = cam.k * c;
  return h.head<2>() / h.z();
}

bool in_image(const TrueCamera& cam, const Eigen::Vector2d& px, double depth_m) {
  return depth_m > 0.0 && px.allFinite() && px.x() >= 0.0 && px.x() < cam.width_px && px.y() >= 0.0 &&
         px.y() < cam.height_px;
}

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

// ---- Impactor pose ---------------------------------------------------------
// Rotation of the impactor (its frame: X front, Z up from the face) whose
// face has travel slopes (sx, sy) = d(travel)/dx, d(travel)/dy: positive sx
// means the +x side is lower. (sx, 0) is a rotation by atan(sx) about +Y.
Eigen::Matrix3d impactor_rotation(double sx, double sy) {
  const Eigen::Vector3d ex = Eigen::Vector3d(1.0, 0.0, -sx).normalized();
  Eigen::Vector3d ey(0.0, 1.0, -sy);
  ey = (ey - ey.dot(ex) * ex).normalized();
  Eigen::Matrix3d r;
  r.col(0) = ex;
  r.col(1) = ey;
  r.col(2) = ex.cross(ey);
  return r;
}

double deviation_deg(double sx, double sy) { return std::atan(std::hypot(sx, sy)) / kDeg; }


}  // namespace

// ---- Public pieces ----------------------------------------------------------

std::vector<std::string> effect_names() {
  return {"lens_distortion",        "lens_distortion_px", "outlier_marker",     "outlier_swap",
          "time_offset",            "baseline_drift",     "force_scale",        "stiffness_nonlinearity",
          "hysteresis",             "hysteresis_elastic", "rate_dependence",    "layer_mass"};
}

void set_effect(Effects& e, const std::string& name, double magnitude) {
  if (!std::isfinite(magnitude)) throw Error(fmt::format("effect {}: magnitude must be finite", name));
  if (name == "lens_distortion")
    e.lens_distortion_k1 = magnitude;
  else if (name == "lens_distortion_px")
    e.lens_distortion_px = magnitude;
  else if (name == "outlier_swap")
    e.outlier_swap = magnitude != 0.0;
  else if (name == "hysteresis_elastic")
    e.hysteresis_h = magnitude;
  else if (name == "outlier_marker")
    e.outlier_marker_px = magnitude;
  else if (name == "time_offset")
    e.time_offset_ms = magnitude;
  else if (name == "baseline_drift")
    e.baseline_drift_n_s = magnitude;
  else if (name == "force_scale")
    e.force_scale = magnitude;
  else if (name == "stiffness_nonlinearity")
    e.k1_cubic_n_m3 = magnitude;
  else if (name == "hysteresis")
    e.r1_unload_n_s_m = magnitude;
  else if (name == "rate_dependence")
    e.maxwell_k_n_m = magnitude;
  else if (name == "layer_mass")
    e.layer_mass_shift_kg = magnitude;
  else
    throw Error(fmt::format("unknown effect '{}' (known: {})", name, fmt::join(effect_names(), ", ")));
}

std::vector<std::string> fault_names() {
  return {"dead_channel", "reversed_channel", "exchanged_channels", "saturation", "amplifier_lowpass",
          "softening",    "declared_mass",    "second_impact"};
}

void set_fault(SynthOptions& o, const std::string& name, double magnitude) {
  if (!std::isfinite(magnitude)) throw Error(fmt::format("fault {}: magnitude must be finite", name));
  InstrumentFaults& f = o.faults;
  const int whole = static_cast<int>(std::lround(magnitude));
  if (name == "dead_channel")
    f.dead_channel = whole;
  else if (name == "reversed_channel")
    f.reversed_channel = whole;
  else if (name == "exchanged_channels")
    f.exchange_a = whole / 10, f.exchange_b = whole % 10;
  else if (name == "saturation")
    f.saturation_n = magnitude;
  else if (name == "amplifier_lowpass")
    f.amplifier_lowpass_hz = magnitude;
  else if (name == "softening")
    f.softening_per_trial = magnitude;
  else if (name == "declared_mass")
    f.declared_mass_kg = magnitude;
  else if (name == "second_impact")
    o.catch_at_apex = magnitude == 0.0;
  else
    throw Error(fmt::format("unknown fault '{}' (known: {})", name, fmt::join(fault_names(), ", ")));
}

MatParams default_mat_params(ModelChoice model_choice, const std::vector<LayerSpec>& layers) {
  const ModelKind model = model_choice.kind();
  MatParams p;
  double total = 0.0;
  for (const LayerSpec& l : layers) total += l.mass_kg;
  const double m2 = layers.empty() ? 0.0 : layers.back().mass_kg;
  const double m1 = total - m2;
  switch (model) {
    case ModelKind::Model1:  // Table 2, Model 1
      p.k1_n_m = 84183.0;
      p.r1_n_s_m = 5700.0;
      break;
    case ModelKind::Model2:  // Table 2, Model 2; m_eff not published: 40 % of the mat
      p.k1_n_m = 84183.0;
      p.r1_n_s_m = 5700.0;
      p.m_eff_kg = 0.4 * total;
      break;
    case ModelKind::Model3:  // Table 2, Model 3
      p.k1_n_m = 76700.0;
      p.k2_n_m = 807380.0;
      p.r1_n_s_m = 490.0;
      p.r2_n_s_m = 980.0;
      p.m1_kg = m1;
      p.m2_kg = m2;
      break;
    case ModelKind::Model4:  // scanned about Table 2 (header comment)
      p.k1_n_m = 79282.5;
      p.k2_n_m = 849226.0;
      p.k3_n_m = 748625.0;
      p.r1_n_s_m = 131.5;
      p.r2_n_s_m = 380.5;
      p.r3_n_s_m = 503.5;
      p.m1_kg = m1;
      p.m2_kg = m2;
      break;
    case ModelKind::Model5:  // Table 2, Model 5
      p.k1_n_m = 70880.0;
      p.k2_n_m = 787200.0;
      p.k3_n_m = 617120.0;
      p.r1_n_s_m = 260.0;
      p.r2_n_s_m = 280.0;
      p.r3_n_s_m = 850.0;
      p.m1_kg = m1;
      p.m2_kg = m2;
      break;
  }
  return p;
}

// ---- Presets ------------------------------------------------------------------

SynthOptions lab_session_options(std::uint64_t seed) {
  SynthOptions o;
  o.seed = seed;
  o.world = "lab";
  // Impactor and markers.
  o.base_marker_layout = BaseMarkerLayout::DiagonalCorners;
  o.base_marker_height_m = 0.0;
  o.impact_point_sd_m = 0.015;
  o.tilt_random_axis = true;
  o.catch_at_apex = true;
  o.mat_marker_motion = MatMarkerMotion::Dish;
  // Video: one second around the trigger, digitised -0.1 .. +0.15 s about
  // contact with a few 1-5-frame gaps.
  o.n_frames = 1000;
  o.trigger_frame = 500;
  o.digitised_from_s = -0.10;
  o.digitised_to_s = 0.15;
  o.random_gaps_per_trial = 4;
  o.gap_max_frames = 5;
  o.gap_both_cameras_fraction = 0.3;
  o.pixel_noise_px = 0.3;
  o.calibration_pixel_noise_px = 0.2;
  // Force: 5 s records, 10 % before the trigger, 1.5 N per channel.
  o.n_samples = 5000;
  o.pretrigger_fraction = 0.10;
  o.channel_noise_n = 1.5;
  o.effects.baseline_drift_whole_record = true;
  o.effects.maxwell_tau_s = 0.025;
  return o;
}

SynthOptions foam_world_options(std::uint64_t seed) {
  SynthOptions o = lab_session_options(seed);
  o.world = "foam";
  Rng r(seed, 9101);
  auto log_uniform = [&](double lo, double hi) { return lo * std::pow(hi / lo, r.uniform()); };
  auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * r.uniform(); };
  o.impact_velocities_m_s.clear();
  for (int i = 0; i < 5; ++i) o.impact_velocities_m_s.push_back(std::round(uniform(4.0, 6.5) * 100.0) / 100.0);
  const double v_max = *std::max_element(o.impact_velocities_m_s.begin(), o.impact_velocities_m_s.end());
  for (int attempt = 0; attempt < 500; ++attempt) {
    FoamColumn f;
    f.top.thickness_m = std::round(uniform(0.095, 0.13) * 1000.0) / 1000.0;
    f.top.mass_kg = std::round(uniform(2.0, 2.9) * 100.0) / 100.0;
    f.top.plateau_pa = log_uniform(1.5e3, 5e3);
    f.top.modulus_pa = f.top.plateau_pa * uniform(12.0, 30.0);
    f.top.hardening_pa = log_uniform(2.5e4, 8e4);
    f.top.densification_pa = log_uniform(150.0, 1500.0);
    f.top.densification_strain = uniform(0.78, 0.9);
    f.top.densification_exponent = uniform(1.6, 3.0);
    f.base.thickness_m = std::round(uniform(0.06, 0.09) * 1000.0) / 1000.0;
    f.base.mass_kg = std::round(uniform(3.0, 4.2) * 100.0) / 100.0;
    f.base.plateau_pa = log_uniform(3e4, 9e4);
    f.base.modulus_pa = f.base.plateau_pa * uniform(12.0, 25.0);
    f.base.hardening_pa = log_uniform(7e4, 2.5e5);
    f.base.densification_pa = log_uniform(2e3, 1.5e4);
    f.base.densification_strain = uniform(0.72, 0.86);
    f.base.densification_exponent = uniform(1.6, 3.0);
    f.g1 = uniform(0.2, 0.8);
    f.tau1_s = log_uniform(1e-3, 4e-3);
    f.g2 = uniform(0.1, 0.5);
    f.tau2_s = log_uniform(0.02, 0.08);
    f.viscosity_pa_s = log_uniform(100.0, 500.0);
    ChainImpact im;
    im.mass_kg = o.impactor_mass_kg;
    im.velocity_m_s = v_max;
    im.gravity_m_s2 = o.gravity_m_s2;
    im.duration_s = 0.15;
    im.output_dt_s = 1e-4;
    const ChainSimulation sim = simulate_foam_column(f, im);
    const double thickness = f.top.thickness_m + f.base.thickness_m;
    if (!(sim.impactor_m.maxCoeff() < 0.88 * thickness) || !std::isfinite(sim.separation_s)) continue;
    // A landing mat like the paper's: the fastest trial's peak within 25 %
    // and its travel within 20 mm of Table 1 at that speed (interpolated).
    const double tv[5] = {4.30, 4.80, 5.25, 5.75, 6.50}, tf[5] = {5593, 6341, 7054, 8398, 9597},
                 td[5] = {0.088, 0.099, 0.100, 0.113, 0.118};
    auto table = [&](const double* y) {
      const double v = std::clamp(v_max, tv[0], tv[4]);
      int i = 0;
      while (i < 3 && v > tv[i + 1]) ++i;
      return y[i] + (y[i + 1] - y[i]) * (v - tv[i]) / (tv[i + 1] - tv[i]);
    };
    if (std::abs(sim.grf_n.maxCoeff() / table(tf) - 1.0) > 0.25 ||
        std::abs(sim.impactor_m.maxCoeff() - table(td)) > 0.02)
      continue;
    o.foam = f;
    o.layers = {{"top_foam", f.top.thickness_m, f.top.mass_kg}, {"base_foam", f.base.thickness_m, f.base.mass_kg}};
    return o;
  }
  throw Error(fmt::format("foam_world_options: no plausible foam drawn for seed {}", seed));
}

SynthOptions independent_world_options(std::uint64_t seed) {
  SynthOptions o = lab_session_options(seed);
  o.world = "independent";
  Rng r(seed, 9001);
  auto log_uniform = [&](double lo, double hi) { return lo * std::pow(hi / lo, r.uniform()); };
  o.impact_velocities_m_s.clear();
  for (int i = 0; i < 5; ++i) o.impact_velocities_m_s.push_back(std::round((4.0 + 2.2 * r.uniform()) * 100.0) / 100.0);
  const double v_max = *std::max_element(o.impact_velocities_m_s.begin(), o.impact_velocities_m_s.end());
  double thickness = 0.0;
  for (const LayerSpec& l : o.layers) thickness += l.thickness_m;
  const MatParams base = default_mat_params(ModelKind::Model4, o.layers);
  for (int attempt = 0; attempt < 500; ++attempt) {
    MatParams p = base;
    p.k1_n_m = log_uniform(2e4, 1e5);
    p.k2_n_m = log_uniform(5e5, 2e6);
    p.k3_n_m = log_uniform(5e5, 2e6);
    p.r1_n_s_m = log_uniform(30.0, 300.0);
    p.r2_n_s_m = log_uniform(80.0, 800.0);
    p.r3_n_s_m = log_uniform(80.0, 800.0);
    p.k1_cubic_n_m3 = r.uniform() < 0.5 ? 0.0 : 2e6 + 6e6 * r.uniform();
    // Plausible: the fastest trial stays within 75 % of the mat's thickness
    // and the impactor leaves the mat.
    ChainImpact im;
    im.mass_kg = o.impactor_mass_kg;
    im.velocity_m_s = v_max;
    im.gravity_m_s2 = o.gravity_m_s2;
    im.duration_s = 0.3;
    im.output_dt_s = 1e-4;
    im.catch_at_apex = true;
    const ChainSimulation sim = simulate_chain(ModelKind::Model4, p, im);
    if (!(sim.impactor_m.maxCoeff() < 0.75 * thickness) || !std::isfinite(sim.separation_s)) continue;
    o.use_default_params = false;
    o.effects.k1_cubic_n_m3 = p.k1_cubic_n_m3;  // named in the truth as stiffness_nonlinearity
    p.k1_cubic_n_m3 = 0.0;
    o.params = p;
    return o;
  }
  throw Error(fmt::format("independent_world_options: no plausible mat drawn for seed {}", seed));
}

void add_random_effects(SynthOptions& o, std::uint64_t seed) {
  Rng r(seed, 9002);
  const double u = r.uniform();
  const int count = u < 0.25 ? 0 : (u < 0.6 ? 1 : 2 + static_cast<int>(r.uniform() * 3.0));  // 0, 1 or 2-4
  std::vector<int> pool{0, 1, 2, 3, 4, 5, 6, 7};
  Effects& e = o.effects;
  const double record_s = static_cast<double>(o.n_samples) / o.force_rate_hz;
  for (int k = 0; k < count && !pool.empty(); ++k) {
    const std::size_t i = std::min(pool.size() - 1, static_cast<std::size_t>(r.uniform() * pool.size()));
    const int which = pool[i];
    pool.erase(pool.begin() + static_cast<std::ptrdiff_t>(i));
    const double sign = r.uniform() < 0.5 ? -1.0 : 1.0;
    switch (which) {
      case 0:
        e.lens_distortion_px = 0.7 + 0.8 * r.uniform();
        break;
      case 1:
        e.outlier_swap = true;
        break;
      case 2:
        e.time_offset_ms = sign * (1.0 + 3.0 * r.uniform());
        break;
      case 3:
        e.baseline_drift_n_s = sign * (10.0 + 30.0 * r.uniform()) / record_s;  // 10-40 N over the record
        e.baseline_drift_whole_record = true;
        break;
      case 4:
        e.force_scale = 1.0 + sign * (0.03 + 0.04 * r.uniform());
        break;
      case 5:
        e.hysteresis_h = 0.15 + 0.15 * r.uniform();
        break;
      case 6:
        e.maxwell_k_n_m = 25000.0 + 5000.0 * r.uniform();
        e.maxwell_tau_s = 0.020 + 0.010 * r.uniform();
        break;
      case 7:
        e.layer_mass_shift_kg = sign * (0.5 + 0.7 * r.uniform());
        break;
    }
  }
}

Eigen::Matrix<double, 8, 1> kistler_channels(const Eigen::Vector3d& f_n, const Eigen::Vector2d& cop_m, double a_m,
                                             double b_m, double az0_m) {
  // From ax = (Fx az0 - My) / Fz and ay = (Fy az0 + Mx) / Fz:
  const double my = f_n.x() * az0_m - cop_m.x() * f_n.z();
  const double mx = cop_m.y() * f_n.z() - f_n.y() * az0_m;
  // Fz = s1+s2+s3+s4, Mx/b = s1+s2-s3-s4, My/a = -s1+s2+s3-s4, and no twist
  // 0 = s1-s2+s3-s4: orthogonal rows of norm^2 4, so s = H^T rhs / 4.
  const double fz = f_n.z(), mxb = mx / b_m, mya = my / a_m;
  Eigen::Matrix<double, 8, 1> ch;
  ch << 0.5 * f_n.x(), 0.5 * f_n.x(), 0.5 * f_n.y(), 0.5 * f_n.y(),  //
      0.25 * (fz + mxb - mya), 0.25 * (fz + mxb + mya), 0.25 * (fz - mxb + mya), 0.25 * (fz - mxb - mya);
  return ch;
}

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
  return distort_px(pinhole_px(camera, lab_m), camera.camera.principal_point_px, camera.camera.focal_px,
                    camera.camera.distortion);
}

// ---- The session --------------------------------------------------------------

namespace {

constexpr double kTriggerSearch_s = 0.15;  // longest contact-to-trigger delay allowed

// The true mat parameters with the mat effects applied; notes each effect in the truth.
MatParams apply_mat_effects(const SynthOptions& o, SynthTruth& truth) {
  const Effects& fx = o.effects;
  MatParams params = o.use_default_params ? default_mat_params(o.model, o.layers) : o.params;
  if (fx.k1_cubic_n_m3 != 0.0) {
    params.k1_cubic_n_m3 = fx.k1_cubic_n_m3;
    truth.effects.push_back({"mat", "stiffness_nonlinearity", fx.k1_cubic_n_m3, "N/m^3",
                             fmt::format("element 1 force gains k1_cubic d^3, k1_cubic = {:.6g} N/m^3", fx.k1_cubic_n_m3)});
  }
  if (fx.r1_unload_n_s_m >= 0.0) {
    params.r1_unload_n_s_m = fx.r1_unload_n_s_m;
    truth.effects.push_back({"mat", "hysteresis", fx.r1_unload_n_s_m, "N s/m",
                             fmt::format("element 1 damping while extending is {:.6g} N s/m instead of r1 = {:.6g} N s/m",
                                         fx.r1_unload_n_s_m, params.r1_n_s_m)});
  }
  if (fx.hysteresis_h != 0.0) {
    require(fx.hysteresis_h > 0.0 && fx.hysteresis_h < 1.0, "hysteresis_elastic h must lie in (0, 1)");
    params.k1_hysteresis = fx.hysteresis_h;
    params.hysteresis_transition_m_s = fx.hysteresis_transition_m_s;
    truth.effects.push_back(
        {"mat", "hysteresis", fx.hysteresis_h, "h",
         fmt::format("element 1's elastic force times (1 - h (1 - tanh(d'/{:.3g}))/2), h = {:.6g}: {:.3g} times lower "
                     "while unloading (not extra damping)",
                     fx.hysteresis_transition_m_s, fx.hysteresis_h, 1.0 - fx.hysteresis_h)});
  }
  if (fx.maxwell_k_n_m > 0.0) {
    require(fx.maxwell_tau_s > 0.0, "rate_dependence needs a positive Maxwell time constant");
    params.maxwell_k_n_m = fx.maxwell_k_n_m;
    params.maxwell_tau_s = fx.maxwell_tau_s;
    truth.effects.push_back({"mat", "rate_dependence", fx.maxwell_k_n_m, "N/m",
                             fmt::format("Maxwell arm k = {:.6g} N/m, tau = {:.6g} s in parallel with element 1",
                                         fx.maxwell_k_n_m, fx.maxwell_tau_s)});
  }
  if (fx.layer_mass_shift_kg != 0.0) {
    require(o.model == ModelKind::Model3 || o.model == ModelKind::Model4,
            "layer_mass needs a layered model (3 or 4)");
    params.m1_kg += fx.layer_mass_shift_kg;
    params.m2_kg -= fx.layer_mass_shift_kg;
    require(params.m1_kg > 0.0 && params.m2_kg > 0.0,
            fmt::format("layer_mass {} kg leaves a layer without mass", fx.layer_mass_shift_kg));
    truth.effects.push_back({"mat", "layer_mass", fx.layer_mass_shift_kg, "kg",
                             fmt::format("true m1 = {:.6g} kg, m2 = {:.6g} kg (declared layers unchanged, total kept)",
                                         params.m1_kg, params.m2_kg)});
  }
  return params;
}

// Base markers in the impactor's frame (face centre origin, X front, Z up) and mat markers' lab x, y.
struct MarkerLayout {
  Eigen::Vector3d base_offset[2];
  Eigen::Vector2d mat_xy[4];
};

// Places the base and mat markers and records them in the truth.
MarkerLayout place_markers(const SynthOptions& o, SynthTruth& truth) {
  const double h_base = o.base_marker_height_m;
  MarkerLayout layout;
  Eigen::Vector3d(&base_offset)[2] = layout.base_offset;
  if (o.base_marker_layout == BaseMarkerLayout::DiagonalCorners) {
    const double ax = 0.5 * o.footprint_m.x(), ay = 0.5 * o.footprint_m.y();
    base_offset[0] = {ax, ay, h_base};
    base_offset[1] = {-ax, -ay, h_base};
  } else {
    base_offset[0] = {o.base_marker_spacing_m, 0.0, h_base};
    base_offset[1] = {-o.base_marker_spacing_m, 0.0, h_base};
  }
  Eigen::Vector2d(&mat_xy)[4] = layout.mat_xy;
  if (o.mat_marker_motion == MatMarkerMotion::Dish) {
    Rng lay(o.seed, kStreamLayout);
    const Eigen::Vector2d dirs[4] = {{0.0, 1.0}, {0.0, -1.0}, {1.0, 0.0}, {-1.0, 0.0}};
    for (int i = 0; i < 4; ++i) {
      // Within the range and at least 2 cm inside the mat's edge.
      const double edge = 0.5 * (i < 2 ? o.mat_width_m : o.mat_length_m) - 0.02;
      const double hi = std::max(o.mat_marker_min_radius_m, std::min(o.mat_marker_max_radius_m, edge));
      const double r = o.mat_marker_min_radius_m + (hi - o.mat_marker_min_radius_m) * lay.uniform();
      mat_xy[i] = r * dirs[i];
    }
  } else {
    const double ry = 0.5 * o.footprint_m.y() + o.surface_marker_clearance_m;
    const double rx = 0.5 * o.footprint_m.x() + o.surface_marker_clearance_m;
    mat_xy[0] = {0.0, ry}, mat_xy[1] = {0.0, -ry}, mat_xy[2] = {rx, 0.0}, mat_xy[3] = {-rx, 0.0};
  }
  truth.base_markers_impactor_m = {base_offset[0], base_offset[1]};
  truth.mat_markers_xy_m.assign(std::begin(mat_xy), std::end(mat_xy));
  return layout;
}

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

// The session manifest: impactor, mat, video and force plate.
void fill_manifest(const SynthOptions& o, double mat_top_m, const SynthTruth& truth, Session& session) {
  const double g = o.gravity_m_s2;
  Manifest& m = session.manifest;
  m.name = fmt::format("synthetic session (dropfit-synth, seed {})", o.seed);
  m.gravity_m_s2 = g;
  m.impactor.mass_kg = o.faults.declared_mass_kg > 0.0 ? o.faults.declared_mass_kg : o.impactor_mass_kg;
  m.impactor.footprint_m = o.footprint_m;
  m.impactor.base_markers = {"imp_base_front", "imp_base_back"};
  m.impactor.base_marker_height_m = o.base_marker_height_m;
  m.mat.length_m = o.mat_length_m;
  m.mat.width_m = o.mat_width_m;
  m.mat.surface_markers = {"mat_n", "mat_s", "mat_e", "mat_w"};
  m.mat.layers = o.layers;
  for (const TrueCamera& c : truth.cameras) m.video.cameras.push_back(c.camera.name);
  m.video.frame_rate_hz = o.frame_rate_hz;
  m.video.points = {"imp_base_front", "imp_base_back", "mat_n", "mat_s", "mat_e", "mat_w"};
  m.video.trigger_frame = o.trigger_frame;
  m.video.image_origin = ImageOrigin::TopLeft;
  m.forceplate.model = "Kistler 9281B";
  m.forceplate.sample_rate_hz = o.force_rate_hz;
  m.forceplate.trigger_threshold_n = o.trigger_threshold_n;
  m.forceplate.pretrigger_fraction = o.pretrigger_fraction;
  m.forceplate.a_m = o.plate_a_m;
  m.forceplate.b_m = o.plate_b_m;
  m.forceplate.az0_m = o.plate_az0_m;
  m.forceplate.mat_top_z_m = mat_top_m;
}

// Notes the sync and force-plate effects (time_offset, baseline_drift, force_scale) in the truth.
void note_sync_and_plate_effects(const SynthOptions& o, SynthTruth& truth) {
  const Effects& fx = o.effects;
  const double offset_s = fx.time_offset_ms * 1e-3;
  if (fx.time_offset_ms != 0.0)
    truth.effects.push_back({"sync", "time_offset", fx.time_offset_ms, "ms",
                             fmt::format("video clock minus force clock is {:.6g} s, not 0 as trigger_frame says",
                                         offset_s)});
  if (fx.baseline_drift_n_s != 0.0)
    truth.effects.push_back({"forceplate", "baseline_drift", fx.baseline_drift_n_s, "N/s",
                             fmt::format("Fz offset ramps at {} N/s {} (split equally over Fz1-Fz4)",
                                         fx.baseline_drift_n_s,
                                         fx.baseline_drift_whole_record ? "from the first sample"
                                                                        : "from the trigger sample on")});
  if (fx.force_scale != 1.0)
    truth.effects.push_back({"forceplate", "force_scale", fx.force_scale, "gain",
                             fmt::format("every channel reads {} times the true load", fx.force_scale)});
}

// Notes the instrument faults in the truth (stage "instrument").
void note_faults(const SynthOptions& o, SynthTruth& truth) {
  const InstrumentFaults& f = o.faults;
  static const char* const channel[8] = {"Fx12", "Fx34", "Fy14", "Fy23", "Fz1", "Fz2", "Fz3", "Fz4"};
  const std::string which = f.trials.empty() ? std::string("every trial")
                                             : fmt::format("trials (0-based) {}", fmt::join(f.trials, " "));
  if (f.dead_channel >= 0)
    truth.effects.push_back({"instrument", "dead_channel", static_cast<double>(f.dead_channel), "channel",
                             fmt::format("{} reads only its noise and offset in {}", channel[f.dead_channel], which)});
  if (f.reversed_channel >= 0)
    truth.effects.push_back({"instrument", "reversed_channel", static_cast<double>(f.reversed_channel), "channel",
                             fmt::format("{} reads the negative of its load in {}", channel[f.reversed_channel],
                                         which)});
  if (f.exchange_a >= 0 && f.exchange_b >= 0)
    truth.effects.push_back({"instrument", "exchanged_channels", 10.0 * f.exchange_a + f.exchange_b, "channels",
                             fmt::format("columns {} and {} exchanged in {}", channel[f.exchange_a],
                                         channel[f.exchange_b], which)});
  if (f.saturation_n > 0.0)
    truth.effects.push_back({"instrument", "saturation", f.saturation_n, "N",
                             fmt::format("each channel clipped at +-{} N before the ADC noise in {}", f.saturation_n,
                                         which)});
  if (f.amplifier_lowpass_hz > 0.0)
    truth.effects.push_back({"instrument", "amplifier_lowpass", f.amplifier_lowpass_hz, "Hz",
                             fmt::format("the analog force through a Butterworth low-pass of order {} at {} Hz",
                                         f.amplifier_lowpass_order, f.amplifier_lowpass_hz)});
  if (f.softening_per_trial > 0.0)
    truth.effects.push_back({"mat", "softening", f.softening_per_trial, "per trial",
                             "every stiffness of trial k (recording order, 0-based) times (1 - s)^k"});
  if (f.declared_mass_kg > 0.0 && f.declared_mass_kg != o.impactor_mass_kg)
    truth.effects.push_back({"instrument", "declared_mass", f.declared_mass_kg, "kg",
                             fmt::format("the manifest declares {} kg; the impactor has {} kg", f.declared_mass_kg,
                                         o.impactor_mass_kg)});
}

// Whether the channel faults and saturation apply to trial ti.
bool faulty_trial(const InstrumentFaults& f, std::size_t ti) {
  return f.trials.empty() || std::find(f.trials.begin(), f.trials.end(), static_cast<int>(ti)) != f.trials.end();
}

// The analog force the amplifier passes on: x (sampled every dt) through a
// Butterworth low-pass of order 2 or 4 at corner_hz (cascaded second-order
// sections, bilinear transform with the corner prewarped), from rest.
Eigen::VectorXd butterworth(const Eigen::VectorXd& x, double dt, double corner_hz, int order) {
  Eigen::VectorXd y = x;
  const double k = std::tan(kPi * corner_hz * dt);
  for (int section = 0; section < order / 2; ++section) {
    // Pole pair angle: q = 1 / (2 sin((2 section + 1) pi / (2 order))).
    const double q = 1.0 / (2.0 * std::sin((2.0 * section + 1.0) * kPi / (2.0 * order)));
    const double norm = 1.0 / (1.0 + k / q + k * k);
    const double b0 = k * k * norm, b1 = 2.0 * b0, b2 = b0;
    const double a1 = 2.0 * (k * k - 1.0) * norm, a2 = (1.0 - k / q + k * k) * norm;
    const Eigen::VectorXd in = y;
    double x1 = 0.0, x2 = 0.0, y1 = 0.0, y2 = 0.0;
    for (Eigen::Index i = 0; i < in.size(); ++i) {
      const double out = b0 * in[i] + b1 * x1 + b2 * x2 - a1 * y1 - a2 * y2;
      x2 = x1, x1 = in[i], y2 = y1, y1 = out;
      y[i] = out;
    }
  }
  return y;
}

// The mat of trial ti: every stiffness times (1 - softening)^ti.
MatParams trial_params(const SynthOptions& o, const MatParams& params, std::size_t ti) {
  MatParams p = params;
  const double f = std::pow(1.0 - o.faults.softening_per_trial, static_cast<double>(ti));
  p.k1_n_m *= f, p.k2_n_m *= f, p.k3_n_m *= f, p.k1_cubic_n_m3 *= f, p.maxwell_k_n_m *= f;
  return p;
}

// What every trial shares: options, true parameters, markers, cameras and record sizes.
struct TrialSetup {
  const SynthOptions& o;
  const MatParams& params;
  const MarkerLayout& layout;
  const std::vector<TrueCamera>& cameras;
  const Manifest& m;
  double g, mat_top_m, offset_s, fs, t_end_force, t_end_video;
  int n, npre, n_pts, n_cam;
};

// The impactor's tilt, impact point, shear share and channel offsets; returns the face slopes.
Eigen::Vector2d draw_trial_pose(const SynthOptions& o, std::size_t ti, TrialTruth& tt) {
  Rng r(o.seed, kStreamTrial + ti);
  const double tilt_abs_deg = std::abs(o.tilt_mean_deg + o.tilt_sd_deg * r.normal());
  const double tilt_sign = r.uniform() < 0.5 ? -1.0 : 1.0;
  const double tilt_rad = tilt_sign * tilt_abs_deg * kDeg;
  tt.impact_point_m = Eigen::Vector2d(r.normal(), r.normal()) * o.impact_point_sd_m;
  tt.cop_m = tt.impact_point_m;
  tt.shear_fraction = Eigen::Vector2d(2.0 * r.uniform() - 1.0, 2.0 * r.uniform() - 1.0) * o.shear_fraction_max;
  for (int c = 0; c < 8; ++c) tt.channel_offsets_n(c) = o.channel_offset_sd_n * r.normal();
  // Face slopes (d travel / dx, d travel / dy): about lab Y, or about a
  // random horizontal axis (its own stream: the classic draws stay).
  Eigen::Vector2d face_slopes(std::tan(tilt_rad), 0.0);
  tt.tilt_axis_deg = 90.0;
  if (o.tilt_random_axis) {
    Rng ax(o.seed, kStreamTrial + 500 + ti);
    const double phi = 2.0 * kPi * ax.uniform();  // direction of steepest descent of the face
    face_slopes = std::tan(tilt_abs_deg * kDeg) * Eigen::Vector2d(std::cos(phi), std::sin(phi));
    tt.tilt_axis_deg = std::remainder(phi / kDeg + 90.0, 360.0);
  }
  tt.tilt_about_y_deg = std::atan(face_slopes.x()) / kDeg;
  return face_slopes;
}

// The chain simulation from first contact (the generator's own physics.h) and the rebound speed.
ChainSimulation simulate_trial_impact(const TrialSetup& setup, const MatParams& params, double v, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const double g = setup.g, fs = setup.fs, t_end_force = setup.t_end_force, t_end_video = setup.t_end_video;
  // -- Physics from first contact: the generator's own (physics.h).
  ChainImpact impact;
  impact.mass_kg = o.impactor_mass_kg;
  impact.velocity_m_s = v;
  impact.gravity_m_s2 = g;
  impact.duration_s = std::max(t_end_force, t_end_video) + kTriggerSearch_s + 2.0 / fs;
  impact.output_dt_s = kSimDt;
  impact.catch_at_apex = o.catch_at_apex;
  const ChainSimulation sim =
      o.foam ? simulate_foam_column(*o.foam, impact) : simulate_chain(o.model, params, impact);
  require(sim.grf_n.size() >= 2, "simulation returned no samples");
  tt.impact_velocity_after_m_s = kNaN;
  if (std::isfinite(sim.separation_s))
    tt.impact_velocity_after_m_s = -interp(sim.impactor_v_m_s, sim.separation_s, kSimDt);
  return sim;
}

// Travels (m, down) of the face, the mat surface and the layers at time tau from contact.
struct TrialMotion {
  const ChainSimulation& sim;
  double v, g;
  bool has_layer;

  // The face: the simulation after contact, free fall from the release before.
  double face_travel(double tau) const {
    const double d0 = 0.0;
    if (tau >= 0.0) return interp(sim.impactor_m, tau, kSimDt);
    const double tau_release = -v / g;  // held at rest before the release
    const double t = std::max(tau, tau_release);
    return d0 + v * t + 0.5 * g * t * t;
  }
  // The mat surface (element 1's top).
  double surface_travel(double tau) const { return tau >= 0.0 ? interp(sim.surface_m, tau, kSimDt) : 0.0; }
  // A layer's travel record y.
  double layer_travel(const Eigen::VectorXd& y, double tau) const { return tau >= 0.0 ? interp(y, tau, kSimDt) : 0.0; }
  // What the mat markers follow: the top layer (or, with no layer mass, element 1's top).
  double top_layer_travel(double tau) const {
    return has_layer ? layer_travel(sim.layer1_m, tau) : surface_travel(tau);
  }
};

// Contact summary (first contact up to separation): peak force, deformation, travel and tilt.
void summarise_contact(const ChainSimulation& sim, const Eigen::Vector2d& face_slopes, TrialTruth& tt) {
  const Eigen::Index n_sim = sim.grf_n.size();
  Eigen::Index end = n_sim;
  if (std::isfinite(sim.separation_s))
    end = std::min<Eigen::Index>(n_sim, static_cast<Eigen::Index>(std::ceil(sim.separation_s / kSimDt)) + 1);
  Eigen::Index k_peak = 0;
  tt.peak_force_n = sim.grf_n.head(end).maxCoeff(&k_peak);
  tt.time_to_peak_s = static_cast<double>(k_peak) * kSimDt;
  tt.max_deformation_m = sim.impactor_m.head(end).maxCoeff();
  tt.max_surface_travel_m = sim.surface_m.head(end).maxCoeff();
  double dev = 0.0;
  for (Eigen::Index k = 0; k < end; ++k) {
    const Eigen::Vector2d sl = face_slopes;
    dev = std::max(dev, deviation_deg(sl.x(), sl.y()));
  }
  tt.tilt_deg = dev;
}

// The time from contact to the noise-free trigger crossing (s); throws when the force never reaches it.
double contact_to_trigger_s(const SynthOptions& o, const Eigen::VectorXd& plate_grf_n, double fs,
                            const std::string& id) {
  const Effects& fx = o.effects;
  // -- Trigger: the plate's zeroed Fz (gain, drift and noise included)
  // first reaches the threshold at sample npre (t = 0); contact sits a
  // random sub-sample phase before the noise-free crossing.
  const double scale = fx.force_scale;
  double tau25 = -1.0;
  for (Eigen::Index k = 0; k < plate_grf_n.size(); ++k)
    if (scale * plate_grf_n(k) >= o.trigger_threshold_n) {
      if (k == 0) {
        tau25 = 0.0;
      } else {
        const double a = scale * plate_grf_n(k - 1), b = scale * plate_grf_n(k);
        tau25 = (static_cast<double>(k - 1) + (o.trigger_threshold_n - a) / (b - a)) * kSimDt;
      }
      break;
    }
  require(tau25 >= 0.0 && tau25 + 1.0 / fs < kTriggerSearch_s,
          fmt::format("trial {}: the force never reaches the {} N trigger within {} s of contact", id,
                      o.trigger_threshold_n, kTriggerSearch_s));
  return tau25;
}

// The force record: sample times, true GRF and the eight channels with the plate effects.
struct ForceRecord {
  Eigen::VectorXd t_s, grf;
  Eigen::MatrixXd data;
};

// Records the plate's channels, placing contact so the trigger fires at sample npre.
ForceRecord record_force(const TrialSetup& setup, std::size_t ti, const ChainSimulation& sim,
                         const Eigen::VectorXd& plate_grf_n, double tau25, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const Effects& fx = o.effects;
  const InstrumentFaults& faults = o.faults;
  const bool faulty = faulty_trial(faults, ti);
  const int n = setup.n, npre = setup.npre;
  const double fs = setup.fs;
  const double scale = fx.force_scale;
  ForceRecord rec;
  Eigen::VectorXd& t_s = rec.t_s;
  Eigen::VectorXd& grf = rec.grf;
  Eigen::MatrixXd& data = rec.data;
  Rng fr(o.seed, kStreamForceNoise + ti);
  t_s.resize(n);
  grf.resize(n);
  data.resize(n, 8);
  bool triggered = false;
  for (int attempt = 0; attempt < 200 && !triggered; ++attempt) {
    const double phase = fr.uniform();
    tt.contact_time_s = -(tau25 + phase / fs);
    for (int j = 0; j < n; ++j) {
      const double t = six_decimals(static_cast<double>(j - npre) / fs);
      t_s(j) = t;
      const double tau = t - tt.contact_time_s;
      grf(j) = tau < 0.0 ? 0.0 : interp(sim.grf_n, tau, kSimDt);
      const double fz = scale * (tau < 0.0 ? 0.0 : interp(plate_grf_n, tau, kSimDt));
      const Eigen::Vector3d f(tt.shear_fraction.x() * fz, tt.shear_fraction.y() * fz, fz);
      Eigen::Matrix<double, 8, 1> ch = kistler_channels(f, tt.cop_m, o.plate_a_m, o.plate_b_m, o.plate_az0_m);
      double drift = 0.0;
      if (fx.baseline_drift_whole_record)
        drift = fx.baseline_drift_n_s * (t - t_s(0));
      else if (t > 0.0)
        drift = fx.baseline_drift_n_s * t;
      ch.tail<4>().array() += 0.25 * drift;
      if (faulty && faults.saturation_n > 0.0) ch = ch.cwiseMax(-faults.saturation_n).cwiseMin(faults.saturation_n);
      if (faulty && faults.dead_channel >= 0) ch(faults.dead_channel) = 0.0;
      if (faulty && faults.reversed_channel >= 0) ch(faults.reversed_channel) = -ch(faults.reversed_channel);
      for (int c = 0; c < 8; ++c) ch(c) += o.channel_noise_n * fr.normal();
      data.row(j) = ch.transpose();
    }
    // The zeroed Fz as the plate's trigger sees it.
    int first = -1;
    for (int j = 0; j < n && first < 0; ++j)
      if (data.row(j).tail<4>().sum() >= o.trigger_threshold_n) first = j;
    triggered = first == npre;
  }
  if (faulty && faults.exchange_a >= 0 && faults.exchange_b >= 0) data.col(faults.exchange_a).swap(data.col(faults.exchange_b));
  require(triggered, fmt::format("trial {}: cannot place the trigger at sample {} with {} N channel noise", tt.id,
                                 npre, o.channel_noise_n));
  for (int j = 0; j < n; ++j)
    for (int c = 0; c < 8; ++c) data(j, c) = six_decimals(data(j, c) + tt.channel_offsets_n(c));
  tt.separation_time_s = std::isfinite(sim.separation_s) ? tt.contact_time_s + sim.separation_s : kNaN;
  return rec;
}

// The truth's travels and noise-free plate Fz at the force samples.
void fill_force_truth(const TrialSetup& setup, const ChainSimulation& sim, const TrialMotion& motion,
                      const ForceRecord& rec, TrialTruth& tt) {
  const Effects& fx = setup.o.effects;
  const int n = setup.n;
  const double scale = fx.force_scale;
  const Eigen::VectorXd& t_s = rec.t_s;
  const Eigen::VectorXd& grf = rec.grf;
  tt.t_s = t_s;
  tt.grf_n = grf;
  tt.impactor_travel_m.resize(n);
  tt.surface_travel_m.resize(n);
  tt.layer1_travel_m.resize(n);
  tt.layer2_travel_m.resize(n);
  tt.plate_fz_noise_free_n.resize(n);
  for (int j = 0; j < n; ++j) {
    const double tau = t_s(j) - tt.contact_time_s;
    tt.impactor_travel_m(j) = motion.face_travel(tau);
    tt.surface_travel_m(j) = motion.surface_travel(tau);
    tt.layer1_travel_m(j) = motion.layer_travel(sim.layer1_m, tau);
    tt.layer2_travel_m(j) = motion.layer_travel(sim.layer2_m, tau);
    double drift = 0.0;
    if (fx.baseline_drift_whole_record)
      drift = fx.baseline_drift_n_s * (t_s(j) - t_s(0));
    else if (t_s(j) > 0.0)
      drift = fx.baseline_drift_n_s * t_s(j);
    tt.plate_fz_noise_free_n(j) = scale * grf(j) + drift;
  }
}

// Renders the markers into both cameras over the digitised window (pixel noise, visibility).
MarkerTracks2D render_markers(const TrialSetup& setup, std::size_t ti, const TrialMotion& motion,
                              const Eigen::Vector2d& face_slopes, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const Manifest& m = setup.m;
  const int n_pts = setup.n_pts, n_cam = setup.n_cam;
  const double offset_s = setup.offset_s, mat_top_m = setup.mat_top_m;
  const Eigen::Vector3d(&base_offset)[2] = setup.layout.base_offset;
  const Eigen::Vector2d(&mat_xy)[4] = setup.layout.mat_xy;
  // -- Video.
  Rng pr(o.seed, kStreamPixelNoise + ti);
  MarkerTracks2D tracks;
  tracks.points = m.video.points;
  tracks.cameras = m.video.cameras;
  tracks.uv_px.setConstant(o.n_frames, 2 * n_pts * n_cam, kNaN);
  tt.frame_force_time_s.resize(o.n_frames);
  tt.markers_lab_m.resize(o.n_frames, 3 * n_pts);
  tt.digitised_first_frame = -1;
  tt.digitised_last_frame = -1;
  for (int f = 0; f < o.n_frames; ++f) {
    const double tf = static_cast<double>(f - o.trigger_frame) / o.frame_rate_hz - offset_s;
    tt.frame_force_time_s(f) = tf;
    const double tau = tf - tt.contact_time_s;
    const bool digitised = tau >= o.digitised_from_s && tau <= o.digitised_to_s;
    if (digitised) {
      if (tt.digitised_first_frame < 0) tt.digitised_first_frame = f;
      tt.digitised_last_frame = f;
    }
    const double d = motion.face_travel(tau);
    const double st = motion.surface_travel(tau);
    const Eigen::Vector2d sl = face_slopes;
    const Eigen::Matrix3d rot = impactor_rotation(sl.x(), sl.y());
    const Eigen::Vector3d face(tt.impact_point_m.x(), tt.impact_point_m.y(), mat_top_m - d);
    std::vector<Eigen::Vector3d> pts;
    pts.push_back(face + rot * base_offset[0]);
    pts.push_back(face + rot * base_offset[1]);
    const double top = motion.top_layer_travel(tau);
    for (int k = 0; k < 4; ++k) {
      const double travel = o.mat_marker_motion == MatMarkerMotion::Dish ? tt.dish_factors[k] * top : st;
      pts.emplace_back(mat_xy[k].x(), mat_xy[k].y(), mat_top_m - travel);
    }
    for (int p = 0; p < n_pts; ++p) {
      tt.markers_lab_m.row(f).segment<3>(3 * p) = pts[p].transpose();
      for (int c = 0; c < n_cam; ++c) {
        const Eigen::Vector2d e(pr.normal(), pr.normal());  // drawn always: visibility changes nothing else
        double depth = 0.0;
        pinhole_px(setup.cameras[c], pts[p], &depth);
        const Eigen::Vector2d clean = project_px(setup.cameras[c], pts[p]);
        if (!digitised || !in_image(setup.cameras[c], clean, depth)) continue;
        const Eigen::Vector2d uv = clean + o.pixel_noise_px * e;
        const int col = tracks.column(p, c);
        tracks.uv_px(f, col) = six_decimals(uv.x());
        tracks.uv_px(f, col + 1) = six_decimals(uv.y());
      }
    }
  }
  require(tt.digitised_first_frame >= 0,
          fmt::format("trial {}: no video frame lies in the digitised window", tt.id));
  return tracks;
}

// Hides the requested and the random gaps (inside the digitised window) in the tracks.
void apply_gaps(const TrialSetup& setup, std::size_t ti, MarkerTracks2D& tracks, TrialTruth& tt) {
  const SynthOptions& o = setup.o;
  const Manifest& m = setup.m;
  const int n_pts = setup.n_pts, n_cam = setup.n_cam;
  // Random gaps inside the digitised window (their own stream).
  std::vector<Gap> trial_gaps = o.gaps;
  {
    Rng gr(o.seed, kStreamGaps + ti);
    const int span = tt.digitised_last_frame - tt.digitised_first_frame + 1;
    for (int k = 0; k < o.random_gaps_per_trial && span > 2; ++k) {
      Gap gap;
      gap.trial = static_cast<int>(ti);
      gap.point = m.video.points[std::min<std::size_t>(m.video.points.size() - 1,
                                                       static_cast<std::size_t>(gr.uniform() * n_pts))];
      gap.n_frames = 1 + std::min(o.gap_max_frames - 1, static_cast<int>(gr.uniform() * o.gap_max_frames));
      gap.first_frame =
          tt.digitised_first_frame + std::min(span - 1, static_cast<int>(gr.uniform() * std::max(1, span - gap.n_frames)));
      gap.camera = gr.uniform() < o.gap_both_cameras_fraction
                       ? -1
                       : std::min(n_cam - 1, static_cast<int>(gr.uniform() * n_cam));
      trial_gaps.push_back(gap);
    }
  }
  for (const Gap& gap : trial_gaps) {
    if (gap.trial != static_cast<int>(ti)) continue;
    const auto it = std::find(tracks.points.begin(), tracks.points.end(), gap.point);
    require(it != tracks.points.end(), fmt::format("gap names unknown point '{}'", gap.point));
    require(gap.camera >= -1 && gap.camera < n_cam, fmt::format("gap names camera {} of {}", gap.camera, n_cam));
    const int p = static_cast<int>(it - tracks.points.begin());
    for (int f = gap.first_frame; f < std::min(o.n_frames, gap.first_frame + gap.n_frames); ++f)
      for (int c = 0; c < n_cam; ++c)
        if (gap.camera < 0 || gap.camera == c) {
          tracks.uv_px(f, tracks.column(p, c)) = kNaN;
          tracks.uv_px(f, tracks.column(p, c) + 1) = kNaN;
        }
    tt.gaps.push_back(gap);
  }
}

// One simulated trial: its recording and its truth.
struct SimulatedTrial {
  TrialRecording trial;
  TrialTruth tt;
};

// Simulates trial ti: pose, physics, force record, video and gaps.
SimulatedTrial simulate_trial(const TrialSetup& setup, std::size_t ti) {
  const SynthOptions& o = setup.o;
  const double g = setup.g, offset_s = setup.offset_s, fs = setup.fs;
  const int npre = setup.npre;
  const Eigen::Vector2d(&mat_xy)[4] = setup.layout.mat_xy;
  SimulatedTrial out;
  TrialTruth& tt = out.tt;
  const double v = o.impact_velocities_m_s[ti];
  tt.id = fmt::format("trial{}", ti + 1);
  tt.impact_velocity_m_s = v;
  tt.model = o.model;
  const MatParams params = trial_params(o, setup.params, ti);
  tt.params = params;
  tt.video_offset_s = offset_s;
  tt.trigger_index = npre;
  tt.drop_height_m = v * v / (2.0 * g);

  const Eigen::Vector2d face_slopes = draw_trial_pose(o, ti, tt);
  const ChainSimulation sim = simulate_trial_impact(setup, params, v, tt);
  const TrialMotion motion{sim, v, g, o.foam || o.model != ModelKind::Model1};
  tt.dish_factors.clear();
  for (const Eigen::Vector2d& xy : mat_xy) {
    const double dist = (xy - tt.impact_point_m).norm();
    tt.dish_factors.push_back(o.mat_marker_motion == MatMarkerMotion::Dish
                                  ? std::exp(-std::pow((dist - o.dish_centre_m) / o.dish_width_m, 2))
                                  : 1.0);
  }
  summarise_contact(sim, face_slopes, tt);
  // What reaches the ADC: the analog force, through the amplifier's low-pass when there is one.
  const Eigen::VectorXd plate_grf_n =
      o.faults.amplifier_lowpass_hz > 0.0
          ? butterworth(sim.grf_n, kSimDt, o.faults.amplifier_lowpass_hz, o.faults.amplifier_lowpass_order)
          : sim.grf_n;
  const double tau25 = contact_to_trigger_s(o, plate_grf_n, fs, tt.id);
  const ForceRecord rec = record_force(setup, ti, sim, plate_grf_n, tau25, tt);
  fill_force_truth(setup, sim, motion, rec, tt);
  MarkerTracks2D tracks = render_markers(setup, ti, motion, face_slopes, tt);
  apply_gaps(setup, ti, tracks, tt);
  const Eigen::VectorXd& t_s = rec.t_s;
  const Eigen::MatrixXd& data = rec.data;

  TrialRecording& trial = out.trial;
  trial.spec = {tt.id, fmt::format("trials/{}", tt.id)};
  trial.tracks = std::move(tracks);
  trial.force.layout = ForceLayout::EightChannel;
  trial.force.sample_rate_hz = fs;
  trial.force.pretrigger_samples = npre;
  trial.force.trigger = fmt::format("Fz > {} N", o.trigger_threshold_n);
  trial.force.t_s = t_s;
  trial.force.data = data;
  return out;
}

}  // namespace

SyntheticSession make_session(const SynthOptions& o) {
  validate(o);
  const Effects& fx = o.effects;
  SyntheticSession out;
  Session& session = out.session;
  SynthTruth& truth = out.truth;

  double mat_top_m = 0.0;
  for (const LayerSpec& l : o.layers) mat_top_m += l.thickness_m;
  const double g = o.gravity_m_s2;

  const MatParams params = apply_mat_effects(o, truth);
  const MarkerLayout layout = place_markers(o, truth);
  make_true_cameras(o, mat_top_m, layout, truth);
  const int n_cam = static_cast<int>(truth.cameras.size());
  make_calibration(o, mat_top_m, truth, session);
  fill_manifest(o, mat_top_m, truth, session);
  Manifest& m = session.manifest;
  note_sync_and_plate_effects(o, truth);
  note_faults(o, truth);
  const double offset_s = fx.time_offset_ms * 1e-3;

  const int n_pts = static_cast<int>(m.video.points.size());

  const int n = o.n_samples;
  const int npre = static_cast<int>(std::lround(o.pretrigger_fraction * n));
  const double fs = o.force_rate_hz;
  const double t_end_force = (n - 1 - npre) / fs;
  const double t_end_video = (o.n_frames - 1 - o.trigger_frame) / o.frame_rate_hz - offset_s;

  truth.seed = o.seed;
  truth.world = o.world;
  truth.model = o.model;
  truth.params = params;
  truth.foam = o.foam;
  truth.points = m.video.points;
  truth.mat_top_z_m = mat_top_m;
  truth.pixel_noise_px = o.pixel_noise_px;
  truth.channel_noise_n = o.channel_noise_n;

  const TrialSetup setup{o, params, layout, truth.cameras, m, g, mat_top_m, offset_s, fs, t_end_force, t_end_video,
                         n, npre, n_pts, n_cam};
  for (std::size_t ti = 0; ti < o.impact_velocities_m_s.size(); ++ti) {
    SimulatedTrial st = simulate_trial(setup, ti);
    m.trials.push_back(st.trial.spec);
    session.trials.push_back(std::move(st.trial));
    truth.trials.push_back(std::move(st.tt));
  }
  return out;
}

// ---- Truth JSON -----------------------------------------------------------------

namespace {

using Json = nlohmann::ordered_json;

double rounded(double v, double unit) { return std::isfinite(v) ? std::round(v / unit) * unit : v; }

Json vec(const Eigen::VectorXd& v, double unit = 0.0) {
  Json a = Json::array();
  for (Eigen::Index i = 0; i < v.size(); ++i) a.push_back(unit > 0.0 ? rounded(v(i), unit) : v(i));
  return a;
}
Json num(double v) { return std::isfinite(v) ? Json(v) : Json(nullptr); }

Json params_json(const MatParams& p) {
  return Json{{"k1_n_m", p.k1_n_m},
              {"k2_n_m", p.k2_n_m},
              {"k3_n_m", p.k3_n_m},
              {"r1_n_s_m", p.r1_n_s_m},
              {"r2_n_s_m", p.r2_n_s_m},
              {"r3_n_s_m", p.r3_n_s_m},
              {"m_eff_kg", p.m_eff_kg},
              {"m1_kg", p.m1_kg},
              {"m2_kg", p.m2_kg},
              {"k1_cubic_n_m3", p.k1_cubic_n_m3},
              {"r1_unload_n_s_m", p.r1_unload_n_s_m},
              {"maxwell_k_n_m", p.maxwell_k_n_m},
              {"maxwell_tau_s", p.maxwell_tau_s},
              {"k1_hysteresis", p.k1_hysteresis},
              {"hysteresis_transition_m_s", p.hysteresis_transition_m_s}};
}

}  // namespace

void write_truth_json(const std::string& path, const SynthTruth& t) {
  Json j;
  j["generator"] = "dropfit-synth";
  j["seed"] = t.seed;
  j["model"] = model_key(t.model);
  j["parameters"] = params_json(t.params);
  if (t.foam) {
    auto layer = [](const FoamLayer& l) {
      return Json{{"thickness_m", l.thickness_m},       {"mass_kg", l.mass_kg},
                  {"plateau_pa", l.plateau_pa},         {"modulus_pa", l.modulus_pa},
                  {"hardening_pa", l.hardening_pa},     {"densification_pa", l.densification_pa},
                  {"densification_strain", l.densification_strain},
                  {"densification_exponent", l.densification_exponent}};
    };
    const FoamColumn& f = *t.foam;
    j["model"] = "foam column";
    j["foam"] = {{"top", layer(f.top)},     {"base", layer(f.base)},         {"g1", f.g1},
                 {"tau1_s", f.tau1_s},      {"g2", f.g2},                    {"tau2_s", f.tau2_s},
                 {"viscosity_pa_s", f.viscosity_pa_s}, {"area_m2", f.area_m2}, {"n_top", f.n_top},
                 {"n_base", f.n_base},
                 {"law", "s_p (1 - exp(-E e / s_p)) + H e + D ((e_d / (e_d - e))^n - 1); "
                         "dq_i/dt = g_i ds_e/dt - q_i / tau_i; + eta de/dt"}};
  }
  j["mat_top_z_m"] = t.mat_top_z_m;
  j["world"] = t.world;
  j["physics"] = "samples/generator/physics.h (own equations, Dormand-Prince 5(4); no fitting/ code)";
  j["pixel_noise_px"] = t.pixel_noise_px;
  j["calibration_pixel_noise_px"] = t.calibration_pixel_noise_px;
  j["channel_noise_n"] = t.channel_noise_n;
  j["points"] = t.points;
  Json layout = Json::object();
  for (std::size_t i = 0; i < t.base_markers_impactor_m.size() && i < t.points.size(); ++i) {
    const Eigen::Vector3d& b = t.base_markers_impactor_m[i];
    layout[t.points[i]] = {{"impactor_frame_m", {b.x(), b.y(), b.z()}}};
  }
  for (std::size_t i = 0; i < t.mat_markers_xy_m.size(); ++i) {
    const std::size_t p = t.base_markers_impactor_m.size() + i;
    if (p < t.points.size()) layout[t.points[p]] = {{"lab_xy_m", {t.mat_markers_xy_m[i].x(), t.mat_markers_xy_m[i].y()}}};
  }
  j["marker_layout"] = layout;
  Json effects = Json::array();
  for (const InjectedEffect& e : t.effects)
    effects.push_back(
        {{"stage", e.stage}, {"name", e.name}, {"magnitude", e.magnitude}, {"unit", e.unit}, {"detail", e.detail}});
  j["effects"] = effects;
  Json cams = Json::array();
  for (const TrueCamera& c : t.cameras) {
    std::vector<double> dlt(c.camera.dlt.data(), c.camera.dlt.data() + 11);
    Json r = Json::array();
    for (int i = 0; i < 3; ++i) r.push_back({c.cam_from_lab_r(i, 0), c.cam_from_lab_r(i, 1), c.cam_from_lab_r(i, 2)});
    cams.push_back({{"name", c.camera.name},
                    {"dlt", dlt},
                    {"distortion", c.camera.distortion},
                    {"principal_point_px", {c.camera.principal_point_px.x(), c.camera.principal_point_px.y()}},
                    {"focal_px", c.camera.focal_px},
                    {"image_size_px", {c.width_px, c.height_px}},
                    {"cam_from_lab_r", r},
                    {"cam_from_lab_t_m", {c.cam_from_lab_t.x(), c.cam_from_lab_t.y(), c.cam_from_lab_t.z()}},
                    {"centre_lab_m", {c.centre_lab_m.x(), c.centre_lab_m.y(), c.centre_lab_m.z()}}});
  }
  j["cameras"] = cams;
  Json markers = Json::array();
  for (const TrueCalibrationMarker& mk : t.calibration_markers) {
    Json px = Json::object();
    for (std::size_t c = 0; c < mk.image_px.size() && c < t.cameras.size(); ++c)
      px[t.cameras[c].camera.name] = {mk.image_px[c].x(), mk.image_px[c].y()};
    markers.push_back({{"id", mk.id},
                       {"lab_m", {mk.lab_m.x(), mk.lab_m.y(), mk.lab_m.z()}},
                       {"role", mk.role == MarkerRole::Fit ? "fit" : "check"},
                       {"image_px_noise_free", px}});
  }
  j["calibration_markers"] = markers;
  Json trials = Json::array();
  for (const TrialTruth& tr : t.trials) {
    Json gaps = Json::array();
    for (const Gap& g : tr.gaps)
      gaps.push_back({{"point", g.point}, {"camera", g.camera}, {"first_frame", g.first_frame}, {"n_frames", g.n_frames}});
    std::vector<double> offsets(tr.channel_offsets_n.data(), tr.channel_offsets_n.data() + 8);
    trials.push_back({{"id", tr.id},
                      {"impact_velocity_m_s", tr.impact_velocity_m_s},
                      {"max_deformation_m", tr.max_deformation_m},
                      {"max_surface_travel_m", tr.max_surface_travel_m},
                      {"peak_force_n", tr.peak_force_n},
                      {"time_to_peak_s", tr.time_to_peak_s},
                      {"tilt_deg", tr.tilt_deg},
                      {"tilt_about_y_deg", tr.tilt_about_y_deg},
                      {"contact_time_s", tr.contact_time_s},
                      {"separation_time_s", num(tr.separation_time_s)},
                      {"video_offset_s", tr.video_offset_s},
                      {"drop_height_m", tr.drop_height_m},
                      {"trigger_index", tr.trigger_index},
                      {"cop_m", {tr.cop_m.x(), tr.cop_m.y()}},
                      {"impact_point_m", {tr.impact_point_m.x(), tr.impact_point_m.y()}},
                      {"shear_fraction", {tr.shear_fraction.x(), tr.shear_fraction.y()}},
                      {"channel_offsets_n", offsets},
                      {"model", model_key(tr.model)},
                      {"parameters", params_json(tr.params)},
                      {"gaps", gaps},
                      {"impact_velocity_after_m_s", num(tr.impact_velocity_after_m_s)},
                      {"tilt_axis_deg", tr.tilt_axis_deg},
                      {"dish_factors", tr.dish_factors},
                      {"digitised_frames", {tr.digitised_first_frame, tr.digitised_last_frame}},
                      {"series",
                       {{"t_s", vec(tr.t_s, 1e-9)},
                        {"grf_n", vec(tr.grf_n, 1e-6)},
                        {"impactor_travel_m", vec(tr.impactor_travel_m, 1e-9)},
                        {"surface_travel_m", vec(tr.surface_travel_m, 1e-9)},
                        {"layer1_travel_m", vec(tr.layer1_travel_m, 1e-9)},
                        {"layer2_travel_m", vec(tr.layer2_travel_m, 1e-9)},
                        {"plate_fz_noise_free_n", vec(tr.plate_fz_noise_free_n, 1e-6)}}}});
  }
  j["trials"] = trials;

  // Whole or not at all (core/atomic_file.h), into a folder that must exist.
  const std::filesystem::path parent = std::filesystem::path(path).parent_path();
  if (!parent.empty() && !std::filesystem::is_directory(parent))
    throw Error(fmt::format("cannot write {}: no folder {}", path, parent.string()));
  try {
    write_file_atomic(path, j.dump(1) + '\n');
  } catch (const Error& e) {
    throw Error(fmt::format("cannot write {}: {}", path, e.what()));
  }
}

}  // namespace dropfit::synth
