#pragma once
// One self-overwriting progress line on a terminal (stderr); silent when
// stderr is not a terminal, so logs and CI stay clean.
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
  bool enabled_;
  bool dirty_ = false;
};

}  // namespace dropfit
