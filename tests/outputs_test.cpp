// Safe outputs: each session's results in a folder of its own, an output
// folder replaced whole (no stale files), nothing ever written into a
// session folder whatever links the output folder holds, and the atomic file
// writer of core/.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/atomic_file.h"
#include "core/error.h"
#include "report/output.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

const fs::path kDemo = fs::path(DROPFIT_SOURCE_DIR) / "samples" / "demo-session";

TEST(AtomicFile, WritesReplacesAndLeavesNoTemporary) {
  TempDir dir;
  const fs::path file = dir / "a" / "b.txt";
  write_file_atomic(file.string(), "first\n");
  EXPECT_EQ(read_text(file), "first\n");
  write_file_atomic(file.string(), "second\n");
  EXPECT_EQ(read_text(file), "second\n");
  int entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir / "a")) ++entries;
  EXPECT_EQ(entries, 1);  // no temporary left beside it
  fs::create_directories(dir / "folder");
  EXPECT_THROW(write_file_atomic((dir / "folder").string(), "x"), Error);
  EXPECT_THROW(write_file_atomic((dir / "a" / "b.txt" / "c").string(), "x"), Error);  // a file in the way
}

TEST(AtomicFile, ManyFilesSyncedInBatchesAreWrittenWholeOrNotAtAll) {
  TempDir dir;
  // More files than one batch (64), each with its own content.
  std::vector<std::string> paths, contents;
  for (int i = 0; i < 70; ++i) {
    paths.push_back((dir / fmt::format("f{}.txt", i)).string());
    contents.push_back(fmt::format("file {}\n", i) + std::string(static_cast<std::size_t>(i) * 1000, 'x'));
  }
  std::vector<std::pair<std::string, std::string_view>> files;
  for (int i = 0; i < 70; ++i) files.emplace_back(paths[i], contents[i]);
  write_files_synced(files);
  for (int i = 0; i < 70; ++i) EXPECT_EQ(read_text(paths[i]), contents[i]) << paths[i];
  // A file that cannot be created (its folder is missing): the error names
  // it and its batch leaves no file behind.
  TempDir other;
  const std::string good = (other / "good.txt").string(), bad = (other / "missing" / "bad.txt").string();
  try {
    write_files_synced({{good, "g"}, {bad, "b"}});
    ADD_FAILURE() << "no error for a file in a missing folder";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find(bad), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(good));
  EXPECT_FALSE(fs::exists(bad));
}

TEST(OutputSetCommit, ReplacesAnEarlierCommitWholeAndRefusesForeignFolders) {
  TempDir dir;
  const fs::path out = dir / "out";
  report::OutputSet first;
  first.add("a.txt", "1");
  first.add("trials/t1/x.csv", "1");
  first.commit(out.string());
  report::OutputSet second;
  second.add("a.txt", "2");
  second.commit(out.string());
  EXPECT_EQ(read_text(out / "a.txt"), "2");
  EXPECT_FALSE(fs::exists(out / "trials"));  // stale folder of the first commit gone
  EXPECT_TRUE(fs::exists(out / report::kOutputMarker));
  // Nothing but the output folder beside it (no staging or old folder left).
  {
    int entries = 0;
    for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir.path())) ++entries;
    EXPECT_EQ(entries, 1);
  }

  // A folder holding someone else's files is refused, untouched.
  const fs::path foreign = dir / "foreign";
  fs::create_directories(foreign);
  write_text(foreign / "thesis.tex", "keep me");
  EXPECT_THROW(second.commit(foreign.string()), Error);
  EXPECT_EQ(read_text(foreign / "thesis.tex"), "keep me");
  // A person's own folder that happens to hold names dropfit writes
  // (trials/, summary.csv) but no marker is theirs: refused, untouched.
  const fs::path own = dir / "own";
  fs::create_directories(own / "trials" / "t1");
  write_text(own / "summary.csv", "my notes");
  write_text(own / "trials" / "t1" / "video.txt", "mine");
  EXPECT_THROW(second.commit(own.string()), Error);
  EXPECT_EQ(read_text(own / "summary.csv"), "my notes");
  EXPECT_EQ(read_text(own / "trials" / "t1" / "video.txt"), "mine");
  // Staging and old folders of a killed run (its process gone) are removed
  // by the next commit; a live process's are left.
  fs::create_directories(dir / ".out.staging-999999999-0" / "trials");
  fs::create_directories(dir / ".out.old-999999999-3");
  const fs::path live = dir / fmt::format(".out.staging-{}-77", ::getpid());
  fs::create_directories(live);
  second.commit(out.string());
  EXPECT_FALSE(fs::exists(dir / ".out.staging-999999999-0"));
  EXPECT_FALSE(fs::exists(dir / ".out.old-999999999-3"));
  EXPECT_TRUE(fs::exists(live));
  fs::remove_all(live);
  // A name that would leave the output folder is refused.
  report::OutputSet escape;
  escape.add("../escaped.txt", "x");
  EXPECT_THROW(escape.commit((dir / "out2").string()), Error);
  EXPECT_FALSE(fs::exists(dir / "escaped.txt"));
}

class Outputs : public ::testing::Test {
 protected:
  void SetUp() override { fs::copy(kDemo, session(), fs::copy_options::recursive); }
  fs::path session() const { return dir_ / "session"; }
  TempDir dir_;
};

// Two sessions with the same folder name: two result folders.
TEST_F(Outputs, SessionsWithTheSameNameGetAFolderEach) {
  fs::create_directories(dir_ / "a");
  fs::create_directories(dir_ / "b");
  fs::copy(kDemo, dir_ / "a" / "demo", fs::copy_options::recursive);
  fs::copy(kDemo, dir_ / "b" / "demo", fs::copy_options::recursive);
  const CliRun r = run_dropfit({"run", (dir_ / "a" / "demo").string(), (dir_ / "b" / "demo").string() + "/", "--out",
                                (dir_ / "out").string(), "--no-diagnose"},
                               dir_.path());
  ASSERT_EQ(r.exit_code, 0) << r.describe();
  EXPECT_TRUE(fs::exists(dir_ / "out" / "a__demo" / "report.html"));
  EXPECT_TRUE(fs::exists(dir_ / "out" / "b__demo" / "report.html"));
  EXPECT_NE(r.out.find("2 session(s)"), std::string::npos) << r.describe();
}

// Per-session folders are chosen from the session's path and found again
// by the marker's source on a re-run, whatever the order or company.
TEST(SessionOutputFolders, StableAcrossReRuns) {
  TempDir dir;
  for (const char* p : {"lab/a/demo", "lab/b/demo", "lab/c/other"}) fs::create_directories(dir / p);
  const std::string out = (dir / "out").string();
  const std::string a = (dir / "lab/a/demo").string(), b = (dir / "lab/b/demo").string(),
                    c = (dir / "lab/c/other").string();
  std::vector<std::string> first = report::session_output_folders(out, {a, b, c});
  EXPECT_EQ(first, (std::vector<std::string>{out + "/a__demo", out + "/b__demo", out + "/other"}));
  EXPECT_EQ(report::session_output_folders(out, {b, a}), (std::vector<std::string>{out + "/b__demo", out + "/a__demo"}));
  // Written once: b alone with c finds b's folder by its marker, not "demo".
  for (std::size_t i = 0; i < 3; ++i) {
    report::OutputSet set;
    set.add("x.txt", "1");
    set.set_source(fs::weakly_canonical(std::vector<std::string>{a, b, c}[i]).string());
    set.commit(first[i]);
  }
  EXPECT_EQ(report::output_source(first[1]), fs::weakly_canonical(b).string());
  EXPECT_EQ(report::session_output_folders(out, {c, b}), (std::vector<std::string>{out + "/other", out + "/b__demo"}));
  // A new session named like an existing folder gets a longer name.
  fs::create_directories(dir / "lab2/c/other");
  EXPECT_EQ(report::session_output_folders(out, {(dir / "lab2/c/other").string()}),
            (std::vector<std::string>{out + "/c__other"}));
}

// A re-run replaces the results whole; a link planted in the output folder
// that points into the session is removed, never followed.
TEST_F(Outputs, RerunReplacesWholeAndNeverFollowsALinkIntoTheSession) {
  const fs::path out = dir_ / "out";
  CliRun r = run_dropfit({"process", session().string(), "--out", out.string()}, dir_.path());
  ASSERT_EQ(r.exit_code, 0) << r.describe();
  write_text(out / "stale.txt", "from an earlier run");
  fs::remove_all(out / "trials");
  fs::create_directory_symlink(session() / "trials", out / "trials");
  const auto before = listing(session());
  r = run_dropfit({"process", session().string(), "--out", out.string()}, dir_.path());
  ASSERT_EQ(r.exit_code, 0) << r.describe();
  EXPECT_EQ(listing(session()), before) << "the session folder changed";
  EXPECT_FALSE(fs::exists(out / "stale.txt"));
  EXPECT_FALSE(fs::is_symlink(out / "trials"));
  EXPECT_TRUE(fs::exists(out / "trials" / "trial1" / "trial.json"));
  EXPECT_FALSE(fs::exists(session() / "trials" / "trial1" / "trial.json"));
}

// --out itself a link into the session, or a folder holding the session:
// refused with one error line, nothing written.
TEST_F(Outputs, OutputFolderResolvingIntoOrAroundTheSessionIsRefused) {
  fs::create_directory_symlink(session() / "trials", dir_ / "link");
  const auto before = listing(session());
  for (const fs::path& out : {dir_ / "link", dir_ / "link" / "x", dir_.path()}) {
    const CliRun r = run_dropfit({"calibrate", session().string(), "--out", out.string()}, dir_.path());
    expect_one_line_error(r);
    EXPECT_EQ(listing(session()), before) << r.describe();
  }
}

}  // namespace
}  // namespace dropfit::clitest
