#include "reconstruction/reconstruction.h"

#include <Eigen/Geometry>
#include <Eigen/LU>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <utility>

#include "core/error.h"
#include "core/median.h"

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

EpipolarSeries epipolar_distance(const calibration::Camera& cam0, const calibration::Camera& cam1,
                                 const Eigen::MatrixXd& uv_px, int n_points, int n_cameras, int p) {
  if (p < 0 || p >= n_points || uv_px.cols() < 2 * static_cast<Eigen::Index>(n_points) * n_cameras)
    throw Error(fmt::format("epipolar_distance: point {} of {} in {} columns", p, n_points, uv_px.cols()));
  const calibration::Matrix34d p0 = cam0.image_from_lab(), p1 = cam1.image_from_lab();
  // F = [e1]x P1 P0^+, e1 camera 0's centre seen by camera 1 (Hartley &
  // Zisserman 2003, sec. 9.2.2). Camera 0's pixel x0 (homogeneous, w = 1)
  // gives the line F x0 in camera 1; the sign of x1's distance from it is
  // the same for every row.
  const Eigen::Vector3d centre = -p0.leftCols<3>().partialPivLu().solve(p0.col(3));
  const Eigen::Vector3d e1 = p1 * centre.homogeneous();
  Eigen::Matrix3d cross;
  cross << 0.0, -e1.z(), e1.y(), e1.z(), 0.0, -e1.x(), -e1.y(), e1.x(), 0.0;
  const Eigen::Matrix<double, 4, 3> p0_pinv = p0.transpose() * (p0 * p0.transpose()).inverse();
  const Eigen::Matrix3d f = cross * p1 * p0_pinv;
  const Eigen::Index c0 = 2 * static_cast<Eigen::Index>(p) * n_cameras, c1 = c0 + 2;
  const auto rows = static_cast<std::size_t>(uv_px.rows());
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  EpipolarSeries out{std::vector<double>(rows, kNaN), std::vector<double>(rows, kNaN)};
  std::vector<Eigen::Vector2d> x1(rows, Eigen::Vector2d::Constant(kNaN)), normal(rows, Eigen::Vector2d::Constant(kNaN));
  for (std::size_t r = 0; r < rows; ++r) {
    const auto row = static_cast<Eigen::Index>(r);
    const Eigen::Vector2d x0 = cam0.undistort({uv_px(row, c0), uv_px(row, c0 + 1)});
    x1[r] = cam1.undistort({uv_px(row, c1), uv_px(row, c1 + 1)});
    if (!x0.allFinite() || !x1[r].allFinite()) continue;
    const Eigen::Vector3d line = f * x0.homogeneous();
    const double norm = line.head<2>().norm();
    if (!(norm > 0.0)) continue;
    normal[r] = line.head<2>() / norm;
    out.distance_px[r] = line.dot(x1[r].homogeneous()) / norm;
  }
  for (std::size_t r = 1; r + 1 < rows; ++r)
    if (normal[r].allFinite() && x1[r - 1].allFinite() && x1[r + 1].allFinite())
      out.normal_velocity_px[r] = 0.5 * (x1[r + 1] - x1[r - 1]).dot(normal[r]);
  return out;
}

namespace {

// The least-squares line through the finite d[row] of rows [from, to),
// evaluated at x: its value and its variance per unit noise variance
// (1/n + (x - mean)^2 / Sxx). False with fewer than two thirds of the rows.
bool line_at(const std::vector<double>& d, int from, int to, double x, double* value, double* var_unit) {
  const int wanted = to - from;
  from = std::max(from, 0);
  to = std::min(to, static_cast<int>(d.size()));
  double n = 0.0, sx = 0.0, sy = 0.0;
  for (int r = from; r < to; ++r)
    if (std::isfinite(d[static_cast<std::size_t>(r)])) n += 1.0, sx += r, sy += d[static_cast<std::size_t>(r)];
  if (3.0 * n < 2.0 * wanted || n < 3.0) return false;
  const double mx = sx / n, my = sy / n;
  double sxx = 0.0, sxy = 0.0;
  for (int r = from; r < to; ++r) {
    const double y = d[static_cast<std::size_t>(r)];
    if (std::isfinite(y)) sxx += (r - mx) * (r - mx), sxy += (r - mx) * (y - my);
  }
  if (!(sxx > 0.0)) return false;
  *value = my + sxy / sxx * (x - mx);
  *var_unit = 1.0 / n + (x - mx) * (x - mx) / sxx;
  return true;
}

// The distance's frame-to-frame noise SD from its second differences (6
// sigma^2 for white noise), by their median absolute value: a step adds two
// large ones, which the median ignores.
double second_difference_noise(const std::vector<double>& d) {
  std::vector<double> s2;
  for (std::size_t r = 1; r + 1 < d.size(); ++r)
    if (std::isfinite(d[r - 1]) && std::isfinite(d[r]) && std::isfinite(d[r + 1]))
      s2.push_back(std::abs(d[r + 1] - 2.0 * d[r] + d[r - 1]));
  if (s2.size() < 20) return std::numeric_limits<double>::quiet_NaN();
  return 1.4826 * median(std::move(s2)) / std::sqrt(6.0);
}

// The stretch's mean against the line before it (at its first row) and the
// line after it (at its last): the smaller departure, in SEs, when both go
// the same way (else 0).
bool stretch_step(const std::vector<double>& d, int first, int last, double sigma, MarkerSlip* slip) {
  double before = 0.0, vb = 0.0, after = 0.0, va = 0.0;
  const int side = std::clamp(last - first + 1, kSlipSideRows, kMaxSlipSideRows);
  if (!line_at(d, first - side, first, first - 0.5, &before, &vb) ||
      !line_at(d, last + 1, last + 1 + side, last + 0.5, &after, &va))
    return false;
  double sum = 0.0;
  int n = 0;
  for (int r = first; r <= last; ++r)
    if (std::isfinite(d[static_cast<std::size_t>(r)])) sum += d[static_cast<std::size_t>(r)], ++n;
  if (n < kMinSlipRows) return false;
  const double mean = sum / n;
  const double zb = (mean - before) / (sigma * std::sqrt(1.0 / n + vb));
  const double za = (mean - after) / (sigma * std::sqrt(1.0 / n + va));
  slip->first_row = first;
  slip->last_row = last;
  slip->step_px = mean - 0.5 * (before + after);
  slip->noise_px = sigma;
  slip->z = std::signbit(zb) != std::signbit(za) ? 0.0 : (std::abs(zb) < std::abs(za) ? zb : za);
  return true;
}

}  // namespace

bool SubframeOffset::significant() const {
  return std::abs(rows) >= kMinSubframeRows && std::abs(rows) >= kSubframeZ * se_rows && std::abs(rows) < 1.0;
}

bool rays_meet(const std::vector<EpipolarSeries>& series) {
  std::vector<double> miss;
  for (const auto& s : series)
    for (double d : s.distance_px)
      if (std::isfinite(d)) miss.push_back(std::abs(d));
  return !miss.empty() && median(std::move(miss)) <= kRaysMeetPx;
}

SubframeOffset subframe_offset(const std::vector<EpipolarSeries>& series) {
  // Each point's rows where both the distance and the velocity are known,
  // centred on the point's own means.
  std::vector<std::pair<double, double>> centred;  // (velocity, distance)
  for (const EpipolarSeries& e : series) {
    double n = 0.0, sw = 0.0, sd = 0.0;
    for (std::size_t r = 0; r < e.distance_px.size(); ++r)
      if (std::isfinite(e.distance_px[r]) && std::isfinite(e.normal_velocity_px[r]))
        n += 1.0, sw += e.normal_velocity_px[r], sd += e.distance_px[r];
    if (n < 3.0) continue;
    for (std::size_t r = 0; r < e.distance_px.size(); ++r)
      if (std::isfinite(e.distance_px[r]) && std::isfinite(e.normal_velocity_px[r]))
        centred.emplace_back(e.normal_velocity_px[r] - sw / n, e.distance_px[r] - sd / n);
  }
  SubframeOffset out;
  double sww = 0.0, swd = 0.0, sdd = 0.0;
  for (const auto& [w, d] : centred) sww += w * w, swd += w * d, sdd += d * d;
  const auto n = static_cast<double>(centred.size());
  if (!(sww > 0.0) || n < 3.0) return out;
  out.rows = swd / sww;
  const double rss = std::max(sdd - out.rows * swd, 0.0);
  out.se_rows = std::sqrt(rss / (n - 1.0) / sww);
  out.rms_before_px = std::sqrt(sdd / n);
  out.rms_after_px = std::sqrt(rss / n);
  return out;
}

std::vector<EpipolarSeries> epipolar_series(const std::vector<calibration::Camera>& cameras,
                                            const Eigen::MatrixXd& uv_px, int n_points) {
  const int n_cameras = static_cast<int>(cameras.size());
  if (n_points < 0 || uv_px.cols() != 2 * static_cast<Eigen::Index>(n_points) * n_cameras)
    throw Error(fmt::format("epipolar_series: the 2-D tracks have {} columns; {} points in {} cameras need {}",
                            uv_px.cols(), n_points, n_cameras, 2 * n_points * n_cameras));
  std::vector<EpipolarSeries> series;
  if (n_cameras < 2) return series;
  for (int p = 0; p < n_points; ++p)
    series.push_back(epipolar_distance(cameras[0], cameras[1], uv_px, n_points, n_cameras, p));
  return series;
}

SubframeOffset subframe_offset(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                               int n_points) {
  return subframe_offset(epipolar_series(cameras, uv_px, n_points));
}

Eigen::MatrixXd resample_camera(const Eigen::MatrixXd& uv_px, int n_points, int n_cameras, int camera,
                                double late_rows) {
  if (n_points < 0 || camera < 0 || camera >= n_cameras ||
      uv_px.cols() != 2 * static_cast<Eigen::Index>(n_points) * n_cameras)
    throw Error(fmt::format("resample_camera: camera {} of {} in {} columns for {} points", camera, n_cameras,
                            uv_px.cols(), n_points));
  Eigen::MatrixXd out = uv_px;
  const Eigen::Index rows = uv_px.rows();
  for (int p = 0; p < n_points; ++p) {
    const Eigen::Index c = 2 * (static_cast<Eigen::Index>(p) * n_cameras + camera);
    for (Eigen::Index k = 0; k < rows; ++k) {
      const double x = static_cast<double>(k) - late_rows;
      const auto i0 = static_cast<Eigen::Index>(std::floor(x));
      const double f = x - static_cast<double>(i0);
      Eigen::Vector2d v = Eigen::Vector2d::Constant(std::numeric_limits<double>::quiet_NaN());
      if (i0 >= 0 && i0 < rows && f == 0.0)
        v = uv_px.block<1, 2>(i0, c).transpose();
      else if (i0 >= 0 && i0 + 1 < rows)
        v = (1.0 - f) * uv_px.block<1, 2>(i0, c).transpose() + f * uv_px.block<1, 2>(i0 + 1, c).transpose();
      out.block<1, 2>(k, c) = v.transpose();
    }
  }
  return out;
}

std::vector<MarkerSlip> marker_slips(const std::vector<calibration::Camera>& cameras, const Eigen::MatrixXd& uv_px,
                                     int n_points) {
  return marker_slips(epipolar_series(cameras, uv_px, n_points));
}

std::vector<MarkerSlip> marker_slips(const std::vector<EpipolarSeries>& series) {
  std::vector<MarkerSlip> out;
  if (!rays_meet(series)) return out;
  const double offset = subframe_offset(series).rows;
  for (int p = 0; p < static_cast<int>(series.size()); ++p) {
    // The distance less what the cameras' sub-frame offset moves it by.
    std::vector<double> d = series[static_cast<std::size_t>(p)].distance_px;
    const std::vector<double>& w = series[static_cast<std::size_t>(p)].normal_velocity_px;
    const int rows = static_cast<int>(d.size());
    for (std::size_t r = 0; r < d.size(); ++r) d[r] -= offset * (std::isfinite(w[r]) ? w[r] : 0.0);
    const double sigma = second_difference_noise(d);
    if (!(sigma > 0.0)) continue;
    // The step at every row boundary (between row i - 1 and row i), in SEs.
    std::vector<double> z(static_cast<std::size_t>(rows), 0.0);
    for (int i = 1; i < rows; ++i) {
      double l = 0.0, vl = 0.0, r = 0.0, vr = 0.0;
      if (line_at(d, i - kSlipEdgeRows, i, i - 0.5, &l, &vl) && line_at(d, i, i + kSlipEdgeRows, i - 0.5, &r, &vr))
        z[static_cast<std::size_t>(i)] = (r - l) / (sigma * std::sqrt(vl + vr));
    }
    // Edges: the largest |z| of each run beyond the threshold of one sign.
    std::vector<int> edges;
    for (int i = 1; i < rows; ++i) {
      const double zi = z[static_cast<std::size_t>(i)];
      if (!(std::abs(zi) >= kSlipEdgeZ)) continue;
      if (!edges.empty() && i - edges.back() < kSlipEdgeRows &&
          std::signbit(z[static_cast<std::size_t>(edges.back())]) == std::signbit(zi)) {
        if (std::abs(zi) > std::abs(z[static_cast<std::size_t>(edges.back())])) edges.back() = i;
        continue;
      }
      edges.push_back(i);
    }
    // A stretch starts at an edge and ends at a later edge of the other
    // sign; of the ends that pass, the one whose stretch departs most.
    for (std::size_t a = 0; a < edges.size(); ++a) {
      const int start = edges[a];
      const bool up = z[static_cast<std::size_t>(start)] > 0.0;
      MarkerSlip best;
      std::size_t best_b = 0;
      for (std::size_t b = a + 1; b < edges.size() && edges[b] - start <= kMaxSlipRows; ++b) {
        const int end = edges[b];
        if ((z[static_cast<std::size_t>(end)] > 0.0) == up || end - start < kMinSlipRows) continue;
        MarkerSlip slip;
        slip.point = p;
        if (stretch_step(d, start, end - 1, sigma, &slip) && std::abs(slip.z) >= kSlipMeanZ &&
            (slip.step_px > 0.0) == up && std::abs(slip.z) > std::abs(best.z)) {
          best = slip;
          best_b = b;
        }
      }
      if (best_b == 0) continue;
      out.push_back(best);
      a = best_b;
    }
  }
  return out;
}

}  // namespace dropfit::reconstruction
