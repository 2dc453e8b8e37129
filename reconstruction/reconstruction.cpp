#include "reconstruction/reconstruction.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

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

bool CameraLag::changes_part_way() const {
  const double whole = rms_px(best_lag);
  return change_row >= 0 && lag_before != lag_after && std::isfinite(whole) && std::isfinite(split_rms_px) &&
         whole > kLagResidualFactor * split_rms_px;
}

namespace {

// Per row f of camera 0: the summed squared residual and the count of
// points seen in both cameras, with camera c's row f + lag beside it.
struct LagRows {
  std::vector<double> sum_sq;
  std::vector<int> count;
};

LagRows lag_rows(const std::vector<calibration::Camera>& pair, const Eigen::MatrixXd& uv_px, int n_points,
                 int n_cameras, int c, const std::vector<int>& points, int l) {
  const Eigen::Index n_frames = uv_px.rows();
  LagRows rows{std::vector<double>(static_cast<std::size_t>(n_frames), 0.0),
               std::vector<int>(static_cast<std::size_t>(n_frames), 0)};
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
      rows.sum_sq[static_cast<std::size_t>(f)] += t.residual_px * t.residual_px;
      ++rows.count[static_cast<std::size_t>(f)];
    }
  }
  return rows;
}

// The best split of the rows into two lags (CameraLag::change_row) into lag.
void split_lags(const std::vector<LagRows>& by_lag, CameraLag& lag) {
  const std::size_t n_lags = by_lag.size();
  const std::size_t n_frames = n_lags ? by_lag[0].sum_sq.size() : 0;
  // Prefix sums per lag: rows [0, m).
  std::vector<std::vector<double>> sq(n_lags, std::vector<double>(n_frames + 1, 0.0));
  std::vector<std::vector<int>> cnt(n_lags, std::vector<int>(n_frames + 1, 0));
  for (std::size_t l = 0; l < n_lags; ++l)
    for (std::size_t f = 0; f < n_frames; ++f) {
      sq[l][f + 1] = sq[l][f] + by_lag[l].sum_sq[f];
      cnt[l][f + 1] = cnt[l][f] + by_lag[l].count[f];
    }
  // The best lag over rows [a, b): its mean squared residual and index.
  auto best_in = [&](std::size_t a, std::size_t b) {
    std::pair<double, std::size_t> best{std::numeric_limits<double>::infinity(), 0};
    for (std::size_t l = 0; l < n_lags; ++l) {
      const int n = cnt[l][b] - cnt[l][a];
      if (n < kMinLagFrames) continue;
      const double m = (sq[l][b] - sq[l][a]) / n;
      if (m < best.first) best = {m, l};
    }
    return best;
  };
  double best = std::numeric_limits<double>::infinity();
  for (std::size_t m = 1; m < n_frames; ++m) {
    const auto [before, lb] = best_in(0, m);
    const auto [after, la] = best_in(m, n_frames);
    if (!std::isfinite(before) || !std::isfinite(after)) continue;
    const double nb = cnt[lb][m], na = cnt[la][n_frames] - cnt[la][m];
    const double mean = (before * nb + after * na) / (nb + na);
    if (mean < best) {
      best = mean;
      lag.change_row = static_cast<int>(m);
      lag.lag_before = static_cast<int>(lb) - lag.max_lag;
      lag.lag_after = static_cast<int>(la) - lag.max_lag;
    }
  }
  if (std::isfinite(best)) lag.split_rms_px = std::sqrt(best);
}

}  // namespace

std::vector<CameraLag> camera_lags(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                                   int n_points, const std::vector<int>& points, int max_lag) {
  const int n_cameras = static_cast<int>(cameras.size());
  if (n_points < 0 || uv_px.cols() != 2 * static_cast<Eigen::Index>(n_points) * n_cameras)
    throw Error(fmt::format("camera_lags: the 2-D tracks have {} columns; {} points in {} cameras need {}",
                            uv_px.cols(), n_points, n_cameras, 2 * n_points * n_cameras));
  std::vector<CameraLag> out;
  for (int c = 1; c < n_cameras; ++c) {
    const std::vector<calibration::Camera> pair{cameras[0], cameras[static_cast<std::size_t>(c)]};
    CameraLag lag;
    lag.camera = c;
    lag.name = cameras[static_cast<std::size_t>(c)].name;
    lag.reference = cameras[0].name;
    lag.max_lag = max_lag;
    std::vector<LagRows> by_lag;
    for (int l = -max_lag; l <= max_lag; ++l) {
      by_lag.push_back(lag_rows(pair, uv_px, n_points, n_cameras, c, points, l));
      const double sum = std::accumulate(by_lag.back().sum_sq.begin(), by_lag.back().sum_sq.end(), 0.0);
      const int n = std::accumulate(by_lag.back().count.begin(), by_lag.back().count.end(), 0);
      lag.mean_sq_px.push_back(n >= kMinLagFrames ? sum / n : std::numeric_limits<double>::quiet_NaN());
    }
    for (int l = -max_lag; l <= max_lag; ++l) {
      const double v = lag.mean_sq_px[static_cast<std::size_t>(l + max_lag)];
      if (std::isfinite(v) && !(lag.mean_sq_px[static_cast<std::size_t>(lag.best_lag + max_lag)] <= v)) lag.best_lag = l;
    }
    split_lags(by_lag, lag);
    out.push_back(std::move(lag));
  }
  return out;
}

}  // namespace dropfit::reconstruction
