// dropfit diagnose SESSION --out DIR
// The pipeline up to the Model 4 fit (calibration with the stage's chosen
// camera model, trials, fit data, fit: fit.json), then the loop on that state.
// Closing the loop: each stage's residual traced to the effect the model
// lacks, added, and the error before and after (diagnosis.json).
#include <fmt/format.h>

#include "capture/io.h"
#include "cli/command.h"
#include "cli/pipeline.h"
#include "diagnosis/diagnosis.h"
#include "report/output.h"

namespace dropfit::cli {
namespace {

void add_diagnose(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string session;
    std::string out;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("diagnose", "trace each stage's residual to the missing effect; error before and after");
  sub->add_option("session", args->session, "session folder")->required()->check(CLI::ExistingDirectory);
  sub->add_option("--out", args->out, "output folder")->required();
  sub->callback([args] {
    // The pipeline up to the baseline fit (the state `run` builds), then the loop.
    const Session session = capture::read_session(args->session);
    diagnosis::SessionState state = pipeline::session_state(session);
    for (const auto& note : pipeline::fit_models(state, session.manifest, {fitting::ModelKind::Model4}))
      fmt::print("note: {}\n", note);
    const diagnosis::DiagnosisResult result = diagnosis::diagnose(state);
    report::OutputSet out;
    out.add("diagnosis.json", diagnosis::diagnosis_json(result));
    if (const auto* fit = state.fit(fitting::ModelKind::Model4))
      pipeline::add_fit_outputs(out, "", *fit, state.fit_data, session.manifest.impactor.mass_kg);
    out.commit(args->out, {args->session});
    fmt::print("{}", result.report());
    fmt::print("wrote {}/diagnosis.json\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(50, add_diagnose);
}  // namespace dropfit::cli
