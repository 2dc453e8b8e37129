// dropfit process SESSION --out DIR
// The session state through the loop (the trial's clock offset is where the
// final mat model places its contact), written as its trial views:
// trials/T/trial.json, series.csv, trajectories, summary.csv.
#include <fmt/format.h>

#include "cli/command.h"
#include "core/error.h"
#include "core/progress.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"

namespace dropfit::cli {
namespace {

void add_process(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string session;
    std::string out;
    double max_tilt_deg = 0.0;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand(
      "process", "synchronise video and force; impact velocity, deformation, tilt, acceptance per trial");
  sub->add_option("session", args->session, "session folder")->required()->check(CLI::ExistingDirectory);
  sub->add_option("--out", args->out, "output folder")->required();
  sub->add_option("--max-tilt", args->max_tilt_deg, "reject trials tilting more than this, degrees")
      ->check(CLI::PositiveNumber);
  sub->callback([args] {
    Progress progress;
    pipeline::BuildOptions options;
    options.max_tilt_deg = args->max_tilt_deg;
    options.models = {fitting::ModelKind::Model4};  // the loop's baseline: all the trial values need
    options.say = [&](const std::string& detail) { progress.update("process", detail); };
    const pipeline::SessionState state = pipeline::build(args->session, options);
    progress.done();
    report::OutputSet out;
    pipeline::add_calibration_outputs(out, state.calibration.after, state.session.manifest.video);
    pipeline::add_trial_outputs(out, state);
    out.commit(args->out, {args->session});
    for (const auto& t : state.trials) {
      const auto& r = t.result;
      fmt::print("{:<10} {:>6.3f} m/s  {:>6.1f} mm  {:>7.0f} N  tilt {:>4.1f} deg  {}\n", r.id, r.impact_velocity_m_s,
                 r.max_deformation_m * 1e3, r.peak_force_n, r.tilt_deg,
                 r.accepted ? "accepted" : "REJECTED: " + r.reject_reason);
    }
    fmt::print("wrote {}\n", args->out);
    // The rejections are written with their reasons; a session with none
    // usable is not a success (as `run`).
    if (!state.trials.empty() && state.accepted() == 0)
      throw dropfit::Error(fmt::format("session {}: no usable trial ({} of {} rejected, reasons in {}/trials/*/trial.json)",
                              args->session, state.trials.size(), state.trials.size(), args->out));
  });
}

}  // namespace
DROPFIT_COMMAND(30, add_process);
}  // namespace dropfit::cli
