#pragma once
// Results are written whole or not at all: a command builds every file of
// its output in memory (an OutputSet), and only then commits them. commit()
// writes every file (fsynced) into a staging folder beside the output
// folder, then swaps it into place (renameat2 RENAME_EXCHANGE, or two
// renames), so the output folder holds exactly this set: an error before
// the swap leaves it as it was, and a re-run leaves no stale file of an
// earlier one. A committed folder carries the marker file kOutputMarker
// (with the session it came from, when set); an existing output folder
// without it is refused unless empty, whatever names it holds: dropfit
// never replaces a folder it did not mark. Staging folders that a killed run
// left beside the output folder (their process gone) are removed. A session folder is never written
// into, whatever symbolic links the output folder held: the old folder is
// removed (its links with it, never followed), never written into.
#include <map>
#include <vector>
#include <string>

namespace dropfit::report {

inline constexpr const char* kOutputMarker = ".dropfit-output";

class OutputSet {
 public:
  // relative_path uses '/' (e.g. "trials/trial1/trial.json").
  void add(const std::string& relative_path, std::string content);
  bool empty() const { return files_.empty(); }
  // The folder the results come from (a session), recorded in the marker
  // so that a later run finds its own folder (session_output_folders).
  void set_source(const std::string& source) { source_ = source; }
  const std::map<std::string, std::string>& files() const { return files_; }

  // Replaces out_dir with exactly these files. Throws dropfit::Error (and
  // leaves out_dir as it was) when out_dir is inside, is, or holds one of
  // the protected folders, is a symbolic link or a file, holds files dropfit
  // did not write, or a file cannot be written.
  void commit(const std::string& out_dir, const std::vector<std::string>& protected_dirs = {}) const;

 private:
  std::map<std::string, std::string> files_;
  std::string source_;
};

// The source recorded in out_dir's marker, "" when none.
std::string output_source(const std::string& out_dir);

// One output folder per session under out_dir, stable across re-runs: a
// session whose results are already there (a marked sub-folder recording
// it as its source, by canonical path) keeps that folder; the others get
// their folder's name, prefixed by as many parent folders as make it
// unique among the sessions and the folders already there (a/demo and
// b/demo: "a__demo" and "b__demo"), "-2", "-3" only when the whole path
// cannot tell them apart.
std::vector<std::string> session_output_folders(const std::string& out_dir, const std::vector<std::string>& sessions);

// Writes one file atomically (dropfit::write_file_atomic, core/atomic_file.h).
void write_file_atomic(const std::string& path, const std::string& content);

}  // namespace dropfit::report
