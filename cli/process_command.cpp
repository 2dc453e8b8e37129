// dropfit process SESSION --out DIR
#include <fmt/format.h>

#include "capture/io.h"
#include "cli/command.h"
#include "cli/pipeline.h"
#include "report/results.h"

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
    const Session session = capture::read_session(args->session);
    const auto calibration = pipeline::calibrate_session(session);
    const auto cameras = pipeline::cameras_of(calibration);

    report::OutputSet out;
    pipeline::add_calibration_outputs(out, calibration, session.manifest.video);
    std::vector<trial::TrialResult> results;
    for (const auto& trial : session.trials) {
      auto outcome = pipeline::process_trial(session.manifest, trial, cameras, args->max_tilt_deg);
      pipeline::add_trial_outputs(out, outcome);
      results.push_back(std::move(outcome.result));
    }
    out.add("summary.csv", report::summary_csv(results));
    out.commit(args->out, {args->session});
    for (const auto& r : results) {
      fmt::print("{:<10} {:>6.3f} m/s  {:>6.1f} mm  {:>7.0f} N  tilt {:>4.1f} deg  {}\n", r.id, r.impact_velocity_m_s,
                 r.max_deformation_m * 1e3, r.peak_force_n, r.tilt_deg,
                 r.accepted ? "accepted" : "REJECTED: " + r.reject_reason);
    }
    fmt::print("wrote {}\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(30, add_process);
}  // namespace dropfit::cli
