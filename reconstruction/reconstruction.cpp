#include "reconstruction/reconstruction.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include "core/error.h"

namespace dropfit::reconstruction {

Triangulation triangulate(const std::vector<calibration::Camera>& cameras,
                          const std::vector<Eigen::Vector2d>& image_px, bool refine) {
  if (cameras.size() != image_px.size())
    throw Error(fmt::format("triangulate: {} pixels given for {} cameras", image_px.size(), cameras.size()));
  return calibration::triangulate(cameras, image_px, refine);
}

Trajectories reconstruct(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                         int n_points, bool refine) {
  const int n_cameras = static_cast<int>(cameras.size());
  if (n_cameras == 0) throw Error("reconstruct: no calibrated cameras");
  if (n_points < 0 || uv_px.cols() != 2 * static_cast<Eigen::Index>(n_points) * n_cameras)
    throw Error(fmt::format("reconstruct: the 2-D tracks have {} columns; {} points in {} cameras need {}",
                            uv_px.cols(), n_points, n_cameras, 2 * n_points * n_cameras));
  const Eigen::Index n_frames = uv_px.rows();
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  Trajectories out;
  out.lab_m = Eigen::MatrixXd::Constant(n_frames, 3 * n_points, kNaN);
  out.residual_px = Eigen::MatrixXd::Constant(n_frames, n_points, kNaN);
  std::vector<Eigen::Vector2d> px(cameras.size());
  for (int p = 0; p < n_points; ++p) {
    for (Eigen::Index f = 0; f < n_frames; ++f) {
      for (int c = 0; c < n_cameras; ++c) {
        const Eigen::Index column = 2 * (static_cast<Eigen::Index>(p) * n_cameras + c);
        px[c] = {uv_px(f, column), uv_px(f, column + 1)};
      }
      const Triangulation t = calibration::triangulate(cameras, px, refine);
      if (!t.lab_m.allFinite()) continue;
      out.lab_m.row(f).segment<3>(3 * p) = t.lab_m.transpose();
      out.residual_px(f, p) = t.residual_px;
    }
  }
  return out;
}

double CameraLag::rms_px(int lag) const {
  const int k = lag + max_lag;
  if (k < 0 || k >= static_cast<int>(mean_sq_px.size())) return std::numeric_limits<double>::quiet_NaN();
  return std::sqrt(mean_sq_px[static_cast<std::size_t>(k)]);
}

bool CameraLag::desynchronised() const {
  const double at_zero = rms_px(0), at_best = rms_px(best_lag);
  return best_lag != 0 && std::isfinite(at_zero) && std::isfinite(at_best) && at_zero > kLagResidualFactor * at_best;
}

std::vector<CameraLag> camera_lags(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                                   int n_points, const std::vector<int>& points, int max_lag) {
  const int n_cameras = static_cast<int>(cameras.size());
  if (n_points < 0 || uv_px.cols() != 2 * static_cast<Eigen::Index>(n_points) * n_cameras)
    throw Error(fmt::format("camera_lags: the 2-D tracks have {} columns; {} points in {} cameras need {}",
                            uv_px.cols(), n_points, n_cameras, 2 * n_points * n_cameras));
  const Eigen::Index n_frames = uv_px.rows();
  std::vector<CameraLag> out;
  for (int c = 1; c < n_cameras; ++c) {
    const std::vector<calibration::Camera> pair{cameras[0], cameras[static_cast<std::size_t>(c)]};
    CameraLag lag;
    lag.camera = c;
    lag.name = cameras[static_cast<std::size_t>(c)].name;
    lag.reference = cameras[0].name;
    lag.max_lag = max_lag;
    for (int l = -max_lag; l <= max_lag; ++l) {
      double sum = 0.0;
      int n = 0;
      for (int p : points) {
        if (p < 0 || p >= n_points) continue;
        const Eigen::Index col0 = 2 * static_cast<Eigen::Index>(p) * n_cameras;
        const Eigen::Index colc = col0 + 2 * c;
        for (Eigen::Index f = std::max<Eigen::Index>(0, -l); f < n_frames && f + l < n_frames; ++f) {
          const std::vector<Eigen::Vector2d> px{{uv_px(f, col0), uv_px(f, col0 + 1)},
                                                {uv_px(f + l, colc), uv_px(f + l, colc + 1)}};
          if (!px[0].allFinite() || !px[1].allFinite()) continue;
          const Triangulation t = calibration::triangulate(pair, px, false);
          if (!std::isfinite(t.residual_px)) continue;
          sum += t.residual_px * t.residual_px;
          ++n;
        }
      }
      lag.mean_sq_px.push_back(n >= kMinLagFrames ? sum / n : std::numeric_limits<double>::quiet_NaN());
    }
    for (int l = -max_lag; l <= max_lag; ++l) {
      const double v = lag.mean_sq_px[static_cast<std::size_t>(l + max_lag)];
      if (std::isfinite(v) && !(lag.mean_sq_px[static_cast<std::size_t>(lag.best_lag + max_lag)] <= v)) lag.best_lag = l;
    }
    out.push_back(std::move(lag));
  }
  return out;
}

}  // namespace dropfit::reconstruction
