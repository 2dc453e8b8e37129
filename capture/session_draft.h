#pragma once
// A session.toml draft from what a lab's folder holds (`dropfit init`):
// DLTdv or Argus marker tables (*xypts.csv, with DLTdv's *offsets.csv) or
// markers.c3d, one trial per folder; DLT coefficients from easyWand, Argus
// or DLTdv (*dltCoefs.csv, *dlt-coefs.csv, dlt_coefs.csv) or a calibration
// frame; force exports (Kistler text, BioWare text, C3D) found by content.
// Camera and point names come from the marker tables' headers, the plate's
// rate, plate count and geometry from the force exports.
//
// What the files cannot tell (the drop mass, the mat, the video frame rate,
// the trigger frame, the plate's certificate when no C3D gives it) is
// written as a string value beginning "FILL IN", which the manifest reader
// refuses naming the key and its line, so that no result is ever computed
// from a guess. Values taken from a convention rather than the files (the
// image origin of a DLTdv 8.3 table, the trigger threshold, which points are
// the impactor's) are written with a "# CHECK:" comment. The draft reads
// only; it writes nothing (the command writes the text it returns).
#include <string>
#include <vector>

namespace dropfit::capture {

struct SessionDraft {
  std::string toml;                  // the draft manifest
  std::vector<std::string> trials;   // trial folders found, relative to the folder ('/')
  std::vector<std::string> fill_in;  // keys still to fill in ("impactor.mass_kg", ...)
  std::vector<std::string> check;    // keys set from a convention, to check
  std::vector<std::string> found;    // what was read, one line each (for the terminal)
};

// Throws dropfit::InputError naming the folder when it holds no trial (no
// marker table and no markers.c3d in it or its sub-folders), and naming a
// file when one it must read is malformed.
SessionDraft draft_session(const std::string& folder);

}  // namespace dropfit::capture
