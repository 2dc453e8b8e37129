// dropfit init FOLDER
// A session.toml draft from what a lab's folder holds (capture/session_draft.h):
// written to FOLDER/session.toml, which must not exist yet; what the files
// could not tell is marked FILL IN (dropfit refuses the manifest until it is
// filled in) and what came from a convention CHECK.
#include <fmt/format.h>

#include <filesystem>

#include "capture/session_draft.h"
#include "cli/command.h"
#include "core/atomic_file.h"
#include "core/error.h"

namespace dropfit::cli {
namespace {

void add_init(CLI::App& app, CommandContext& ctx) {
  struct Args {
    std::string folder;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("init", "a session.toml draft from a lab's folder (DLTdv, easyWand, BioWare, C3D files)");
  sub->add_option("folder", args->folder, "the lab's folder: one sub-folder per trial")
      ->required()
      ->check(CLI::ExistingDirectory);
  sub->callback([args, &ctx] {
    namespace fs = std::filesystem;
    const fs::path manifest = fs::path(args->folder) / "session.toml";
    std::error_code ec;
    if (fs::exists(fs::symlink_status(manifest, ec)))
      throw Error(fmt::format("{} already exists; dropfit init only drafts a new one (move it aside first)",
                              manifest.string()));
    const capture::SessionDraft d = capture::draft_session(args->folder);
    write_file_atomic(manifest.string(), d.toml);
    for (const auto& line : d.found) fmt::print("found: {}\n", line);
    fmt::print("wrote {} ({} trial(s))\n", manifest.string(), d.trials.size());
    if (!d.fill_in.empty()) fmt::print("fill in: {}\n", fmt::join(d.fill_in, ", "));
    if (!d.check.empty()) fmt::print("check: {}\n", fmt::join(d.check, ", "));
    fmt::print("then: dropfit run {} --out RESULTS\n", args->folder);
    ctx.exit_code = 0;
  });
}

}  // namespace
DROPFIT_COMMAND(2, add_init);
}  // namespace dropfit::cli
