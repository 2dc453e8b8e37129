// dropfit calibrate SESSION --out DIR
// The calibration stage's chosen camera model (diagnosis.h), the one
// reconstruct, process, fit and run use.
#include <fmt/format.h>

#include <filesystem>

#include "capture/io.h"
#include "cli/command.h"
#include "pipeline/wiring.h"
#include "pipeline/outputs.h"

namespace dropfit::cli {
namespace {

void add_calibrate(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string session;
    std::string out;
    bool distortion = false;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("calibrate", "DLT per camera from the fit markers; accuracy on the check markers");
  sub->add_option("session", args->session, "session folder")->required()->check(CLI::ExistingDirectory);
  sub->add_option("--out", args->out, "output folder")->required();
  sub->add_flag("--distortion", args->distortion,
                "force Bouguet lens distortion terms (k1 p1 p2) instead of the cross-validated choice");
  sub->callback([args] {
    namespace fs = std::filesystem;
    const fs::path root(args->session);
    const Manifest manifest = capture::read_manifest((root / "session.toml").string());
    Session session;
    session.root = args->session;
    session.manifest = manifest;
    capture::read_session_calibration(args->session, session);
    // By default the camera model every later stage uses: outliers and lens
    // distortion decided by cross-validation on every marker.
    calibration::CalibrationResult result;
    std::vector<std::string> left_out;
    if (args->distortion) {
      calibration::CalibrationOptions options;
      options.dlt.fit_distortion = true;
      result = pipeline::calibrate_session(session, options);
    } else {
      const auto choice = pipeline::choose_calibration(session);
      for (const auto& e : choice.effects) fmt::print("{}: {}\n", e.name, e.evidence);
      for (const auto& r : choice.remaining) fmt::print("unexplained {}: {}\n", r.name, r.description);
      result = choice.after;
      left_out = choice.dropped_markers;
    }

    report::OutputSet out;
    pipeline::add_calibration_outputs(out, result, manifest.video);
    out.commit(args->out, {args->session});
    fmt::print("{}", result.report());
    // The report above is of the markers kept; those the stage left out
    // are named here, so that "outliers: none" is not read as all of them.
    if (!left_out.empty())
      fmt::print("  left out of every fit by the calibration stage: {}\n", fmt::join(left_out, ", "));
    fmt::print("wrote {}/calibration.json\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(10, add_calibrate);
}  // namespace dropfit::cli
