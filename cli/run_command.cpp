// dropfit run SESSION... --out DIR
// Calibrate, process trials, fit all models, close the loop, report.
// Several sessions are processed in parallel where the machine allows; a
// failing session is reported and the others still run.
#include <fmt/format.h>

#include <chrono>
#include <filesystem>
#include <set>
#include <thread>

#include "cli/command.h"
#include "pipeline/run.h"
#include "report/output.h"
#include "core/progress.h"

namespace dropfit::cli {
namespace {

void add_run(CLI::App& app, CommandContext& ctx) {
  struct Args {
    std::vector<std::string> sessions;
    std::string out;
    std::string models = "all";
    bool no_diagnose = false;
    int jobs = 0;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("run", "the main job: calibrate, process, fit all models, close the loop, report");
  sub->add_option("sessions", args->sessions, "session folder(s)")->required()->check(CLI::ExistingDirectory);
  sub->add_option("--out", args->out, "output folder (one sub-folder per session when several)")->required();
  sub->add_option("--jobs", args->jobs, "parallel workers (default: the machine's cores)")->check(CLI::NonNegativeNumber);
  sub->add_flag("--no-diagnose", args->no_diagnose, "skip closing the loop");
  sub->callback([args, &ctx] {
    namespace fs = std::filesystem;
    const auto start = std::chrono::steady_clock::now();
    const int cores = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    const int jobs = args->jobs > 0 ? args->jobs : cores;
    pipeline::BuildOptions options;
    if (args->no_diagnose) options.upto = pipeline::Stage::Fits;

    // The same folder named twice is one session.
    {
      std::vector<std::string> unique_sessions;
      std::set<std::string> seen;
      for (const auto& s : args->sessions) {
        std::error_code ec;
        if (seen.insert(fs::weakly_canonical(s, ec).string()).second) unique_sessions.push_back(s);
      }
      args->sessions = std::move(unique_sessions);
    }
    const size_t n = args->sessions.size();
    // Each session its own folder, stable across re-runs, even when two
    // session folders share a name (a/demo and b/demo go to OUT/a__demo and
    // OUT/b__demo).
    const std::vector<std::string> out_dirs =
        n == 1 ? std::vector<std::string>{args->out} : report::session_output_folders(args->out, args->sessions);
    Progress progress;
    const std::vector<pipeline::SessionRun> runs = pipeline::run_sessions(args->sessions, out_dirs, options, jobs, progress);

    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    int failed = 0;
    for (size_t i = 0; i < n; ++i) {
      const auto& s = runs[i].summary;
      if (!runs[i].ok) {
        ++failed;
        fmt::print(stderr, "dropfit: error: session {}: {}\n", args->sessions[i], runs[i].error);
        if (s.trials == 0 && s.session.empty()) continue;  // nothing ran
      }
      fmt::print("{}: {} of {} trials accepted; report {}/report.html\n", s.session, s.accepted, s.trials, out_dirs[i]);
      for (const auto& note : s.notes) fmt::print("  note: {}\n", note);
    }
    fmt::print("{} session(s) in {:.1f} s; {} failed\n", n, seconds, failed);
    ctx.exit_code = failed > 0 ? 1 : 0;
  });
}

}  // namespace
DROPFIT_COMMAND(5, add_run);
}  // namespace dropfit::cli
