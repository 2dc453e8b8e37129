#include "core/progress.h"

#include <unistd.h>

#include <cstdio>
#include <mutex>

namespace dropfit {
namespace {
std::mutex& line_mutex() {
  static std::mutex m;
  return m;
}
}  // namespace

Progress::Progress() : enabled_(isatty(fileno(stderr)) != 0) {}
Progress::Progress(bool enabled) : enabled_(enabled) {}
Progress::~Progress() { done(); }

void Progress::update(const std::string& stage, const std::string& detail) {
  if (!enabled_) return;
  std::lock_guard lock(line_mutex());
  std::string text = detail.empty() ? stage : stage + ": " + detail;
  if (text.size() > 78) text.resize(78);
  std::fprintf(stderr, "\r\033[K%s", text.c_str());
  std::fflush(stderr);
  dirty_ = true;
}

void Progress::done() {
  if (!enabled_) return;
  std::lock_guard lock(line_mutex());
  if (!dirty_) return;
  std::fprintf(stderr, "\r\033[K");
  std::fflush(stderr);
  dirty_ = false;
}

}  // namespace dropfit
