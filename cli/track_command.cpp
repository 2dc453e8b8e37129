// dropfit track SESSION --trial T --camera cam1 --frames DIR --seed SEED.csv
//                       [--camera cam2 --frames DIR2 --seed SEED2.csv ...] --out xypts.csv
//
// Finds the markers in each camera's footage and writes the trial's
// xypts.csv: pipeline/track.h says how (frame numbering, merging cameras,
// lab seeds projected through the session's calibration); the seed files'
// formats are capture/tracking.h's.
#include <fmt/format.h>

#include <memory>

#include "cli/command.h"
#include "core/progress.h"
#include "pipeline/track.h"

namespace dropfit::cli {
namespace {

void add_track(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    pipeline::TrackRequest request;
    std::string motion = "velocity";
  };
  auto args = std::make_shared<Args>();
  pipeline::TrackRequest& r = args->request;
  auto* sub = app.add_subcommand("track", "find the markers in the video frames and write the trial's xypts.csv");
  sub->add_option("session", r.session_dir, "session folder (its session.toml names the points and cameras)")
      ->required();
  sub->add_option("--trial", r.trial, "trial id from session.toml")->required();
  sub->add_option("--camera", r.cameras, "camera name (repeat for several cameras)")->required();
  sub->add_option("--frames", r.frames, "that camera's frames: a folder of PNG/TIFF files or a video file")
      ->required();
  sub->add_option("--seed", r.seed_files, "that camera's seed file: point,frame,u_px,v_px");
  sub->add_option("--seed-lab", r.lab_seed_file,
                  "instead of --seed: one file point,frame,x_m,y_m,z_m for all cameras, projected with the "
                  "session's calibration");
  sub->add_option("--out", r.out, "xypts.csv to write")->required();
  sub->add_flag("--merge", r.merge, "keep the other cameras' columns of an existing --out file");
  sub->add_option("--warnings", r.warnings_out, "also write the warnings as CSV here");
  sub->add_option("--motion", args->motion, "motion model: velocity or acceleration")
      ->check(CLI::IsMember({"velocity", "acceleration"}));
  sub->add_option("--gate", r.options.gate_px, "search gate around the prediction, px")
      ->check(CLI::PositiveNumber);
  sub->add_option("--seed-radius", r.options.seed_radius_px, "a seed snaps to the marker within this, px")
      ->check(CLI::PositiveNumber);
  sub->add_option("--min-contrast", r.options.detection.min_contrast,
                  "least marker brightness above the background, grey levels")
      ->check(CLI::PositiveNumber);
  sub->add_option("--max-lost", r.options.max_lost_frames, "stop searching after this many frames lost")
      ->check(CLI::NonNegativeNumber);
  sub->callback([args] {
    pipeline::TrackRequest request = args->request;
    request.options.motion = args->motion == "acceleration" ? capture::MotionModel::ConstantAcceleration
                                                            : capture::MotionModel::ConstantVelocity;
    Progress progress;
    const pipeline::TrackOutcome outcome = pipeline::track_trial(request, &progress);
    for (const auto& line : outcome.lines) fmt::print("{}", line);
    for (const auto& line : pipeline::write_track_outcome(request, outcome)) fmt::print("{}", line);
  });
}

}  // namespace
DROPFIT_COMMAND(15, add_track);
}  // namespace dropfit::cli
