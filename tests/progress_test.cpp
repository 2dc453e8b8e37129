// The terminal progress line (core/progress.h) and the parallel loop
// (core/parallel.h), alone and together as `dropfit run` uses them: several
// sessions on worker threads sharing one progress line. The thread
// sanitizer build (scripts/sanitize thread) runs this file to find races.
#include <gtest/gtest.h>

#include <atomic>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "core/parallel.h"
#include "core/progress.h"

namespace dropfit {
namespace {

const std::string kClear = "\r\033[K";

// The records a progress line wrote: the text after each clear sequence
// ("" for a bare clear).
std::vector<std::string> records(const std::string& written) {
  std::vector<std::string> out;
  std::size_t at = written.find(kClear);
  EXPECT_EQ(at, 0u) << "output does not start with a clear";
  while (at != std::string::npos) {
    const std::size_t next = written.find(kClear, at + kClear.size());
    out.push_back(written.substr(at + kClear.size(), next == std::string::npos ? std::string::npos
                                                                               : next - at - kClear.size()));
    at = next;
  }
  return out;
}

TEST(Progress, SilentWhenDisabled) {
  testing::internal::CaptureStderr();
  {
    Progress p(false);
    p.update("fit", "model4");
    p.done();
  }
  EXPECT_EQ(testing::internal::GetCapturedStderr(), "");
}

TEST(Progress, OverwritesOneLineAndClearsItOnce) {
  testing::internal::CaptureStderr();
  {
    Progress p(true);
    p.update("fit", "model4");
    p.update(std::string(100, 'x'));  // cut to 78 columns
    p.done();
    p.done();  // nothing left to clear
  }            // nor at destruction
  EXPECT_EQ(testing::internal::GetCapturedStderr(), kClear + "fit: model4" + kClear + std::string(78, 'x') + kClear);
}

TEST(Progress, SharedByParallelSessionsKeepsEveryRecordWhole) {
  constexpr int kSessions = 4, kSteps = 300;
  testing::internal::CaptureStderr();
  {
    Progress p(true);
    // As `dropfit run A B C D`: each session reports its steps and clears
    // the line when a stage ends, while the others go on writing. All start
    // together, so that clearing and writing overlap.
    std::atomic<int> started{0};
    parallel_for(kSessions, kSessions, [&](std::size_t s) {
      started.fetch_add(1);
      while (started.load() < kSessions) std::this_thread::yield();
      for (int i = 0; i < kSteps; ++i) {
        p.update("session " + std::to_string(s), "step " + std::to_string(i));
        if (i % 4 == 3) p.done();  // a stage ends: its line cleared
      }
    });
    p.done();
  }
  const std::vector<std::string> recs = records(testing::internal::GetCapturedStderr());
  int updates = 0;
  std::set<std::string> expected;
  for (int s = 0; s < kSessions; ++s)
    for (int i = 0; i < kSteps; ++i) expected.insert("session " + std::to_string(s) + ": step " + std::to_string(i));
  for (const auto& r : recs) {
    if (r.empty()) continue;
    ++updates;
    EXPECT_EQ(expected.count(r), 1u) << "a torn record: '" << r << "'";
  }
  EXPECT_EQ(updates, kSessions * kSteps);
  // The line ends cleared: the last record is a bare clear.
  ASSERT_FALSE(recs.empty());
  EXPECT_EQ(recs.back(), "");
}

TEST(ParallelFor, CallsEveryIndexOnceOnEachThreadCount) {
  for (int threads : {1, 2, 3, 8}) {
    std::vector<std::atomic<int>> calls(1000);
    parallel_for(calls.size(), threads, [&](std::size_t i) { calls[i].fetch_add(1); });
    for (std::size_t i = 0; i < calls.size(); ++i) ASSERT_EQ(calls[i].load(), 1) << "index " << i << ", " << threads;
  }
  int never = 0;
  parallel_for(0, 4, [&](std::size_t) { ++never; });
  EXPECT_EQ(never, 0);
}

}  // namespace
}  // namespace dropfit
