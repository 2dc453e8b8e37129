// dropfit reconstruct SESSION --out DIR
#include <fmt/format.h>

#include "capture/io.h"
#include "cli/command.h"
#include "cli/pipeline.h"

namespace dropfit::cli {
namespace {

void add_reconstruct(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string session;
    std::string out;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("reconstruct", "3-D marker trajectories of every trial, with residuals");
  sub->add_option("session", args->session, "session folder")->required()->check(CLI::ExistingDirectory);
  sub->add_option("--out", args->out, "output folder")->required();
  sub->callback([args] {
    const Session session = capture::read_session(args->session);
    // The calibration stage's chosen camera model (distortion included):
    // every point is undistorted with it before triangulation.
    const auto calibration = pipeline::calibrate_session(session);
    const auto cameras = pipeline::cameras_of(calibration);

    report::OutputSet out;
    pipeline::add_calibration_outputs(out, calibration, session.manifest.video);
    for (const auto& trial : session.trials) {
      const auto trajectories = reconstruction::reconstruct(cameras, trial.tracks.uv_px, trial.tracks.n_points());
      pipeline::add_reconstruction_outputs(out, trial.spec.id, trajectories, session.manifest.video.points);
    }
    out.commit(args->out, {args->session});
    fmt::print("reconstructed {} trials; wrote {}\n", session.trials.size(), args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(20, add_reconstruct);
}  // namespace dropfit::cli
