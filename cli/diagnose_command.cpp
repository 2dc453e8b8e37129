// dropfit diagnose SESSION --out DIR
// Closing the loop: each stage's residual traced to the effect the model
// lacks, added, and the error before and after (diagnosis.json).
#include <fmt/format.h>

#include "capture/io.h"
#include "cli/command.h"
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
    const Session session = capture::read_session(args->session);
    const diagnosis::DiagnosisResult result = diagnosis::diagnose(session);
    report::OutputSet out;
    out.add("diagnosis.json", diagnosis::diagnosis_json(result));
    out.commit(args->out, {args->session});
    fmt::print("{}", result.report());
    fmt::print("wrote {}/diagnosis.json\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(50, add_diagnose);
}  // namespace dropfit::cli
