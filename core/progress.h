#pragma once
// One self-overwriting progress line on a terminal (stderr); silent when
// stderr is not a terminal, so logs and CI stay clean. Thread-safe: parallel
// sessions share one Progress (`dropfit run` with several sessions), so the
// line and its state change only under one process-wide mutex.
#include <string>

namespace dropfit {

class Progress {
 public:
  // enabled: show the line; default is "stderr is a terminal".
  Progress();
  explicit Progress(bool enabled);
  ~Progress();

  // Replace the current line with `stage: detail`.
  void update(const std::string& stage, const std::string& detail = "");
  // Clear the line (called by the destructor too).
  void done();
  bool enabled() const { return enabled_; }

 private:
  const bool enabled_;  // fixed at construction: read without the lock
  bool dirty_ = false;   // a line is shown; guarded by the line mutex
};

}  // namespace dropfit
