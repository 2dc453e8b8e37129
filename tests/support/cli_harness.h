#pragma once
// Running the dropfit command line from a test (tests/cli_*_test.cpp, which
// get DROPFIT_CLI, the built binary, as a compile definition): a fresh
// folder per test, a run with its exit code and both output streams, a
// listing of a folder (sizes and modification times) to prove that a run
// changed nothing, and synthetic sessions written to disk.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "capture/io.h"
#include "samples/generator/synth.h"
#include "support/temp_dir.h"

namespace dropfit::clitest {

namespace fs = std::filesystem;

// A fresh folder per test and whole-file text I/O (support/temp_dir.h).
using testsupport::read_text;
using testsupport::TempDir;
using testsupport::write_text;

// Replaces the first occurrence of `from` (which must be there).
inline std::string replace_first(std::string text, const std::string& from, const std::string& to) {
  const std::size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << "'" << from << "' not found";
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

inline std::string shell_quote(const std::string& s) {
  std::string out = "'";
  for (char c : s) out += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return out + "'";
}

struct CliRun {
  std::string command;
  int exit_code = -1;
  std::string out;
  std::string err;

  // The run's command and output, for failure messages.
  std::string describe() const {
    return fmt::format("$ {}\nexit {}\n--- stdout ---\n{}\n--- stderr ---\n{}", command, exit_code,
                       out.substr(0, 4000), err.substr(0, 4000));
  }
};

// Runs `dropfit ARGS...` with stdout and stderr captured to files in
// `scratch` (which must not be a folder whose contents a test compares).
inline CliRun run_dropfit(const std::vector<std::string>& args, const fs::path& scratch) {
  static std::atomic<int> counter{0};
  const int n = counter++;
  const fs::path out_file = scratch / fmt::format("run{}.stdout", n);
  const fs::path err_file = scratch / fmt::format("run{}.stderr", n);
  CliRun run;
  run.command = shell_quote(DROPFIT_CLI);
  for (const auto& a : args) {
    run.command += ' ';
    run.command += shell_quote(a);
  }
  const std::string shell = run.command + " </dev/null >" + shell_quote(out_file.string()) + " 2>" +
                            shell_quote(err_file.string());
  const int status = std::system(shell.c_str());
  run.exit_code = status == -1 ? -1 : WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  run.out = read_text(out_file);
  run.err = read_text(err_file);
  return run;
}

// Every entry below `root` (relative path -> kind, size and modification
// time, in nanoseconds): equal listings mean nothing was added, removed,
// resized or rewritten.
inline std::map<std::string, std::string> listing(const fs::path& root) {
  std::map<std::string, std::string> out;
  auto describe = [](const fs::directory_entry& e) {
    const auto mtime = e.last_write_time().time_since_epoch().count();
    if (e.is_directory()) return fmt::format("dir mtime {}", mtime);
    return fmt::format("file {} bytes mtime {}", e.file_size(), mtime);
  };
  out["."] = describe(fs::directory_entry(root));
  for (const auto& entry : fs::recursive_directory_iterator(root))
    out[fs::relative(entry.path(), root).string()] = describe(entry);
  return out;
}

// A short synthetic session (two trials, 5.25 and 4.80 m/s), small enough
// that a command runs in well under a second.
inline synth::SynthOptions short_session_options() {
  synth::SynthOptions o;
  o.seed = 7;
  o.impact_velocities_m_s = {5.25, 4.80};
  o.n_frames = 260;
  o.trigger_frame = 100;
  // forceplate/ takes the zero offset from at least 50 samples ending 0.05 s
  // before the trigger: 120 pre-trigger samples leave room for that.
  o.n_samples = 600;
  o.pretrigger_fraction = 0.20;
  return o;
}

// make_session, then capture::write_session into `root`.
inline synth::SyntheticSession write_synthetic_session(const fs::path& root,
                                                       const synth::SynthOptions& options = short_session_options()) {
  synth::SyntheticSession s = synth::make_session(options);
  s.session.root = root.string();
  capture::write_session(root.string(), s.session);
  return s;
}

// The one-line error contract: exit non-zero, and stderr is exactly one
// line starting "dropfit: error:".
inline void expect_one_line_error(const CliRun& run) {
  EXPECT_NE(run.exit_code, 0) << run.describe();
  EXPECT_EQ(run.err.rfind("dropfit: error:", 0), 0u) << run.describe();
  ASSERT_FALSE(run.err.empty()) << run.describe();
  EXPECT_EQ(run.err.back(), '\n') << run.describe();
  EXPECT_EQ(std::count(run.err.begin(), run.err.end(), '\n'), 1) << run.describe();
}

}  // namespace dropfit::clitest
