#include "pipeline/run.h"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <filesystem>
#include <thread>

#include "pipeline/outputs.h"

namespace dropfit::pipeline {
namespace {

SessionRun run_one(const std::string& session, const std::string& out_dir, const std::vector<std::string>& all_sessions,
                   BuildOptions options, Progress& progress) {
  namespace fs = std::filesystem;
  SessionRun run;
  try {
    const std::string label = fs::path(session).filename().string();
    options.say = [&progress, label](const std::string& detail) { progress.update(label, detail); };
    const SessionState state = build(session, options);
    report::OutputSet out;
    add_run_outputs(out, state);
    std::error_code ec;
    out.set_source(fs::weakly_canonical(fs::absolute(session), ec).string());
    out.commit(out_dir, all_sessions);
    run.summary = summarise(state);
    // Results are written (the report says why), but a session with no
    // usable trial or no final model is not a success; a model that failed
    // beside a final one is a note.
    const RunSummary& s = run.summary;
    if (s.accepted == 0)
      run.error = fmt::format("no usable trial ({} of {} rejected, reasons in {}/report.html)", s.trials, s.trials,
                              out_dir);
    else if (!s.final_model)
      run.error = fmt::format("no mat model could be fitted (see the notes and {}/report.html)", out_dir);
    else
      run.ok = true;
  } catch (const std::exception& e) {
    run.error = e.what();
  }
  return run;
}

}  // namespace

std::vector<SessionRun> run_sessions(const std::vector<std::string>& sessions, const std::vector<std::string>& out_dirs,
                                     BuildOptions options, int jobs, Progress& progress) {
  const std::size_t n = sessions.size();
  std::vector<SessionRun> runs(n);
  options.threads = n == 1 ? std::max(jobs, 1) : 1;
  std::atomic<std::size_t> next{0};
  std::vector<std::thread> workers;
  for (int w = 0; w < std::min<int>(std::max(jobs, 1), static_cast<int>(n)); ++w)
    workers.emplace_back([&] {
      for (std::size_t i; (i = next++) < n;) runs[i] = run_one(sessions[i], out_dirs[i], sessions, options, progress);
    });
  for (auto& w : workers) w.join();
  progress.done();
  return runs;
}

}  // namespace dropfit::pipeline
