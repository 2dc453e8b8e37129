#pragma once
// The project's shared data beside the source tree (../shared: the
// validation sessions, real instrument files, the format specs), read in
// place. A user's clone has no ../shared, so a test that needs it is skipped
// there; under CI=true (the CI run, .ci/run) a missing path fails the test
// instead, so that CI cannot pass by skipping the tests that matter.
//
//   DROPFIT_NEED_SHARED(shared_path("validation") / "v1-realistic");
//
// The macro returns from the test (skip or failure) when the path is absent.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <string>

namespace dropfit::testsupport {

// ../shared beside the source tree, and paths inside it.
inline std::filesystem::path shared_path(const std::string& relative = "") {
  const std::filesystem::path root = std::filesystem::path(DROPFIT_SOURCE_DIR) / ".." / "shared";
  return relative.empty() ? root : root / relative;
}

// True when the environment says this is a CI run (CI=true or CI=1, as CI
// services set it).
inline bool ci_run() {
  const char* ci = std::getenv("CI");
  return ci != nullptr && (std::string(ci) == "true" || std::string(ci) == "1");
}

}  // namespace dropfit::testsupport

// Skips the test when `needed` (a path) does not exist (fails it under CI=true).
#define DROPFIT_NEED_SHARED(needed)                                                                     \
  do {                                                                                                \
    const std::filesystem::path dropfit_needed_path_ = (needed);                                        \
    if (!std::filesystem::exists(dropfit_needed_path_)) {                                             \
      if (::dropfit::testsupport::ci_run())                                                           \
        GTEST_FAIL() << dropfit_needed_path_.string() << " is absent, and CI=true needs ../shared";    \
      else                                                                                            \
        GTEST_SKIP() << dropfit_needed_path_.string() << " is absent (../shared is not beside the tree)"; \
    }                                                                                                 \
  } while (false)
