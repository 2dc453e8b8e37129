// docs/walkthrough.md runs as written: its ```sh blocks, in order, as one
// bash script from the source folder with the built dropfit first on PATH
// (and TMPDIR in a scratch folder, where the page's mktemp puts its work).
// Then the results it leaves are checked: the three trials of the demo
// session, laid out as DLTdv, easyWand and BioWare leave them, drafted by
// `dropfit init`, filled in, run.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>
#include <string>

#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

// The page's ```sh blocks, joined.
std::string shell_blocks(const std::string& markdown) {
  std::istringstream in(markdown);
  std::string line, script;
  bool inside = false;
  while (std::getline(in, line)) {
    if (!inside && line == "```sh") {
      inside = true;
    } else if (inside && line == "```") {
      inside = false;
      script += "\n";
    } else if (inside) {
      script += line + "\n";
    }
  }
  return script;
}

TEST(Walkthrough, RunsAsWrittenFromALabFolderToAReport) {
  const fs::path page = fs::path(DROPFIT_SOURCE_DIR) / "docs" / "walkthrough.md";
  const std::string script = shell_blocks(read_text(page));
  ASSERT_NE(script.find("dropfit init lab"), std::string::npos) << script;
  TempDir dir;
  fs::create_directories(dir / "tmp");
  write_text(dir / "walkthrough.sh", "set -euo pipefail\n" + script);
  const std::string command = fmt::format(
      "cd {} && PATH={}:\"$PATH\" TMPDIR={} bash {} >{} 2>&1", shell_quote(DROPFIT_SOURCE_DIR),
      shell_quote(fs::path(DROPFIT_CLI).parent_path().string()), shell_quote((dir / "tmp").string()),
      shell_quote((dir / "walkthrough.sh").string()), shell_quote((dir / "log.txt").string()));
  const int status = std::system(command.c_str());
  const std::string log = read_text(dir / "log.txt");
  ASSERT_EQ(status, 0) << log;

  // The page's work folder: the one mktemp made under TMPDIR.
  fs::path work;
  for (const auto& e : fs::directory_iterator(dir / "tmp"))
    if (fs::exists(e.path() / "lab" / "session.toml")) work = e.path();
  ASSERT_FALSE(work.empty()) << log;
  // init's output: what it found, and what to fill in.
  EXPECT_NE(log.find("found: drop1: marker table drop1xypts.csv (600 rows, 6 points, 2 cameras) with DLTdv offsets"),
            std::string::npos)
      << log;
  EXPECT_NE(log.find("found: drop1: force export drop1.txt (BioWare 5.4.3.0 text, 1000 Hz)"), std::string::npos) << log;
  EXPECT_NE(log.find("fill in: "), std::string::npos) << log;
  EXPECT_NE(log.find("impactor.mass_kg, "), std::string::npos) << log;
  // The refusal before filling in names the manifest's line and key.
  EXPECT_NE(log.find("lab/session.toml:26:17 [video.frame_rate_hz]: wrong type"), std::string::npos) << log;
  // The run: every trial accepted, each aligned on its own data.
  const std::string summary = read_text(work / "results" / "summary.csv");
  EXPECT_EQ(std::count(summary.begin(), summary.end(), '\n'), 4) << summary;
  EXPECT_EQ(summary.find(",no,"), std::string::npos) << summary;
  for (const char* t : {"drop1", "drop2", "drop3"}) {
    const std::string trial = read_text(work / "results" / "trials" / t / "trial.json");
    EXPECT_NE(trial.find("sample 100 from the data"), std::string::npos) << t << ": " << trial.substr(0, 600);
  }
  EXPECT_TRUE(fs::exists(work / "results" / "report.html"));
  EXPECT_TRUE(fs::exists(work / "results" / "fits" / "model4" / "fit.json"));
  // init wrote only lab/session.toml; the run nothing in lab/.
  EXPECT_FALSE(fs::exists(work / "lab" / "trials"));
  EXPECT_FALSE(fs::exists(work / "lab" / "drop1" / "trial.json"));
}

}  // namespace
}  // namespace dropfit::clitest
