#pragma once
// Force-plate files as labs have them (docs/formats.md,
// "trials/TRIAL/force.txt" and "Files as other tools write them"):
// the Kistler eight-channel text export, BioWare text exports as they come,
// and C3D (force and 3-D markers). read_force (capture/io.h) dispatches here;
// these are the lower-level readers, for tests, tools and fuzzing.
#include <Eigen/Core>
#include <array>
#include <string>
#include <vector>

#include "capture/c3d.h"
#include "core/session.h"

namespace dropfit::capture {

// ---------------------------------------------------------------------------
// BioWare text exports
// ---------------------------------------------------------------------------
//
// Free header lines (BioWare Version, Device:, Samples (#):, Rate (Hz):,
// Contact period ..., Normalized force (N), Date, Name, ...), then the
// column header beginning "abs time", then one units line (it may begin
// with a tab), then the data; tab separated; UTF-8 or UTF-16 (LE or BE,
// with a byte-order mark). The columns after the time are any of Fx Fy Fz
// Mx My Mz Ax Ay (other names are ignored); several plates are repeated
// blocks of the same names, plate 1 first: a name seen again starts the
// next plate. Every plate must have the same names. "Rate (Hz):" gives one
// value per column (all must agree); "Samples (#):", when present, must equal
// the number of data rows. Units: forces N, moments N.m (Nm, N m), Ax Ay mm
// or m; converted to SI.
struct BioWareExport {
  std::string version;            // from "BioWare Version X Export", "" when absent
  double sample_rate_hz = 0.0;
  int n_plates = 0;
  std::array<bool, 8> present{};  // Fx Fy Fz Mx My Mz Ax Ay: which the export has
  Eigen::VectorXd abs_time_s;     // the file's time column
  // One n x 8 matrix per plate: Fx Fy Fz (N) Mx My Mz (N m) Ax Ay (m);
  // columns the export does not have are NaN throughout; Ax Ay may be NaN
  // (or empty) where the plate is unloaded.
  std::vector<Eigen::MatrixXd> plates;
};
BioWareExport read_bioware_export(const std::string& path);

// ---------------------------------------------------------------------------
// C3D
// ---------------------------------------------------------------------------
//
// FORCE_PLATFORM: USED, TYPE, CHANNEL (1-based analog channels), ORIGIN.
// TYPE 3 (Kistler): CHANNEL gives Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4; the
//   record is EightChannel and ORIGIN gives a, b, az0 (in POINT:UNITS, mm
//   when absent) as plate_geometry_m = (|a|, |b|, -|az0|): the sensor plane
//   is below the top surface whatever sign a writer stores (BioWare stores
//   +58 mm for az0 = -0.058 m).
// TYPE 2: CHANNEL gives Fx Fy Fz Mx My Mz about the transducer origin, at
//   -ORIGIN from the top surface's centre (ORIGIN: the vector from the
//   transducer origin to that centre); the record is Resultants with the
//   moments moved to the point under the centre at the transducer's depth
//   (with (ox, oy) = -ORIGIN x, y: Mx += oy Fz, My -= ox Fz, Mz += ox Fy - oy Fx),
//   Ax Ay NaN (the centre of pressure is computed from the moments with az0 =
//   -|ORIGIN z|, in plate_geometry_m with a, b NaN).
// Other types are refused naming FORCE_PLATFORM:TYPE. Counts become
// physical units with ANALOG:OFFSET, SCALE and GEN_SCALE; ANALOG:UNITS, when
// given, must be N (or kN) for forces and N.m or N.mm for moments.
// `plate.plate` (1-based) picks the plate. The analog rate must equal
// plate.sample_rate_hz (relative 1e-6). The C3D has no trigger mark: as for
// BioWare, the trigger sample comes from plate.pretrigger_fraction when
// given, else from the record's data (trigger_sample_from_data in
// capture/io.h), and t_s = 0 at that sample.
ForceRecord force_record_from_c3d(const C3dFile& file, const ForcePlateSpec& plate);
ForceRecord read_force_c3d(const std::string& path, const ForcePlateSpec& plate);

// 3-D marker trajectories from a C3D's POINT group.
struct MarkerTrajectories {
  std::vector<std::string> points;  // as asked, in that order
  double frame_rate_hz = 0.0;
  int first_frame = 1;              // the file's first frame number (1-based)
  // n_frames x (3 n_points): X Y Z of point p in columns 3p..3p+2, metres
  // (POINT:UNITS mm or m; mm when absent); NaN where the point is invalid.
  Eigen::MatrixXd xyz_m;
};
// `points`: the labels wanted (e.g. [video].points), matched against
// POINT:LABELS (case-insensitive, blanks trimmed). A label not in the file,
// or in it twice, is an error naming POINT:LABELS.
MarkerTrajectories markers_from_c3d(const C3dFile& file, const std::vector<std::string>& points);
MarkerTrajectories read_markers_c3d(const std::string& path, const std::vector<std::string>& points);

// What a file holds, judged from its first 64 KiB: a C3D with analog data
// (the key byte 0x50 and a non-zero analog count), a Kistler eight-channel
// text export (a column header "Time(s)"), a BioWare text export (a column
// header beginning "abs time"; UTF-16 too), or none of them.
enum class ForceFileKind { None, C3d, KistlerText, BioWareText };
ForceFileKind force_file_kind(const std::string& path);

// The force file of a trial folder: force.txt or force.c3d (the extension in
// any case, e.g. force.C3D); else the one .txt, .tsv or .c3d file (any case)
// whose content is a force export (force_file_kind), as BioWare names them
// (kistler_DJ_2plates.txt, trial3.C3D); else <dir>/force.txt (reported
// missing when read). Two contract names, or no contract name and two force
// exports: an InputError naming both (which one is meant is not known).
std::string find_force_file(const std::string& trial_dir);

}  // namespace dropfit::capture
