#pragma once
// Readers and writers of the session format (docs/formats.md).
// Every reader checks what it reads and throws dropfit::InputError naming
// the file, line, column and field on anything malformed or missing.
// Writers produce exactly what the readers accept (the sample generator
// uses them); they write each file whole (temporary name, then rename).
//
// Conventions shared by all readers:
// - Lines and columns are 1-based. In CSV and tab-separated files the column
//   is the character position where the offending field starts; in
//   session.toml it is the position of the key or value (from toml++).
//   Line 0 means the file as a whole.
// - Numbers are parsed strictly (std::from_chars on the whole field, blanks
//   around it allowed): "1.2x", "1,2" or an empty field where a number is
//   required is an error. Infinite values are always errors.
// - Nothing is ever written by a reader.
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/session.h"

namespace dropfit::capture {

// session.toml. Unknown keys are an error naming the key (dotted, e.g.
// "mat.layers[1].thickness_m", array indices 0-based) and its line.
// Required: impactor.{mass_kg, footprint_m, base_markers},
//   mat.{length_m, width_m, surface_markers, layers (at least one; each with
//   name, thickness_m, mass_kg)}, video.{cameras, frame_rate_hz, points,
//   trigger_frame}, forceplate.{sample_rate_hz, trigger_threshold_n,
//   a_m, b_m, az0_m, mat_top_z_m}, and at least one
//   [[trial]] with id and dir.
// Optional (default): session.name (""), session.gravity_m_s2 (9.81),
//   impactor.base_marker_height_m (0), forceplate.model (""),
//   forceplate.pretrigger_fraction (absent: exports without a trigger are
//   aligned by their own data), forceplate.plate
//   (1: the plate of a several-plate BioWare or C3D export, an integer >= 1),
//   video.image_origin ("top-left"), video.image_height_px (required with
//   "bottom-left").
// Checked: masses, lengths, thicknesses, rates, gravity, footprint, trigger
//   threshold, a_m, b_m and image_height_px positive (layer masses may be
//   zero); pretrigger_fraction in [0, 1); trigger_frame an integer >= 0;
//   cameras and points non-empty lists of unique non-empty names (cameras
//   also name files, so no '/' or '\\'); base_markers (non-empty) and
//   surface_markers are names in video.points; trial ids unique and non-empty,
//   dirs non-empty, relative and each trial's own (two trials reading one
//   folder are one drop counted twice).
// Physical ranges (a typo or a unit slip otherwise flows into every result;
//   the error names the field, its line and the range): gravity 9.70-9.90
//   m/s^2, impactor mass 1-200 kg, layer thickness 0.001-2 m and mass
//   0-500 kg, mat length and width 0.05-20 m, frame rate 20 Hz-1 MHz, force
//   sample rate 100 Hz-1 MHz, a_m and b_m 0.01-2 m, az0_m +-0.5 m,
//   mat_top_z_m 0-3 m, trigger threshold 0.1-5000 N. A value outside on
//   purpose is accepted when [session] outside_physical_range lists its
//   dotted name (e.g. ["session.gravity_m_s2"]).
// Optional: forceplate.lowpass_hz and lowpass_order (2): the charge
//   amplifier's Butterworth low-pass, when the lab set one.
// Several key/values on one line separated by ';', as the spec's own
// example writes its layers (`name = "carpet";  thickness_m = 0.005;
// mass_kg = 0.0`), are accepted although TOML is not: before parsing, such
// a line is split at its ';' into one line per key/value. Since ';' is
// never valid TOML outside strings and comments, no valid file changes
// meaning. A line is split only when that is unambiguous: it does not start
// inside a multi-line string or array, its ';' are outside strings,
// comments and brackets (a ';' inside an inline array or table is left for
// the parser to reject), and every piece reads `key = ...` (a trailing ';',
// optionally followed by a comment, is allowed). Otherwise the line is
// parsed as written and the parser's error names it. Either way every
// error names the file's own line, and the column within that line
// (counted in characters, as toml++ does).
Manifest read_manifest(const std::string& path);

// Why a trial id or folder cannot be used, or "" when it can. The id names
// the trial's output folder (trials/ID/ in the results), so it must be a
// plain file name: at most 128 characters, no control characters (NUL
// included), no '/' or '\\', not "." or "..". The folder is relative to the
// session and stays inside it: no ".." component that leaves it, no control
// characters, at most 1024 characters. read_manifest applies both;
// read_session also refuses a trial folder that resolves (through symbolic
// links) outside the session folder.
std::string trial_id_problem(std::string_view id);
std::string trial_dir_problem(std::string_view dir);

// calibration/frame.csv: header id,x_m,y_m,z_m,role (any order, no other
// columns), ids unique and non-empty, role "fit" or "check", at least one
// row and at most 500 (the 501st is refused at its line: the calibration's
// leave-one-out refits grow as N^2.5); coordinates within +-1e4 m.
std::vector<CalibrationMarker> read_frame_csv(const std::string& path);
// calibration/<camera>.csv: header id,u_px,v_px (any order). Checks every id
// against `frame` (an id not in frame.csv is an error naming it) and rejects
// duplicate ids. A camera may see any subset of the markers.
CalibrationImage read_camera_csv(const std::string& path, const std::string& camera,
                                 const std::vector<CalibrationMarker>& frame);

// [calibration] dlt_coefficients: 11 rows (L1..L11) of comma- or
// tab-separated numbers, one column per camera in video.cameras order, as
// easyWand (*_dltCoefs.csv), Argus (*-dlt-coefs.csv) and DLTdv write them; a
// first line whose first field is not a number is a header and skipped.
// The coefficients are in video.image_origin; bottom-left ones are converted
// to top-left (dlt_from_bottom_left). Errors name the row (field "L<k> of
// <camera>"); a camera whose L1..L3 or L5..L7 are all zero is refused.
std::vector<DltCoefficients> read_dlt_coefficients(const std::string& path, const VideoSpec& video);
// The DLT of the same camera for image coordinates v' = image_height_px - v
// (bottom-left <-> top-left; the map is its own inverse): L5..L8 become
// H L9 - L5, H L10 - L6, H L11 - L7, H - L8.
DltCoefficients dlt_from_bottom_left(const DltCoefficients& coefficients, double image_height_px);

// The marker table of a trial folder: <dir>/xypts.csv when it exists, else
// the one file whose name ends in "xypts.csv" (DLTdv and Argus prefix it
// with the trial's name, e.g. trial1xypts.csv, trial1-xypts.csv). Two or
// more such files: an InputError naming two of them. None: <dir>/xypts.csv
// (whose reading then reports it missing).
std::string find_xypts(const std::string& trial_dir);
// DLTdv's offsets file beside a marker table: its path with the trailing
// "xypts.csv" replaced by "offsets.csv".
std::string offsets_path(const std::string& xypts_path);
// offsets.csv as DLTdv writes it: a header (cam1_offset,cam2_offset,...),
// then one row per frame and one column per camera, whole frames printed
// %.6f ("-3.000000"); the offsets may change along the trial. The contract's
// short form, one row per camera with one field each (more than one camera),
// is read as constant offsets. Numbers are parsed as decimals and must be
// whole frames within +-1e6; a header line is optional. DLTdv stores its
// rows already aligned, so the offsets only say which video frame each row
// came from (FrameOffsets in core/session.h).
FrameOffsets read_offsets(const std::string& path, int n_cameras);

// xypts.csv in any of the three layouts, told apart by the header:
//   DLTdv 8.3   ptK_camN_X, ptK_camN_Y   (K 1-based index into video.points)
//   DLTdv 8.4+  NAME_camN_U, NAME_camN_V (NAME from video.points)
//   Argus       NAME_cam_N_x, NAME_cam_N_y
// N is the 1-based index into video.cameras. In the DLTdv 8.4 and Argus
// layouts a NAME that video.points does not list but reads ptK (DLTdv's and
// Argus's default names) is video.points[K-1]. The file is comma-separated,
// or tab-separated when its header line has tabs and no comma. Columns may come in any order;
// one file uses one layout. The result is in the DLTdv column order of
// MarkerTracks2D (points and cameras in manifest order). An empty field or
// NaN (any case) is a missing measurement and stays NaN, never 0.
// A point or camera in the header that the manifest does not name is an
// error; a manifest point (or point/camera pair) absent from the file is
// all-NaN, i.e. never digitised. An X column without its Y (or U/V, x/y) is
// an error. video.trigger_frame must be a row of the file.
//
// Image origin: the result is top-left, v downwards. With
// video.image_origin == BottomLeft the file's v is measured upwards from the
// bottom edge and is converted as v_top = image_height_px - v_file. Both
// systems are continuous coordinates measured from the image's outer edges
// (pixel corners, so the image spans [0, image_height_px] in v either way);
// the flip is exact for that convention. A file whose bottom-left
// coordinates put pixel centres at integers (MATLAB, 1-based) differs by a
// constant offset of at most one pixel, absorbed by the DLT calibration as
// long as the calibration images were digitised the same way.
MarkerTracks2D read_xypts(const std::string& path, const VideoSpec& video);

// force.txt in either layout, told apart by the column header, or force.c3d
// (a path ending in .c3d, any case: read_force_c3d of capture/force_io.h).
// Text files may be UTF-8 or UTF-16 with a byte-order mark.
// - Kistler eight-channel: key<TAB>value header lines ("Sample rate",
//   "Samples", "Pretrigger samples" required; "Device", "Trigger" optional;
//   other keys ignored), a blank line, the column header "Time(s)" then Fx12
//   Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4 in any order (a missing channel is an
//   error naming it; other columns are ignored), then exactly "Samples" data
//   rows. t_s is the file's time column, which must read 0 (within half a
//   sample) at row "Pretrigger samples": the trigger sample.
// - BioWare resultants as they come (read_bioware_export in
//   capture/force_io.h): any subset of Fx Fy Fz Mx My Mz Ax Ay that has Fz
//   (no Fz: refused), several plates as repeated blocks (plate.plate picks
//   one), header lines of any BioWare version. Columns the export lacks are
//   NaN throughout in `data`. The file has no trigger mark, so the trigger
//   sample is taken from the manifest when it gives one,
//   pretrigger_samples = trigger_sample_from_fraction(plate.pretrigger_fraction, n),
//   else found in the record's own data (trigger_sample_from_data with
//   plate.trigger_threshold_n; trigger_from_data set, `trigger` says which
//   sample and how), and t_s[i] = abs_time[i] - abs_time[pretrigger_samples],
//   i.e. t = 0 at the trigger sample as for the eight-channel layout. Ax, Ay may be NaN
//   (centre of pressure undefined while unloaded).
// For all: the sample rate must equal plate.sample_rate_hz (relative 1e-6);
// time steps must be uniform (each step within a quarter sample plus the
// printed time resolution of 1 / rate, and no drift over the record).
ForceRecord read_force(const std::string& path, const ForcePlateSpec& plate);

// The trigger sample of a record that carries none, found in its data as
// the acquisition would have triggered: the first sample at which Fz stands
// more than `threshold_n` above the quiet level before it. A window is quiet
// when its 50 samples lie well below the record's largest Fz and spread no
// more than twice the quietest window's (at least 1 N). When the record
// starts quiet, the level is its first window's median and the trigger the
// first crossing after it (a drop jump's first landing, not its larger
// second one); when it starts loaded or swaying, the level is that of the
// last quiet window before the largest Fz and the trigger the crossing after
// it (quiet before impact). Fz is the record's (eight channels: Fz1 + Fz2 +
// Fz3 + Fz4). nullopt when Fz never rises that far above a quiet level (no
// impact in the record).
struct DataTrigger {
  int sample = 0;            // 0-based
  double quiet_level_n = 0;  // the quiet Fz the crossing is measured from
};
std::optional<DataTrigger> trigger_sample_from_data(const ForceRecord& record, double threshold_n);

// Index of the trigger sample in a record of n samples of which a share
// `pretrigger_fraction` precedes it: round(fraction * n) (halves away from 0).
int trigger_sample_from_fraction(double pretrigger_fraction, int n_samples);

// The whole session folder: session.toml, calibration/frame.csv,
// calibration/<camera>.csv for each manifest camera (images in manifest
// order), and each trial's marker table (find_xypts) and <dir>/force.txt.
// With [calibration] dlt_coefficients the coefficients are read into
// Session::dlt_coefficients and frame.csv is optional (absent: no frame, no
// images); with frame.csv present a camera without its <camera>.csv saw
// none of the markers. DLTdv's offsets.csv beside a marker table is read
// into TrialRecording::frame_offsets (a per-frame file must have the marker
// table's number of rows). A trial folder holding markers.c3d (any case)
// instead of a marker table brings its own 3-D markers (read_markers_c3d for
// [video].points, at video.frame_rate_hz, trigger_frame a frame of it) into
// TrialRecording::markers_xyz_m; a folder with both is refused. When every
// trial has markers.c3d and the session has neither calibration/frame.csv
// nor [calibration] dlt_coefficients, no calibration is read. A trial folder
// resolving outside the session folder is refused. A missing file is an
// InputError naming it. Reads only; never writes.
Session read_session(const std::string& root);
// The calibration part of read_session alone: fills session.frame, .images
// and .dlt_coefficients from the folder `root` for session.manifest.
void read_session_calibration(const std::string& root, Session& session);

// Writers (top-left origin, DLTdv 8.3 layout unless asked otherwise).
// Formats: metres and other manifest values at full precision (shortest
// round-trip), frame.csv metres %.9g, pixels and forces %.6f, times %.6f s,
// missing pixels "NaN". Failures to write throw dropfit::Error; a writer
// leaves no partial file behind.
enum class XyptsLayout { Dltdv83, Dltdv84, Argus };
void write_manifest(const std::string& path, const Manifest& manifest);
void write_frame_csv(const std::string& path, const std::vector<CalibrationMarker>& frame);
void write_camera_csv(const std::string& path, const CalibrationImage& image);
// BottomLeft writes v_file = image_height_px - v (image_height_px > 0 needed).
void write_xypts(const std::string& path, const MarkerTracks2D& tracks, XyptsLayout layout = XyptsLayout::Dltdv83,
                 ImageOrigin origin = ImageOrigin::TopLeft, double image_height_px = 0.0);
// Eight-channel: the record's t_s as the time column (t_s at
// pretrigger_samples must be 0), `device` on the Device line ("unknown" when
// empty). Resultants: BioWare layout, abs time = t_s - t_s[0], Ax/Ay in mm;
// its trigger sample on reading comes from the manifest (see read_force).
void write_force(const std::string& path, const ForceRecord& record, const std::string& device = "");
// Creates root, calibration/ and each trial folder, then writes every file.
// The xypts origin follows manifest.video.image_origin. Throws
// dropfit::Error if the session is inconsistent (an image missing for a
// manifest camera, trials not matching manifest.trials, tracks' points or
// cameras not those of the manifest, a BioWare record whose
// pretrigger_samples differs from the manifest's fraction).
void write_session(const std::string& root, const Session& session, XyptsLayout layout = XyptsLayout::Dltdv83);

}  // namespace dropfit::capture
