#pragma once
// Readers and writers of the session format (shared/spec/session-format.md).
// Every reader checks what it reads and throws dropfit::InputError naming
// the file, line, column and field on anything malformed or missing.
// Writers produce exactly what the readers accept (the sample generator
// uses them); they write each file whole (temporary name, then rename).
#include <string>

#include "capture/session.h"

namespace dropfit::capture {

// session.toml. Unknown keys are an error naming the key.
Manifest read_manifest(const std::string& path);

std::vector<CalibrationMarker> read_frame_csv(const std::string& path);
// Checks every id against `frame` (an id not in frame.csv is an error).
CalibrationImage read_camera_csv(const std::string& path, const std::string& camera,
                                 const std::vector<CalibrationMarker>& frame);

// xypts.csv in any of the three layouts (DLTdv 8.3 ptK_camN_X, DLTdv 8.4+
// NAME_camN_U, Argus NAME_cam_N_x); converted to a top-left origin.
MarkerTracks2D read_xypts(const std::string& path, const VideoSpec& video);

// force.txt in either layout (Kistler eight-channel or BioWare resultants).
ForceRecord read_force(const std::string& path, const ForcePlateSpec& plate);

// The whole session folder: manifest, calibration, every trial.
Session read_session(const std::string& root);

// Writers (top-left origin, DLTdv 8.3 layout unless asked otherwise).
enum class XyptsLayout { Dltdv83, Dltdv84, Argus };
void write_manifest(const std::string& path, const Manifest& manifest);
void write_frame_csv(const std::string& path, const std::vector<CalibrationMarker>& frame);
void write_camera_csv(const std::string& path, const CalibrationImage& image);
void write_xypts(const std::string& path, const MarkerTracks2D& tracks, XyptsLayout layout = XyptsLayout::Dltdv83,
                 ImageOrigin origin = ImageOrigin::TopLeft, double image_height_px = 0.0);
void write_force(const std::string& path, const ForceRecord& record);
void write_session(const std::string& root, const Session& session);

}  // namespace dropfit::capture
