#pragma once
// Results are written whole or not at all: a command builds every file of
// its output in memory (an OutputSet), and only then commits them. Each file
// goes to a temporary name in its final folder and is renamed into place, so
// a reader never sees half a file and an error before commit() writes
// nothing. A session folder is never written into.
#include <map>
#include <vector>
#include <string>

namespace dropfit::report {

class OutputSet {
 public:
  // relative_path uses '/' (e.g. "trials/trial1/trial.json").
  void add(const std::string& relative_path, std::string content);
  bool empty() const { return files_.empty(); }
  const std::map<std::string, std::string>& files() const { return files_; }

  // Writes every file under out_dir. Throws dropfit::Error when out_dir is
  // inside (or is) one of the protected folders, or a file cannot be written.
  void commit(const std::string& out_dir, const std::vector<std::string>& protected_dirs = {}) const;

 private:
  std::map<std::string, std::string> files_;
};

// Writes one file atomically (temporary name + rename).
void write_file_atomic(const std::string& path, const std::string& content);

}  // namespace dropfit::report
