// dropfit run SESSION... --out DIR
// Calibrate, process trials, fit all models, close the loop, report.
// Several sessions are processed in parallel where the machine allows; a
// failing session is reported and the others still run.
#include <fmt/format.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <mutex>
#include <set>
#include <thread>

#include "cli/command.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"
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
    Progress progress;
    std::vector<std::string> out_dirs(n), errors(n);
    std::vector<pipeline::RunSummary> summaries(n);
    // One byte per session: the workers set their own (a vector<bool> packs
    // several sessions' flags into one word, a data race between workers).
    std::vector<char> ok(n, 0);
    // Each session its own folder, stable across re-runs, even when two
    // session folders share a name (a/demo and b/demo go to OUT/a__demo and
    // OUT/b__demo).
    if (n == 1) {
      out_dirs[0] = args->out;
    } else {
      out_dirs = report::session_output_folders(args->out, args->sessions);
    }
    // One session: its models in parallel. Several: sessions in parallel.
    options.threads = n == 1 ? jobs : 1;
    std::atomic<size_t> next{0};
    std::vector<std::thread> workers;
    for (int w = 0; w < std::min<int>(jobs, static_cast<int>(n)); ++w) {
      workers.emplace_back([&] {
        for (size_t i; (i = next++) < n;) {
          try {
            pipeline::BuildOptions session_options = options;
            const std::string label = fs::path(args->sessions[i]).filename().string();
            session_options.say = [&progress, label](const std::string& detail) { progress.update(label, detail); };
            const pipeline::SessionState state = pipeline::build(args->sessions[i], session_options);
            report::OutputSet out;
            pipeline::add_run_outputs(out, state);
            std::error_code ec;
            out.set_source(fs::weakly_canonical(fs::absolute(args->sessions[i]), ec).string());
            std::vector<std::string> protected_dirs(args->sessions.begin(), args->sessions.end());
            out.commit(out_dirs[i], protected_dirs);
            summaries[i] = pipeline::summarise(state);
            // Results are written (the report says why), but a session with
            // no usable trial or no final model is not a success; a model
            // that failed beside a final one is a note.
            const auto& s = summaries[i];
            if (s.accepted == 0) {
              errors[i] = fmt::format("no usable trial ({} of {} rejected, reasons in {}/report.html)", s.trials,
                                      s.trials, out_dirs[i]);
            } else if (!s.final_model) {
              errors[i] = fmt::format("no mat model could be fitted (see the notes and {}/report.html)", out_dirs[i]);
            } else {
              ok[i] = 1;
            }
          } catch (const std::exception& e) {
            errors[i] = e.what();
          }
        }
      });
    }
    for (auto& w : workers) w.join();
    progress.done();

    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    int failed = 0;
    for (size_t i = 0; i < n; ++i) {
      if (!ok[i]) {
        ++failed;
        fmt::print(stderr, "dropfit: error: session {}: {}\n", args->sessions[i], errors[i]);
        if (summaries[i].trials == 0 && summaries[i].session.empty()) continue;  // nothing ran
      }
      const auto& s = summaries[i];
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
