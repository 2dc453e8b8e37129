// dropfit track SESSION --trial T --camera cam1 --frames DIR --seed SEED.csv
//                       [--camera cam2 --frames DIR2 --seed SEED2.csv ...] --out xypts.csv
//
// Finds the markers in each camera's footage (a folder of PNG/TIFF frames or
// a video file) and writes the trial's xypts.csv (DLTdv layout, all the
// manifest's cameras; cameras not tracked in this run are NaN). A
// sequence's frames are numbered by their file names (frame_00399.png is
// frame and row 399; rows before the first file are NaN), and seed frames
// use those numbers.
//
// Merging cameras: give every camera in one run (repeat --camera, --frames
// and --seed in the same order), or track one camera per run with --merge,
// which reads the existing --out file and replaces only the tracked
// cameras' columns (the file keeps the longer of the two lengths).
//
// Seeds: --seed gives one seed file per camera (point,frame,u_px,v_px; see
// capture/tracking.h). Alternatively --seed-lab gives one file for all
// cameras with each point's approximate lab position in its first frame
// (point,frame,x_m,y_m,z_m), projected into each camera through a DLT fitted
// to the session's calibration (calibration/frame.csv fit markers and
// calibration/CAMERA.csv, or the manifest's [calibration] dlt_coefficients);
// the seed then snaps to the marker within --seed-radius px of the
// projection.
#include <fmt/format.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>

#include "calibration/calibration.h"
#include "capture/io.h"
#include "capture/footage.h"
#include "capture/tracking.h"
#include "cli/command.h"
#include "core/error.h"
#include "core/progress.h"

namespace dropfit::cli {
namespace {

namespace fs = std::filesystem;

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}

struct LabSeed {
  std::string point;
  int frame = 0;
  Eigen::Vector3d lab_m;
  int line = 0;
};

// point,frame,x_m,y_m,z_m (this column order; blank and '#' lines skipped).
std::vector<LabSeed> read_lab_seeds(const std::string& path, const std::vector<std::string>& points) {
  std::ifstream in(path);
  if (!in) throw InputError(path, 0, 0, "", "cannot open the seed file");
  std::vector<LabSeed> seeds;
  std::string line;
  int line_no = 0;
  bool header = false;
  const std::vector<std::string> names{"point", "frame", "x_m", "y_m", "z_m"};
  while (std::getline(in, line)) {
    ++line_no;
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    std::vector<std::string> fields;
    std::stringstream ss(t);
    for (std::string f; std::getline(ss, f, ',');) fields.push_back(trim(f));
    if (!header) {
      if (fields != names) throw InputError(path, line_no, 0, "", "expected the header point,frame,x_m,y_m,z_m");
      header = true;
      continue;
    }
    if (fields.size() != 5) throw InputError(path, line_no, 0, "", fmt::format("expected 5 fields, found {}", fields.size()));
    LabSeed s;
    s.point = fields[0];
    s.line = line_no;
    if (std::find(points.begin(), points.end(), s.point) == points.end())
      throw InputError(path, line_no, 1, "point", fmt::format("unknown point '{}' (not in [video].points)", s.point));
    double v[4];
    for (int k = 0; k < 4; ++k) {
      try {
        std::size_t used = 0;
        v[k] = std::stod(fields[k + 1], &used);
        if (used != fields[k + 1].size() || !std::isfinite(v[k])) throw std::invalid_argument("");
      } catch (const std::exception&) {
        throw InputError(path, line_no, k + 2, names[k + 1], fmt::format("'{}' is not a number", fields[k + 1]));
      }
    }
    if (v[0] < 0 || v[0] != std::floor(v[0]))
      throw InputError(path, line_no, 2, "frame", fmt::format("'{}' is not a frame number", fields[1]));
    s.frame = static_cast<int>(v[0]);
    s.lab_m = {v[1], v[2], v[3]};
    seeds.push_back(s);
  }
  if (seeds.empty()) throw InputError(path, 0, 0, "", "no seeds in the file");
  return seeds;
}

// The lab seeds projected into one camera through a DLT fitted to the
// session's calibration files.
std::vector<capture::Seed> project_lab_seeds(const std::string& session, const Manifest& manifest,
                                             const std::string& camera, const std::string& lab_path,
                                             const std::vector<LabSeed>& lab) {
  const fs::path root(session);
  calibration::Camera projector;
  if (!manifest.calibration.dlt_coefficients.empty()) {
    // A wand calibration: the given coefficients.
    const auto given =
        capture::read_dlt_coefficients((root / manifest.calibration.dlt_coefficients).string(), manifest.video);
    const auto& cams = manifest.video.cameras;
    projector.name = camera;
    projector.dlt = given[std::find(cams.begin(), cams.end(), camera) - cams.begin()];
  } else {
    const auto frame = capture::read_frame_csv((root / "calibration" / "frame.csv").string());
    const auto image = capture::read_camera_csv((root / "calibration" / (camera + ".csv")).string(), camera, frame);
    std::vector<calibration::Correspondence> fit;
    for (const auto& obs : image.observations)
      for (const auto& m : frame)
        if (m.id == obs.id && m.role == MarkerRole::Fit) fit.push_back({m.id, m.lab_m, obs.image_px});
    projector = calibration::fit_dlt(camera, fit).camera;
  }
  std::vector<capture::Seed> seeds;
  for (const auto& s : lab) seeds.push_back({s.point, s.frame, projector.project(s.lab_m), lab_path, s.line});
  return seeds;
}

void write_warnings(const std::string& path, const std::vector<std::pair<std::string, capture::TrackWarning>>& rows) {
  std::string text = "camera,point,first_frame,last_frame,reason\n";
  for (const auto& [camera, w] : rows)
    text += fmt::format("{},{},{},{},\"{}\"\n", camera, w.point, w.frame, w.last_frame, w.reason);
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    out << text;
    if (!out) throw Error(fmt::format("{}: cannot write", path));
  }
  std::error_code ec;
  fs::rename(tmp, path, ec);
  if (ec) throw Error(fmt::format("{}: cannot write: {}", path, ec.message()));
}

void add_track(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string session;
    std::string trial;
    std::vector<std::string> cameras, frames, seeds;
    std::string seed_lab;
    std::string out;
    std::string warnings;
    bool merge = false;
    std::string motion = "velocity";
    capture::TrackingOptions options;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("track", "find the markers in the video frames and write the trial's xypts.csv");
  sub->add_option("session", args->session, "session folder (its session.toml names the points and cameras)")
      ->required();
  sub->add_option("--trial", args->trial, "trial id from session.toml")->required();
  sub->add_option("--camera", args->cameras, "camera name (repeat for several cameras)")->required();
  sub->add_option("--frames", args->frames, "that camera's frames: a folder of PNG/TIFF files or a video file")
      ->required();
  sub->add_option("--seed", args->seeds, "that camera's seed file: point,frame,u_px,v_px");
  sub->add_option("--seed-lab", args->seed_lab,
                  "instead of --seed: one file point,frame,x_m,y_m,z_m for all cameras, projected with the "
                  "session's calibration");
  sub->add_option("--out", args->out, "xypts.csv to write")->required();
  sub->add_flag("--merge", args->merge, "keep the other cameras' columns of an existing --out file");
  sub->add_option("--warnings", args->warnings, "also write the warnings as CSV here");
  sub->add_option("--motion", args->motion, "motion model: velocity or acceleration")
      ->check(CLI::IsMember({"velocity", "acceleration"}));
  sub->add_option("--gate", args->options.gate_px, "search gate around the prediction, px")
      ->check(CLI::PositiveNumber);
  sub->add_option("--seed-radius", args->options.seed_radius_px, "a seed snaps to the marker within this, px")
      ->check(CLI::PositiveNumber);
  sub->add_option("--min-contrast", args->options.detection.min_contrast,
                  "least marker brightness above the background, grey levels")
      ->check(CLI::PositiveNumber);
  sub->add_option("--max-lost", args->options.max_lost_frames, "stop searching after this many frames lost")
      ->check(CLI::NonNegativeNumber);
  sub->callback([args] {
    const std::string manifest_path = (fs::path(args->session) / "session.toml").string();
    const Manifest manifest = capture::read_manifest(manifest_path);
    const auto& video = manifest.video;
    if (std::none_of(manifest.trials.begin(), manifest.trials.end(),
                     [&](const TrialSpec& t) { return t.id == args->trial; }))
      throw InputError(manifest_path, 0, 0, "trial", fmt::format("no trial '{}' in the manifest", args->trial));
    const std::size_t n = args->cameras.size();
    if (args->frames.size() != n)
      throw Error(fmt::format("track: {} --camera but {} --frames; give one --frames per camera", n,
                              args->frames.size()));
    if (args->seed_lab.empty() == args->seeds.empty())
      throw Error("track: give either --seed (one per camera) or --seed-lab");
    if (!args->seeds.empty() && args->seeds.size() != n)
      throw Error(fmt::format("track: {} --camera but {} --seed; give one seed file per camera", n,
                              args->seeds.size()));
    for (std::size_t i = 0; i < n; ++i) {
      if (std::find(video.cameras.begin(), video.cameras.end(), args->cameras[i]) == video.cameras.end())
        throw InputError(manifest_path, 0, 0, "video.cameras",
                         fmt::format("no camera '{}' in the manifest", args->cameras[i]));
      for (std::size_t j = 0; j < i; ++j)
        if (args->cameras[j] == args->cameras[i])
          throw Error(fmt::format("track: camera '{}' given twice", args->cameras[i]));
    }
    capture::TrackingOptions options = args->options;
    options.motion = args->motion == "acceleration" ? capture::MotionModel::ConstantAcceleration
                                                    : capture::MotionModel::ConstantVelocity;
    std::vector<LabSeed> lab;
    if (!args->seed_lab.empty()) lab = read_lab_seeds(args->seed_lab, video.points);

    MarkerTracks2D all;
    all.points = video.points;
    all.cameras = video.cameras;
    all.uv_px.resize(0, 2 * all.n_points() * all.n_cameras());
    if (args->merge && fs::exists(args->out)) all = capture::read_xypts(args->out, video);

    Progress progress;
    std::vector<std::pair<std::string, capture::TrackWarning>> warnings;
    std::vector<int> lengths;
    for (std::size_t i = 0; i < n; ++i) {
      const std::string& camera = args->cameras[i];
      const auto seeds = lab.empty() ? capture::read_seed_csv(args->seeds[i], video.points)
                                     : project_lab_seeds(args->session, manifest, camera, args->seed_lab, lab);
      capture::FrameSource frames(args->frames[i]);
      // Rows and seed frames are the footage's own frame numbers.
      const capture::TrackingResult result =
          capture::track_footage(frames, camera, video.points, seeds, options, &progress);
      if (video.image_origin == ImageOrigin::BottomLeft && video.image_height_px &&
          std::abs(*video.image_height_px - result.image_height_px) > 0.5)
        throw InputError(manifest_path, 0, 0, "video.image_height_px",
                         fmt::format("{:g} px, but {}'s frames are {} px high", *video.image_height_px, camera,
                                     result.image_height_px));
      capture::merge_camera_tracks(all, result.tracks);
      lengths.push_back(result.tracks.n_frames());
      fmt::print("{}", result.report());
      for (const auto& w : result.warnings) warnings.emplace_back(camera, w);
    }
    for (std::size_t i = 1; i < n; ++i)
      if (lengths[i] != lengths[0])
        fmt::print("note: {} has {} frames, {} has {}; the shorter camera's last rows are NaN\n", args->cameras[0],
                   lengths[0], args->cameras[i], lengths[i]);
    capture::write_xypts(args->out, all, capture::XyptsLayout::Dltdv83, video.image_origin,
                         video.image_height_px.value_or(0.0));
    fmt::print("wrote {} ({} frames)\n", args->out, all.n_frames());
    if (!args->warnings.empty()) {
      write_warnings(args->warnings, warnings);
      fmt::print("wrote {} ({} warnings)\n", args->warnings, warnings.size());
    }
  });
}

}  // namespace
DROPFIT_COMMAND(15, add_track);
}  // namespace dropfit::cli
