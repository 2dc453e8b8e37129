#pragma once
// `dropfit run` as a view of the pipeline: each session built through the
// loop, its results committed whole to its own folder (never into a session
// folder), and a verdict on whether it is a success.
#include <string>
#include <vector>

#include "core/progress.h"
#include "pipeline/pipeline.h"

namespace dropfit::pipeline {

struct SessionRun {
  RunSummary summary;  // empty when the session could not be built
  bool ok = false;     // results written, a usable trial and a final model
  std::string error;   // why not, when !ok
};

// Several sessions, `jobs` at a time: one session keeps `options.threads`
// for its own models; several run a session per worker, each on one thread.
// out_dirs[i] receives sessions[i]'s results (report::session_output_folders
// names them); no session folder is written into. A session that fails
// is reported in its SessionRun and the others still run. Progress goes to
// `progress` (one line shared by the workers).
std::vector<SessionRun> run_sessions(const std::vector<std::string>& sessions, const std::vector<std::string>& out_dirs,
                                     BuildOptions options, int jobs, Progress& progress);

}  // namespace dropfit::pipeline
