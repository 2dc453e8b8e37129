// The ../shared guard of the tests (support/shared_data.h): a missing path
// fails the test under CI=true (so CI cannot pass by skipping), and a
// present one lets it run.
#include <gtest/gtest-spi.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "support/shared_data.h"

namespace dropfit::testsupport {
namespace {

// Restores CI as it was.
class CiEnvironment {
 public:
  explicit CiEnvironment(const char* value) {
    if (const char* old = std::getenv("CI")) old_ = old, had_ = true;
    if (value)
      setenv("CI", value, 1);
    else
      unsetenv("CI");
  }
  ~CiEnvironment() {
    if (had_)
      setenv("CI", old_.c_str(), 1);
    else
      unsetenv("CI");
  }

 private:
  std::string old_;
  bool had_ = false;
};

void need_missing() { DROPFIT_NEED_SHARED(shared_path("no-such-folder-here")); }

bool reached_after_present = false;
void need_present() {
  DROPFIT_NEED_SHARED(std::filesystem::path(DROPFIT_SOURCE_DIR) / "tests");
  reached_after_present = true;
}

TEST(SharedData, MissingPathFailsUnderCi) {
  const CiEnvironment ci("true");
  EXPECT_TRUE(ci_run());
  EXPECT_FATAL_FAILURE(need_missing(), "CI=true needs ../shared");
}

TEST(SharedData, CiIsTrueOrOneOnly) {
  {
    const CiEnvironment ci("1");
    EXPECT_TRUE(ci_run());
  }
  {
    const CiEnvironment ci("false");
    EXPECT_FALSE(ci_run());
  }
  {
    const CiEnvironment ci(nullptr);
    EXPECT_FALSE(ci_run());
  }
}

TEST(SharedData, PresentPathRuns) {
  const CiEnvironment ci("true");
  need_present();
  EXPECT_TRUE(reached_after_present);
  EXPECT_EQ(shared_path("validation"), std::filesystem::path(DROPFIT_SOURCE_DIR) / ".." / "shared" / "validation");
}

}  // namespace
}  // namespace dropfit::testsupport
