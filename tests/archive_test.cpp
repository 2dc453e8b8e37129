// The local archive recipe (scripts/archive: GNU parallel, one dropfit
// process per session, then `dropfit gather`) on copies of the demo session,
// two of which share a folder name; and gather's refusal of a folder that
// holds no results.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>
#include <string>

#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

const fs::path kDemo = fs::path(DROPFIT_SOURCE_DIR) / "samples" / "demo-session";

int count_lines(const std::string& text) { return static_cast<int>(std::count(text.begin(), text.end(), '\n')); }

TEST(Archive, LocalRecipeRunsEverySessionAndGathersOneTable) {
  if (std::system("command -v parallel >/dev/null 2>&1") != 0) GTEST_SKIP() << "GNU parallel not installed";
  TempDir dir;
  fs::create_directories(dir / "lab" / "a");
  fs::create_directories(dir / "lab" / "b");
  fs::copy(kDemo, dir / "lab" / "a" / "demo", fs::copy_options::recursive);
  fs::copy(kDemo, dir / "lab" / "b" / "demo", fs::copy_options::recursive);
  const std::string command =
      fmt::format("bash {} --jobs 2 --no-diagnose --dropfit {} --out {} {} >{} 2>&1",
                  shell_quote((fs::path(DROPFIT_SOURCE_DIR) / "scripts" / "archive").string()), shell_quote(DROPFIT_CLI),
                  shell_quote((dir / "out").string()), shell_quote((dir / "lab").string()),
                  shell_quote((dir / "log.txt").string()));
  const int status = std::system(command.c_str());
  const std::string log = read_text(dir / "log.txt");
  ASSERT_EQ(status, 0) << log;
  EXPECT_NE(log.find("2 session(s)"), std::string::npos) << log;
  // Each session its own folder, each with its report.
  EXPECT_TRUE(fs::exists(dir / "out" / "sessions" / "lab__a__demo" / "report.html")) << log;
  EXPECT_TRUE(fs::exists(dir / "out" / "sessions" / "lab__b__demo" / "report.html")) << log;
  // parallel's job log: a header and one line per session, all exit 0.
  const std::string joblog = read_text(dir / "out" / "joblog.tsv");
  EXPECT_EQ(count_lines(joblog), 3) << joblog;
  // archive.csv: a header and one row per session and model (5 models, every
  // demo trial accepted).
  const std::string csv = read_text(dir / "out" / "archive" / "archive.csv");
  EXPECT_EQ(count_lines(csv), 1 + 2 * 5) << csv;
  EXPECT_NE(csv.find("lab__a__demo,"), std::string::npos);
  EXPECT_NE(csv.find(",5,5,model4,"), std::string::npos) << csv;
  const std::string html = read_text(dir / "out" / "archive" / "archive.html");
  EXPECT_NE(html.find("../sessions/lab__b__demo/report.html"), std::string::npos) << html.substr(0, 2000);
}

TEST(Archive, GatherRefusesAFolderWithoutResults) {
  TempDir dir;
  fs::create_directories(dir / "empty");
  const CliRun r = run_dropfit({"gather", (dir / "empty").string(), "--out", (dir / "archive").string()}, dir.path());
  expect_one_line_error(r);
  EXPECT_NE(r.err.find("no dropfit results"), std::string::npos) << r.describe();
  EXPECT_FALSE(fs::exists(dir / "archive"));
}

}  // namespace
}  // namespace dropfit::clitest
