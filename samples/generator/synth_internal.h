#pragma once
// What the generator's own source files share (not part of its public
// header): deterministic random numbers, the writers' rounding, the camera
// projection, and the pieces make_session() assembles a session from
// (synth.cpp: the session; synth_options.cpp: checks and presets;
// synth_cameras.cpp: cameras and calibration; synth_trial.cpp: one trial).
#include <Eigen/Core>
#include <fmt/format.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <string>

#include "core/error.h"
#include "samples/generator/synth.h"

namespace dropfit::synth::detail {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
inline constexpr double kPi = 3.14159265358979323846;
inline constexpr double kDeg = kPi / 180.0;
inline constexpr double kSimDt = 1e-5;  // output step of the physics (simulate_chain), interpolated linearly

// ---- Random numbers: deterministic on every platform --------------------
// mt19937_64's output is fixed by the standard; the distributions of
// <random> are not, so uniform and normal are written out here. Each use has
// its own stream (seed, stream id), so that switching an effect on does not
// change the draws of anything else.
inline std::uint64_t splitmix64(std::uint64_t x) {
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
inline constexpr std::uint64_t kStreamCalibrationNoise = 1;
inline constexpr std::uint64_t kStreamOutlier = 2;
inline constexpr std::uint64_t kStreamLayout = 3;
inline constexpr std::uint64_t kStreamGaps = 3000;  // + trial index
inline constexpr std::uint64_t kStreamTrial = 100;       // + trial index: tilt, impact point, shear, offsets
inline constexpr std::uint64_t kStreamForceNoise = 1000;  // + trial index: contact phase and channel noise
inline constexpr std::uint64_t kStreamPixelNoise = 2000;  // + trial index


// Rounds to the writers' six decimals, so that what read_session returns
// equals the in-memory session bit for bit (N / 1e6 is correctly rounded,
// as strtod is).
inline double six_decimals(double v) { return std::isfinite(v) ? std::round(v * 1e6) / 1e6 : v; }

// Linear interpolation of a series sampled every dt from 0; clamps at the ends.
inline double interp(const Eigen::VectorXd& y, double t, double dt) {
  const Eigen::Index n = y.size();
  if (n == 0) return 0.0;
  const double x = t / dt;
  if (x <= 0.0) return y(0);
  const auto k = static_cast<Eigen::Index>(std::floor(x));
  if (k >= n - 1) return y(n - 1);
  const double f = x - static_cast<double>(k);
  return (1.0 - f) * y(k) + f * y(k + 1);
}

inline std::string model_key(ModelChoice kind) { return fmt::format("model{}", kind.number); }

inline void require(bool ok, const std::string& reason) {
  if (!ok) throw Error("dropfit-synth: " + reason);
}

// Throws dropfit::Error naming the first option out of its range.
void validate(const SynthOptions& o);

// The ideal pinhole pixel of a lab point (its depth in the camera when asked).
inline Eigen::Vector2d pinhole_px(const TrueCamera& cam, const Eigen::Vector3d& lab_m, double* depth_m = nullptr) {
  const Eigen::Vector3d c = cam.cam_from_lab_r * lab_m + cam.cam_from_lab_t;
  if (depth_m) *depth_m = c.z();
  const Eigen::Vector3d h = cam.k * c;
  return h.head<2>() / h.z();
}

inline bool in_image(const TrueCamera& cam, const Eigen::Vector2d& px, double depth_m) {
  return depth_m > 0.0 && px.allFinite() && px.x() >= 0.0 && px.x() < cam.width_px && px.y() >= 0.0 &&
         px.y() < cam.height_px;
}

// Base markers in the impactor's frame (face centre origin, X front, Z up) and mat markers' lab x, y.
struct MarkerLayout {
  Eigen::Vector3d base_offset[2];
  Eigen::Vector2d mat_xy[4];
};

// The true cameras, with the lens_distortion effect (k1 from its pixel size when given).
void make_true_cameras(const SynthOptions& o, double mat_top_m, const MarkerLayout& layout, SynthTruth& truth);

// The calibration frame and its noisy images, with the outlier_marker and outlier_swap effects.
void make_calibration(const SynthOptions& o, double mat_top_m, SynthTruth& truth, Session& session);

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

// One simulated trial: its recording and its truth.
struct SimulatedTrial {
  TrialRecording trial;
  TrialTruth tt;
};

// Simulates trial ti: pose, physics, force record, video and gaps.
SimulatedTrial simulate_trial(const TrialSetup& setup, std::size_t ti);

}  // namespace dropfit::synth::detail
