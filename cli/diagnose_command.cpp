// dropfit diagnose SESSION --out DIR
// The session state through the loop with the loop's baseline (Model 4):
// each stage's residual traced to the effect the model lacks, added, and
// the error before and after (diagnosis.json); the final model as fit.json.
#include <fmt/format.h>

#include "cli/command.h"
#include "core/error.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"

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
    pipeline::BuildOptions options;
    options.models = {fitting::ModelKind::Model4};
    const pipeline::SessionState state = pipeline::build(args->session, options);
    for (const auto& note : state.all_notes()) fmt::print("note: {}\n", note);
    if (!state.loop) throw dropfit::Error(fmt::format("{}: the loop could not run (see the notes above)", args->session));
    report::OutputSet out;
    out.add("diagnosis.json", diagnosis::diagnosis_json(*state.loop));
    if (state.final_model6())
      pipeline::add_model6_outputs(out, "", state);
    else if (const auto* fit = state.final_fit())
      pipeline::add_fit_outputs(out, "", *fit, state, state.final_label());
    out.commit(args->out, {args->session});
    fmt::print("{}", state.loop->report());
    fmt::print("wrote {}/diagnosis.json\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(50, add_diagnose);
}  // namespace dropfit::cli
