// dropfit gather OUT_DIR... --out DIR
// Gathers many results (the folders `dropfit run` and `dropfit table` wrote,
// or folders holding several of them) into one archive table: archive.csv
// and archive.html (report/archive.h says what a row holds). The result
// folders are only read.
#include <fmt/format.h>

#include <memory>

#include "cli/command.h"
#include "report/archive.h"

namespace dropfit::cli {
namespace {

void add_gather(CLI::App& app, CommandContext& ctx) {
  struct Args {
    std::vector<std::string> dirs;
    std::string out;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("gather", "many sessions' results into one archive table (archive.csv, archive.html)");
  sub->add_option("results", args->dirs, "result folders of `dropfit run` (or folders holding them)")->required();
  sub->add_option("--out", args->out, "archive folder")->required();
  sub->callback([args, &ctx] {
    const report::Archive archive = report::gather_results(args->dirs, args->out);
    std::vector<std::string> inputs;
    for (const auto& s : archive.sessions) inputs.push_back(s.dir.string());
    archive.files.commit(args->out, inputs);
    fmt::print("{} results folder(s) gathered into {}/archive.csv and archive.html\n", archive.sessions.size(),
               args->out);
    ctx.exit_code = 0;
  });
}

}  // namespace
DROPFIT_COMMAND(90, add_gather);
}  // namespace dropfit::cli
