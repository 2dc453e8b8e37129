#pragma once
// `dropfit track`: one trial's markers found in each camera's footage and
// written as the trial's xypts.csv (DLTdv layout, all the manifest's
// cameras; cameras not tracked in this run are NaN).
//
// A sequence's frames are numbered by their file names (frame_00399.png is
// frame and row 399; rows before the first file are NaN), and seed frames
// use those numbers. Seeds: one pixel seed file per camera, or one lab seed
// file for all cameras (capture/tracking.h), projected into each camera
// through the session's calibration as the pipeline chooses it (the
// calibration stage's camera model, or the manifest's DLT coefficients), so
// tracking reads only the manifest and the calibration files: the trial's
// own marker table need not exist yet.
//
// Merging cameras: track every camera in one request, or one camera per
// request with `merge`, which reads the existing `out` file and replaces only
// the tracked cameras' columns (the file keeps the longer of the lengths).
//
// Linked into dropfit-track only (it reads footage through OpenCV's video
// stack, which the main executable does not load).
#include <string>
#include <utility>
#include <vector>

#include "capture/session.h"
#include "capture/tracking.h"
#include "core/progress.h"

namespace dropfit::pipeline {

struct TrackRequest {
  std::string session_dir;
  std::string trial;
  std::vector<std::string> cameras, frames;  // one footage (folder of frames or video file) per camera
  std::vector<std::string> seed_files;       // one pixel seed file per camera, or
  std::string lab_seed_file;                 // one lab seed file for all
  std::string out;                           // xypts.csv to write
  std::string warnings_out;                  // optional: the warnings as CSV
  bool merge = false;
  capture::TrackingOptions options;
};

struct TrackOutcome {
  MarkerTracks2D tracks;  // every manifest camera; the untracked ones NaN (or as merged)
  std::vector<std::pair<std::string, capture::TrackWarning>> warnings;  // camera, warning
  std::vector<std::string> lines;  // each camera's report and notes, for the terminal
};

// Reads the manifest (and the calibration for lab seeds), checks the request
// against it (the trial and cameras exist, one footage and seed per camera,
// a bottom-left image height that matches the frames), tracks each camera.
// Throws dropfit::InputError / Error naming the file and field; writes
// nothing.
TrackOutcome track_trial(const TrackRequest& request, Progress* progress = nullptr);

// Writes request.out (and request.warnings_out when set), each whole or not
// at all. Returns the lines saying what was written.
std::vector<std::string> write_track_outcome(const TrackRequest& request, const TrackOutcome& outcome);

}  // namespace dropfit::pipeline
