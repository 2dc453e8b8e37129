// dropfit calibrate SESSION --out DIR
#include <fmt/format.h>

#include <filesystem>

#include "capture/io.h"
#include "cli/command.h"
#include "cli/pipeline.h"

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
  sub->add_flag("--distortion", args->distortion, "add Bouguet lens distortion terms (dlt16)");
  sub->callback([args] {
    namespace fs = std::filesystem;
    const fs::path root(args->session);
    const Manifest manifest = capture::read_manifest((root / "session.toml").string());
    Session session;
    session.root = args->session;
    session.manifest = manifest;
    capture::read_session_calibration(args->session, session);
    calibration::CalibrationOptions options;
    options.dlt.fit_distortion = args->distortion;
    const auto result = pipeline::calibrate_session(session, options);

    report::OutputSet out;
    pipeline::add_calibration_outputs(out, result);
    out.commit(args->out, {args->session});
    fmt::print("{}", result.report());
    fmt::print("wrote {}/calibration.json\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(10, add_calibrate);
}  // namespace dropfit::cli
