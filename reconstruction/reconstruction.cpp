#include "reconstruction/reconstruction.h"

#include <fmt/format.h>

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

}  // namespace dropfit::reconstruction
