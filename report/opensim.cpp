#include "report/opensim.h"

#include <fmt/format.h>

#include <cmath>

#include "core/error.h"

namespace dropfit::report {

namespace {
std::string number(double v, int significant = 9) {
  if (!std::isfinite(v)) return "NaN";
  return fmt::format("{:.{}g}", v, significant);
}
}  // namespace

std::string markers_trc(const reconstruction::Trajectories& trajectories, const std::vector<std::string>& names,
                        const Eigen::VectorXd& frame_times_s, double frame_rate_hz, const std::string& file_name) {
  const int n_frames = trajectories.n_frames();
  const int n_points = trajectories.n_points();
  if (frame_times_s.size() != n_frames) {
    throw Error(fmt::format("markers.trc: {} frame times for {} frames", frame_times_s.size(), n_frames));
  }
  if (!(frame_rate_hz > 0.0)) throw Error(fmt::format("markers.trc: frame rate {} Hz is not positive", frame_rate_hz));
  auto name = [&](int p) {
    return p < static_cast<int>(names.size()) && !names[p].empty() ? names[p] : fmt::format("pt{}", p + 1);
  };
  const std::string rate = number(frame_rate_hz);
  std::string out = fmt::format("PathFileType\t4\t(X/Y/Z)\t{}\n", file_name);
  out += "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames\n";
  out += fmt::format("{0}\t{0}\t{1}\t{2}\tmm\t{0}\t1\t{1}\n", rate, n_frames, n_points);
  out += "Frame#\tTime";
  for (int p = 0; p < n_points; ++p) out += fmt::format("\t{}\t\t", name(p));
  out += "\n\t";
  for (int p = 0; p < n_points; ++p) out += fmt::format("\tX{0}\tY{0}\tZ{0}", p + 1);
  out += '\n';
  for (int f = 0; f < n_frames; ++f) {
    out += fmt::format("{}\t{}", f + 1, number(frame_times_s[f], 12));
    for (int p = 0; p < n_points; ++p) {
      const Eigen::Vector3d mm = opensim_from_lab(trajectories.point(f, p)) * 1e3;
      out += fmt::format("\t{}\t{}\t{}", number(mm.x()), number(mm.y()), number(mm.z()));
    }
    out += '\n';
  }
  return out;
}

GroundReaction ground_reaction(const forceplate::Resultants& plate, Eigen::Index i) {
  GroundReaction g;
  g.force_n = plate.f_n.row(i).transpose();
  const double ax = plate.cop_m.rows() > i ? plate.cop_m(i, 0) : NAN;
  const double ay = plate.cop_m.rows() > i ? plate.cop_m(i, 1) : NAN;
  if (!plate.cop_unavailable.empty()) {
    // No centre of pressure in this record at all (an export without
    // moments): NaN, never the plate centre, where the force is applied.
    g.point_m.setConstant(NAN);
    g.torque_n_m.setConstant(NAN);
  } else if (std::isfinite(ax) && std::isfinite(ay)) {
    g.point_m = {ax, ay, 0.0};
    const double tz = plate.m_n_m(i, 2) - ax * plate.f_n(i, 1) + ay * plate.f_n(i, 0);
    g.torque_n_m = {0.0, 0.0, tz};
  } else {
    g.point_m.setZero();
    g.torque_n_m.setZero();
  }
  return g;
}

std::string grf_mot(const forceplate::ForceTrial& force, const std::string& file_name) {
  const auto& plate = force.plate;
  const Eigen::Index n = plate.t_s.size();
  const char* labels[] = {"time",
                          "ground_force_vx", "ground_force_vy", "ground_force_vz",
                          "ground_force_px", "ground_force_py", "ground_force_pz",
                          "ground_torque_x", "ground_torque_y", "ground_torque_z"};
  std::string out = fmt::format("{}\nversion=1\nnRows={}\nnColumns=10\ninDegrees=no\nendheader\n", file_name, n);
  for (int c = 0; c < 10; ++c) out += fmt::format("{}{}", c ? "\t" : "", labels[c]);
  out += '\n';
  for (Eigen::Index i = 0; i < n; ++i) {
    const GroundReaction g = ground_reaction(plate, i);
    const Eigen::Vector3d f = opensim_from_lab(g.force_n);
    const Eigen::Vector3d p = opensim_from_lab(g.point_m);
    const Eigen::Vector3d t = opensim_from_lab(g.torque_n_m);
    out += fmt::format("{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\n", number(plate.t_s[i], 12), number(f.x()),
                       number(f.y()), number(f.z()), number(p.x()), number(p.y()), number(p.z()), number(t.x()),
                       number(t.y()), number(t.z()));
  }
  return out;
}

}  // namespace dropfit::report
