#pragma once
// Files that drive musculoskeletal models in OpenSim (results-format.md,
// "Version 2 additions"): the markers as a TRC file and the plate's ground
// reaction as an ExternalLoads .mot file.
//
// Frames. dropfit's lab frame has Z up (session-format.md); OpenSim's
// ground has Y up. Both files are written in OpenSim's frame:
//
//   x_opensim = X_lab,  y_opensim = Z_lab,  z_opensim = -Y_lab
//
// (a rotation of -90 degrees about lab X; right-handed either way).
//
// Formats, from their public descriptions:
// - TRC (Motion Analysis "Track Row Column", as OpenSim's TRCFileAdapter
//   reads it): tab separated; line 1 `PathFileType 4 (X/Y/Z) NAME`; line 2
//   the keys DataRate CameraRate NumFrames NumMarkers Units OrigDataRate
//   OrigDataStartFrame OrigNumFrames; line 3 their values; line 4
//   `Frame# Time NAME1 (two empty cells) NAME2 ...`; line 5 the component
//   labels `X1 Y1 Z1 X2 ...` after two empty cells; data from line 6, one row
//   per frame (Frame# from 1, Time in s). Units "mm". Gaps are written as
//   NaN (OpenSim reads them as missing markers).
// - .mot (OpenSim Storage): a header of `NAME`, `version=1`, `nRows=N`,
//   `nColumns=C` (time included), `inDegrees=no`, `endheader`, then a tab
//   separated column-label line and the data. ExternalLoads columns, one
//   force: ground_force_vx/vy/vz (N), ground_force_px/py/pz (m, the point of
//   application: the centre of pressure on the plate's top surface),
//   ground_torque_x/y/z (N m, the free moment about that point).
#include <string>
#include <vector>

#include <Eigen/Core>

#include "forceplate/forceplate.h"
#include "reconstruction/reconstruction.h"

namespace dropfit::report {

// lab (Z up) -> OpenSim ground (Y up).
inline Eigen::Vector3d opensim_from_lab(const Eigen::Vector3d& lab) { return {lab.x(), lab.z(), -lab.y()}; }

// markers.trc: every frame of `trajectories`, named `names` (ptK when a name
// is missing), frame i at time frame_times_s[i] (the force clock), positions
// in millimetres in OpenSim's frame. Throws dropfit::Error when the lengths
// disagree or frame_rate_hz is not positive.
std::string markers_trc(const reconstruction::Trajectories& trajectories, const std::vector<std::string>& names,
                        const Eigen::VectorXd& frame_times_s, double frame_rate_hz,
                        const std::string& file_name = "markers.trc");

// The ground reaction of one plate sample in the lab frame, as OpenSim's
// ExternalLoads takes it: the force on what stands on the plate, its point
// of application (the centre of pressure on the top surface, z = 0) and the
// free moment about the vertical through it. Plate axes x, y are lab X, Y
// (the convention of this project: forceplate.h, samples/generator); Fz is
// positive upward on the load. The free moment is Tz = Mz - ax Fy + ay Fx.
// Where the COP is undefined because the plate is unloaded (|Fz| below the
// plate's threshold), the point is the plate centre (0, 0, 0) and the torque
// 0, as gait tools write it: the force there is near zero. A record with no
// centre of pressure at all (plate.cop_unavailable: an export without
// moments) gives NaN point and torque for every sample, never the plate
// centre: the force's point of application is not known.
struct GroundReaction {
  Eigen::Vector3d force_n, point_m, torque_n_m;
};
GroundReaction ground_reaction(const forceplate::Resultants& plate, Eigen::Index sample);

// grf.mot: every sample of the processed (zeroed) plate record on the force
// clock, in OpenSim's frame; ground_force_p* and ground_torque_* NaN
// throughout when the record has no centre of pressure (trial.json and the
// report say why).
std::string grf_mot(const forceplate::ForceTrial& force, const std::string& file_name = "grf.mot");

}  // namespace dropfit::report
