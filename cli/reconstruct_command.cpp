// dropfit reconstruct SESSION --out DIR
// The session state through reconstruction: the calibration stage's camera
// model and every trial's 3-D trajectories with their residuals.
#include <fmt/format.h>

#include "cli/command.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"

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
    pipeline::BuildOptions options;
    options.upto = pipeline::Stage::Reconstruction;
    const pipeline::SessionState state = pipeline::build(args->session, options);
    report::OutputSet out;
    pipeline::add_calibration_outputs(out, state.calibration.after, state.session.manifest.video);
    pipeline::add_reconstruction_outputs(out, state);
    out.commit(args->out, {args->session});
    fmt::print("reconstructed {} trials; wrote {}\n", state.trials.size(), args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(20, add_reconstruct);
}  // namespace dropfit::cli
