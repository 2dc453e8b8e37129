// One trial's markers tracked in the footage (pipeline/track.h).
#include "pipeline/track.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>

#include "capture/footage.h"
#include "capture/io.h"
#include "core/atomic_file.h"
#include "core/error.h"
#include "pipeline/wiring.h"

namespace dropfit::pipeline {

namespace {

namespace fs = std::filesystem;

// The request against the manifest: the trial and cameras exist, each camera
// once, one footage and one seed file per camera (or one lab seed file).
void check_request(const TrackRequest& r, const Manifest& manifest, const std::string& manifest_path) {
  if (std::none_of(manifest.trials.begin(), manifest.trials.end(), [&](const TrialSpec& t) { return t.id == r.trial; }))
    throw InputError(manifest_path, 0, 0, "trial", fmt::format("no trial '{}' in the manifest", r.trial));
  const std::size_t n = r.cameras.size();
  if (r.frames.size() != n)
    throw Error(fmt::format("track: {} --camera but {} --frames; give one --frames per camera", n, r.frames.size()));
  if (r.lab_seed_file.empty() == r.seed_files.empty()) throw Error("track: give either --seed (one per camera) or --seed-lab");
  if (!r.seed_files.empty() && r.seed_files.size() != n)
    throw Error(fmt::format("track: {} --camera but {} --seed; give one seed file per camera", n, r.seed_files.size()));
  const auto& cams = manifest.video.cameras;
  for (std::size_t i = 0; i < n; ++i) {
    if (std::find(cams.begin(), cams.end(), r.cameras[i]) == cams.end())
      throw InputError(manifest_path, 0, 0, "video.cameras", fmt::format("no camera '{}' in the manifest", r.cameras[i]));
    for (std::size_t j = 0; j < i; ++j)
      if (r.cameras[j] == r.cameras[i]) throw Error(fmt::format("track: camera '{}' given twice", r.cameras[i]));
  }
}

// The session's cameras as the calibration stage chooses them (the manifest's
// DLT coefficients when it gives them), from the calibration files alone.
std::vector<calibration::Camera> session_cameras(const std::string& session_dir, const Manifest& manifest) {
  Session session;
  session.root = session_dir;
  session.manifest = manifest;
  capture::read_session_calibration(session_dir, session);
  return cameras_of(choose_calibration(session).after);
}

std::vector<capture::Seed> project(const std::vector<capture::LabSeed>& lab, const calibration::Camera& camera,
                                   const std::string& source) {
  std::vector<capture::Seed> seeds;
  for (const auto& s : lab) seeds.push_back({s.point, s.frame, camera.project(s.lab_m), source, s.line});
  return seeds;
}

}  // namespace

TrackOutcome track_trial(const TrackRequest& r, Progress* progress) {
  const std::string manifest_path = (fs::path(r.session_dir) / "session.toml").string();
  const Manifest manifest = capture::read_manifest(manifest_path);
  const auto& video = manifest.video;
  check_request(r, manifest, manifest_path);
  std::vector<capture::LabSeed> lab;
  std::vector<calibration::Camera> cameras;
  if (!r.lab_seed_file.empty()) {
    lab = capture::read_lab_seed_csv(r.lab_seed_file, video.points);
    cameras = session_cameras(r.session_dir, manifest);
  }

  TrackOutcome out;
  out.tracks.points = video.points;
  out.tracks.cameras = video.cameras;
  out.tracks.uv_px.resize(0, 2 * out.tracks.n_points() * out.tracks.n_cameras());
  if (r.merge && fs::exists(r.out)) out.tracks = capture::read_xypts(r.out, video);
  std::vector<int> lengths;
  for (std::size_t i = 0; i < r.cameras.size(); ++i) {
    const std::string& camera = r.cameras[i];
    std::vector<capture::Seed> seeds;
    if (lab.empty()) {
      seeds = capture::read_seed_csv(r.seed_files[i], video.points);
    } else {
      const auto it = std::find_if(cameras.begin(), cameras.end(), [&](const auto& c) { return c.name == camera; });
      if (it == cameras.end())
        throw Error(fmt::format("track: the session's calibration has no camera '{}' to project the lab seeds into",
                                camera));
      seeds = project(lab, *it, r.lab_seed_file);
    }
    capture::FrameSource frames(r.frames[i]);
    // Rows and seed frames are the footage's own frame numbers.
    const capture::TrackingResult result =
        capture::track_footage(frames, camera, video.points, seeds, r.options, progress);
    if (video.image_origin == ImageOrigin::BottomLeft && video.image_height_px &&
        std::abs(*video.image_height_px - result.image_height_px) > 0.5)
      throw InputError(manifest_path, 0, 0, "video.image_height_px",
                       fmt::format("{:g} px, but {}'s frames are {} px high", *video.image_height_px, camera,
                                   result.image_height_px));
    capture::merge_camera_tracks(out.tracks, result.tracks);
    lengths.push_back(result.tracks.n_frames());
    out.lines.push_back(result.report());
    for (const auto& w : result.warnings) out.warnings.emplace_back(camera, w);
  }
  for (std::size_t i = 1; i < lengths.size(); ++i)
    if (lengths[i] != lengths[0])
      out.lines.push_back(fmt::format("note: {} has {} frames, {} has {}; the shorter camera's last rows are NaN\n",
                                      r.cameras[0], lengths[0], r.cameras[i], lengths[i]));
  return out;
}

std::vector<std::string> write_track_outcome(const TrackRequest& r, const TrackOutcome& outcome) {
  const Manifest manifest = capture::read_manifest((fs::path(r.session_dir) / "session.toml").string());
  const auto& video = manifest.video;
  std::vector<std::string> lines;
  capture::write_xypts(r.out, outcome.tracks, capture::XyptsLayout::Dltdv83, video.image_origin,
                       video.image_height_px.value_or(0.0));
  lines.push_back(fmt::format("wrote {} ({} frames)\n", r.out, outcome.tracks.n_frames()));
  if (!r.warnings_out.empty()) {
    std::string text = "camera,point,first_frame,last_frame,reason\n";
    for (const auto& [camera, w] : outcome.warnings)
      text += fmt::format("{},{},{},{},\"{}\"\n", camera, w.point, w.frame, w.last_frame, w.reason);
    const fs::path folder = fs::path(r.warnings_out).parent_path();
    if (!folder.empty() && !fs::is_directory(folder))
      throw Error(fmt::format("cannot write {}: no folder {}", r.warnings_out, folder.string()));
    write_file_atomic(r.warnings_out, text);
    lines.push_back(fmt::format("wrote {} ({} warnings)\n", r.warnings_out, outcome.warnings.size()));
  }
  return lines;
}

}  // namespace dropfit::pipeline
