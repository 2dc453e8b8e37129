// reconstruction/: triangulation of single points and of whole DLTdv-layout
// tracks, against the known truth of tests/support/cameras.h.
#include "reconstruction/reconstruction.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>
#include <limits>
#include <numbers>
#include <vector>

#include "core/error.h"
#include "support/cameras.h"

namespace {

using namespace dropfit;
using calibration::Camera;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::vector<Camera> true_cameras(double k1 = 0.0) {
  std::vector<Camera> cameras;
  for (const auto& c : testsupport::two_cameras(k1)) cameras.push_back(c.as_camera());
  return cameras;
}

// Cameras calibrated from the 20-marker structure at 0.25 px noise.
std::vector<Camera> calibrated_cameras(unsigned seed) {
  const auto truth = testsupport::two_cameras();
  const auto markers = testsupport::calibration_markers();
  calibration::CalibrationOptions options;
  options.leave_one_out = false;
  const auto result = calibration::calibrate(markers, testsupport::observe(truth, markers, 0.25, seed), options);
  std::vector<Camera> cameras;
  for (const auto& fit : result.cameras) cameras.push_back(fit.camera);
  return cameras;
}

std::vector<Eigen::Vector2d> pixels(const std::vector<testsupport::TrueCamera>& truth, const Eigen::Vector3d& X,
                                    testsupport::PixelNoise& noise) {
  std::vector<Eigen::Vector2d> px;
  for (const auto& c : truth) px.push_back(c.project(X) + noise());
  return px;
}

TEST(Triangulate, NoiseFreePointsAreExact) {
  const auto truth = testsupport::two_cameras();
  const auto cameras = true_cameras();
  testsupport::PixelNoise none(0.0, 1);
  for (const auto& X : testsupport::volume_grid(4)) {
    for (bool refine : {false, true}) {
      const auto t = reconstruction::triangulate(cameras, pixels(truth, X, none), refine);
      EXPECT_EQ(t.n_cameras, 2);
      EXPECT_LT((t.lab_m - X).norm(), 1e-9);
      EXPECT_LT(t.residual_px, 1e-6);
    }
  }
}

// 3-D errors of random points in the volume digitised with 0.25 px noise.
struct ErrorSummary {
  double rms_m = 0.0, worst_m = 0.0, within_1mm = 0.0;  // share of points within 1 mm
};
ErrorSummary triangulation_errors(const std::vector<Camera>& cameras, unsigned seed, int n_points) {
  const auto truth = testsupport::two_cameras();
  std::mt19937 engine(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  testsupport::PixelNoise noise(0.25, 100 + seed);
  ErrorSummary s;
  for (int i = 0; i < n_points; ++i) {
    const Eigen::Vector3d X(-0.45 + 0.9 * unit(engine), -0.3 + 0.6 * unit(engine), 0.8 * unit(engine));
    const auto t = reconstruction::triangulate(cameras, pixels(truth, X, noise));
    const double e = (t.lab_m - X).norm();
    s.rms_m += e * e;
    s.worst_m = std::max(s.worst_m, e);
    s.within_1mm += e < 0.001 ? 1.0 : 0.0;
    EXPECT_LT(t.residual_px, 1.5);
  }
  s.rms_m = std::sqrt(s.rms_m / n_points);
  s.within_1mm /= n_points;
  return s;
}

TEST(Triangulate, WithinOneMillimetreAtQuarterPixelNoise) {
  // 1 px is about 1.3 mm here, so 0.25 px gives about 0.3 mm per axis and
  // a 3-D error whose tail passes 1 mm now and then (1.4 mm worst of 300).
  const ErrorSummary exact = triangulation_errors(true_cameras(), 7, 300);
  std::printf("0.25 px, true cameras: 3-D RMS %.3f mm, worst %.3f mm, %.1f %% within 1 mm\n", 1e3 * exact.rms_m,
              1e3 * exact.worst_m, 100 * exact.within_1mm);
  EXPECT_LT(exact.rms_m, 0.0007);
  EXPECT_GT(exact.within_1mm, 0.95);
  EXPECT_LT(exact.worst_m, 0.0015);

  // Cameras calibrated at 0.25 px as well (5 calibrations, 50 points each).
  double sum_sq = 0.0, worst = 0.0, within = 0.0;
  for (unsigned seed = 1; seed <= 5; ++seed) {
    const ErrorSummary s = triangulation_errors(calibrated_cameras(seed), seed, 50);
    sum_sq += s.rms_m * s.rms_m;
    worst = std::max(worst, s.worst_m);
    within += s.within_1mm / 5.0;
  }
  const double rms = std::sqrt(sum_sq / 5.0);
  std::printf("0.25 px, calibrated cameras: 3-D RMS %.3f mm, worst %.3f mm, %.1f %% within 1 mm\n", 1e3 * rms,
              1e3 * worst, 100 * within);
  EXPECT_LT(rms, 0.001);
  EXPECT_GT(within, 0.85);
  EXPECT_LT(worst, 0.002);
}

TEST(Triangulate, RefinementLowersTheReprojectionResidual) {
  const auto truth = testsupport::two_cameras();
  const auto cameras = true_cameras();
  testsupport::PixelNoise noise(0.5, 5);
  for (const auto& X : testsupport::volume_grid(3)) {
    const auto px = pixels(truth, X, noise);
    const auto linear = reconstruction::triangulate(cameras, px, false);
    const auto refined = reconstruction::triangulate(cameras, px, true);
    EXPECT_LE(refined.residual_px, linear.residual_px + 1e-12);
    EXPECT_LT((refined.lab_m - linear.lab_m).norm(), 1e-3);  // a small correction
  }
}

TEST(Triangulate, APointSeenByOneCameraIsAGap) {
  const auto truth = testsupport::two_cameras();
  testsupport::PixelNoise none(0.0, 1);
  auto px = pixels(truth, Eigen::Vector3d(0.1, 0.0, 0.3), none);
  px[1] = Eigen::Vector2d(kNaN, kNaN);
  const auto t = reconstruction::triangulate(true_cameras(), px);
  EXPECT_EQ(t.n_cameras, 1);
  EXPECT_TRUE(t.lab_m.array().isNaN().all());
  EXPECT_TRUE(std::isnan(t.residual_px));
  // Half a pixel missing is not seen either.
  px[1] = Eigen::Vector2d(400.0, kNaN);
  EXPECT_TRUE(reconstruction::triangulate(true_cameras(), px).lab_m.array().isNaN().all());
}

TEST(Triangulate, ParallelRaysAreAGap) {
  // The same camera twice: the rays coincide and the point is undetermined.
  const auto truth = testsupport::two_cameras();
  const std::vector<Camera> twice{truth[0].as_camera(), truth[0].as_camera()};
  const Eigen::Vector2d px = truth[0].project(Eigen::Vector3d(0.0, 0.0, 0.4));
  const auto t = reconstruction::triangulate(twice, {px, px});
  EXPECT_TRUE(t.lab_m.array().isNaN().all());
}

TEST(Triangulate, UndistortsCamerasWithLensDistortion) {
  const auto truth = testsupport::two_cameras(-0.2);
  const auto cameras = true_cameras(-0.2);
  testsupport::PixelNoise none(0.0, 1);
  for (const auto& X : testsupport::volume_grid(4)) {
    const auto t = reconstruction::triangulate(cameras, pixels(truth, X, none));
    EXPECT_LT((t.lab_m - X).norm(), 1e-8);
    EXPECT_LT(t.residual_px, 1e-6);  // measured against the distorted projection
  }
}

TEST(Triangulate, MismatchedLengthsThrow) {
  EXPECT_THROW(reconstruction::triangulate(true_cameras(), {Eigen::Vector2d(1.0, 2.0)}), Error);
}

// n_frames x (2 * n_points * n_cameras) in the DLTdv layout.
Eigen::MatrixXd dltdv_tracks(const std::vector<testsupport::TrueCamera>& truth,
                             const std::vector<std::vector<Eigen::Vector3d>>& path, double noise_px) {
  const int n_frames = static_cast<int>(path.size()), n_points = static_cast<int>(path[0].size());
  const int n_cameras = static_cast<int>(truth.size());
  testsupport::PixelNoise noise(noise_px, 42);
  Eigen::MatrixXd uv(n_frames, 2 * n_points * n_cameras);
  for (int f = 0; f < n_frames; ++f)
    for (int p = 0; p < n_points; ++p)
      for (int c = 0; c < n_cameras; ++c)
        uv.row(f).segment<2>(2 * (p * n_cameras + c)) = (truth[c].project(path[f][p]) + noise()).transpose();
  return uv;
}

TEST(Reconstruct, FollowsTheDltdvColumnLayoutAndLeavesGaps) {
  // Three points moving differently over 40 frames at 1000 Hz.
  const auto truth = testsupport::two_cameras();
  std::vector<std::vector<Eigen::Vector3d>> path;
  for (int f = 0; f < 40; ++f) {
    const double t = 1e-3 * f;
    path.push_back({Eigen::Vector3d(0.0, 0.0, 0.6 - 5.0 * t), Eigen::Vector3d(0.3, -0.2, 0.2),
                    Eigen::Vector3d(-0.3, 0.1, 0.2 - 0.5 * t)});
  }
  Eigen::MatrixXd uv = dltdv_tracks(truth, path, 0.0);
  // Point 1 (0-based) not digitised in camera 1 for frames 10..14.
  uv.block(10, 2 * (1 * 2 + 1), 5, 2).setConstant(kNaN);

  const auto out = reconstruction::reconstruct(true_cameras(), uv, 3);
  ASSERT_EQ(out.n_frames(), 40);
  ASSERT_EQ(out.n_points(), 3);
  ASSERT_EQ(out.lab_m.cols(), 9);
  for (int f = 0; f < 40; ++f)
    for (int p = 0; p < 3; ++p) {
      if (p == 1 && f >= 10 && f < 15) {
        EXPECT_TRUE(out.point(f, p).array().isNaN().all()) << f;
        EXPECT_TRUE(std::isnan(out.residual_px(f, p)));
        continue;
      }
      EXPECT_LT((out.point(f, p) - path[f][p]).norm(), 1e-9) << "frame " << f << " point " << p;
      EXPECT_LT(out.residual_px(f, p), 1e-6);
    }
}

TEST(Reconstruct, MatchesTriangulateWithNoise) {
  const auto truth = testsupport::two_cameras();
  const auto cameras = calibrated_cameras(3);
  std::vector<std::vector<Eigen::Vector3d>> path;
  for (int f = 0; f < 20; ++f)
    path.push_back({Eigen::Vector3d(0.05 * f / 20.0, 0.0, 0.5), Eigen::Vector3d(-0.2, 0.2, 0.1 + 0.01 * f)});
  const Eigen::MatrixXd uv = dltdv_tracks(truth, path, 0.25);
  const auto out = reconstruction::reconstruct(cameras, uv, 2);
  for (int f = 0; f < 20; ++f)
    for (int p = 0; p < 2; ++p) {
      const std::vector<Eigen::Vector2d> px{uv.row(f).segment<2>(2 * (p * 2)).transpose(),
                                            uv.row(f).segment<2>(2 * (p * 2 + 1)).transpose()};
      const auto t = reconstruction::triangulate(cameras, px);
      EXPECT_EQ(out.point(f, p), t.lab_m);
      EXPECT_EQ(out.residual_px(f, p), t.residual_px);
      EXPECT_LT((t.lab_m - path[f][p]).norm(), 0.002);
    }
}

// A drop seen at 1 kHz: a marker falling at 4 m/s from 0.7 m, stopped over
// 40 ms from row 100 (half a sine of deceleration), then at rest; a second
// marker at rest. Its height at row f + lag (lag in rows, fractional).
Eigen::Vector3d dropping(double f) {
  const double t = 1e-3 * f, v0 = 4.0, stop = 0.1, span = 0.04;
  if (t < stop) return {0.05, 0.0, 0.7 - v0 * t};
  const double u = std::min(t - stop, span);
  // Velocity v0 (1 + cos(pi u / span)) / 2 over the span: its integral.
  const double fall = 0.5 * v0 * (u + span / std::numbers::pi * std::sin(std::numbers::pi * u / span));
  return {0.05, 0.0, 0.7 - v0 * stop - fall};
}

// Camera 1's pixels lag_rows later than camera 0's.
Eigen::MatrixXd drop_tracks(double noise_px, double lag_rows, unsigned seed) {
  const auto truth = testsupport::two_cameras();
  testsupport::PixelNoise noise(noise_px, seed);
  const int rows = 240;
  Eigen::MatrixXd uv(rows, 8);
  for (int f = 0; f < rows; ++f) {
    const Eigen::Vector3d still(-0.2, 0.1, 0.2);
    uv.row(f).segment<2>(0) = (truth[0].project(dropping(f)) + noise()).transpose();
    uv.row(f).segment<2>(2) = (truth[1].project(dropping(f + lag_rows)) + noise()).transpose();
    uv.row(f).segment<2>(4) = (truth[0].project(still) + noise()).transpose();
    uv.row(f).segment<2>(6) = (truth[1].project(still) + noise()).transpose();
  }
  return uv;
}

// Rays through one point meet: the distance from the epipolar line is 0;
// a pixel moved in camera 1 moves it by the move's component across the
// line, the same size either way.
TEST(MarkerSlips, TheEpipolarDistanceIsTheMoveAcrossTheLine) {
  const auto cameras = true_cameras();
  Eigen::MatrixXd uv = drop_tracks(0.0, 0.0, 1);
  const auto clean = reconstruction::epipolar_distance(cameras[0], cameras[1], uv, 2, 2, 0);
  for (int f = 0; f < 240; ++f) EXPECT_NEAR(clean.distance_px[static_cast<std::size_t>(f)], 0.0, 1e-6) << f;
  uv(50, 2) += 3.0;
  const double plus = reconstruction::epipolar_distance(cameras[0], cameras[1], uv, 2, 2, 0).distance_px[50];
  uv(50, 2) -= 6.0;
  const double minus = reconstruction::epipolar_distance(cameras[0], cameras[1], uv, 2, 2, 0).distance_px[50];
  EXPECT_NEAR(plus, -minus, 1e-6);
  EXPECT_GT(std::abs(plus), 0.5);  // the lines are not along camera 1's x axis
  EXPECT_LE(std::abs(plus), 3.0 + 1e-9);
  EXPECT_THROW(reconstruction::epipolar_distance(cameras[0], cameras[1], uv, 2, 2, 2), Error);
}

// Camera 1 a third of a row late: the fitted offset is that third within
// 0.03 rows at 0.2 px noise.
TEST(MarkerSlips, TheSubframeOffsetIsRecovered) {
  const auto cameras = true_cameras();
  const Eigen::MatrixXd uv = drop_tracks(0.2, 1.0 / 3.0, 2);
  std::vector<reconstruction::EpipolarSeries> series;
  for (int p = 0; p < 2; ++p) series.push_back(reconstruction::epipolar_distance(cameras[0], cameras[1], uv, 2, 2, p));
  EXPECT_NEAR(reconstruction::subframe_offset(series).rows, 1.0 / 3.0, 0.03);
}

// Camera 1's pixels moved to camera 0's instants: the offset goes (within
// 0.02 rows at 0.2 px noise), and a row whose neighbour is missing becomes
// a gap.
TEST(MarkerSlips, ResamplingTakesTheSubframeOffsetOut) {
  const auto cameras = true_cameras();
  Eigen::MatrixXd uv = drop_tracks(0.2, 0.4, 4);
  uv.block<1, 2>(60, 2).setConstant(kNaN);
  const auto before = reconstruction::subframe_offset(cameras, uv, 2);
  ASSERT_TRUE(before.significant());
  EXPECT_NEAR(before.rows, 0.4, 0.03);
  const Eigen::MatrixXd aligned = reconstruction::resample_camera(uv, 2, 2, 1, before.rows);
  const auto after = reconstruction::subframe_offset(cameras, aligned, 2);
  EXPECT_NEAR(after.rows, 0.0, 0.02);
  EXPECT_FALSE(after.significant());
  // Row 60 is missing: rows 60 and 61 (which read it) are gaps; camera 0 untouched.
  EXPECT_TRUE(std::isnan(aligned(60, 2)) && std::isnan(aligned(61, 2)));
  EXPECT_TRUE(std::isfinite(aligned(62, 2)));
  EXPECT_EQ(aligned.col(0), uv.col(0));
  EXPECT_THROW(reconstruction::resample_camera(uv, 2, 2, 2, 0.4), Error);
}

// Point 0 clicked 3 px off in camera 0 over rows 90-125 (through the
// stop), with camera 1 half a row late: one slip, those rows, point 0; the
// still point none. Without the slip: none.
TEST(MarkerSlips, AStretchClickedOffIsFoundToTheRow) {
  const auto cameras = true_cameras();
  Eigen::MatrixXd uv = drop_tracks(0.2, 0.5, 3);
  EXPECT_TRUE(reconstruction::marker_slips(cameras, uv, 2).empty());
  for (int f = 90; f <= 125; ++f) uv(f, 0) += 3.0, uv(f, 1) += 3.0;
  const auto slips = reconstruction::marker_slips(cameras, uv, 2);
  ASSERT_EQ(slips.size(), 1u);
  EXPECT_EQ(slips[0].point, 0);
  EXPECT_NEAR(slips[0].first_row, 90, 1);
  EXPECT_NEAR(slips[0].last_row, 125, 1);
  EXPECT_GE(std::abs(slips[0].z), reconstruction::kSlipMeanZ);
  EXPECT_THROW(reconstruction::marker_slips(cameras, Eigen::MatrixXd::Zero(5, 6), 2), Error);
  EXPECT_TRUE(reconstruction::marker_slips({cameras[0]}, Eigen::MatrixXd::Zero(5, 4), 2).empty());
}

TEST(Reconstruct, WrongColumnCountThrows) {
  const Eigen::MatrixXd uv = Eigen::MatrixXd::Zero(5, 10);  // 2 points x 2 cameras need 8
  EXPECT_THROW(reconstruction::reconstruct(true_cameras(), uv, 2), Error);
  EXPECT_THROW(reconstruction::reconstruct({}, Eigen::MatrixXd::Zero(5, 0), 0), Error);
}

}  // namespace
