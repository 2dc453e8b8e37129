// dropfit-synth's worlds from the command line and scripts/make-archive:
// sessions the capture stage reads, truth files that name what was done,
// the same command giving the same archive, and one-line errors.
#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "capture/io.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

fs::path build_dir() { return fs::path(DROPFIT_CLI).parent_path().parent_path(); }
fs::path synth_exe() { return build_dir() / "samples" / "generator" / "dropfit-synth"; }

int shell(const std::string& command, const fs::path& log) {
  const int status = std::system((command + " </dev/null >" + shell_quote(log.string()) + " 2>&1").c_str());
  return status == -1 ? -1 : WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

TEST(GeneratorCli, IndependentWorldWithRandomEffectsIsALabSession) {
  if (!fs::exists(synth_exe())) GTEST_SKIP() << "dropfit-synth not built";
  TempDir dir;
  const int rc = shell(shell_quote(synth_exe().string()) + " --world independent --random-effects --seed 104 --out " +
                           shell_quote((dir / "s").string()) + " --truth " + shell_quote((dir / "t.json").string()),
                       dir / "log");
  ASSERT_EQ(rc, 0) << read_text(dir / "log");
  const Session s = capture::read_session((dir / "s").string());
  ASSERT_EQ(s.trials.size(), 5u);
  EXPECT_EQ(s.manifest.impactor.base_marker_height_m, 0.0);
  EXPECT_EQ(s.trials[0].force.t_s.size(), 5000);
  const auto truth = nlohmann::json::parse(read_text(dir / "t.json"));
  EXPECT_EQ(truth.at("world"), "independent");
  const double k1 = truth.at("parameters").at("k1_n_m").get<double>();
  EXPECT_GE(k1, 2e4);
  EXPECT_LE(k1, 1e5);
  // Digitised only about contact: most frames NaN, ~250 with data.
  const auto& uv = s.trials[0].tracks.uv_px;
  int rows = 0;
  for (Eigen::Index f = 0; f < uv.rows(); ++f) rows += uv.row(f).array().isFinite().any();
  EXPECT_NEAR(rows, 250, 2);
  // The truth names every effect the log line lists.
  const std::string log = read_text(dir / "log");
  for (const auto& e : truth.at("effects")) EXPECT_NE(log.find(e.at("name").get<std::string>()), std::string::npos);
}

TEST(GeneratorCli, MakeArchiveIsReproducibleAndListsEachSessionsEffects) {
  if (!fs::exists(synth_exe())) GTEST_SKIP() << "dropfit-synth not built";
  TempDir dir;
  const std::string script = shell_quote(std::string(DROPFIT_SOURCE_DIR) + "/scripts/make-archive");
  const std::string env = "DROPFIT_SYNTH=" + shell_quote(synth_exe().string()) + " ";
  ASSERT_EQ(shell(env + script + " 2 " + shell_quote((dir / "a").string()) + " --seed 9", dir / "log1"), 0)
      << read_text(dir / "log1");
  ASSERT_EQ(shell(env + script + " 2 " + shell_quote((dir / "b").string()) + " --seed 9", dir / "log2"), 0);
  const std::string csv = read_text(dir / "a" / "archive.csv");
  EXPECT_EQ(csv, read_text(dir / "b" / "archive.csv"));
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 3) << csv;
  EXPECT_NE(csv.find("s001,9,"), std::string::npos) << csv;
  EXPECT_NE(csv.find("s002,10,"), std::string::npos) << csv;
  EXPECT_EQ(read_text(dir / "a" / "s002" / "truth.json"), read_text(dir / "b" / "s002" / "truth.json"));
  EXPECT_TRUE(fs::exists(dir / "a" / "s001" / "session" / "session.toml"));
  // A non-empty target is refused.
  EXPECT_NE(shell(env + script + " 1 " + shell_quote((dir / "a").string()), dir / "log3"), 0);
  EXPECT_NE(read_text(dir / "log3").find("not empty"), std::string::npos);
}

TEST(GeneratorCli, BadOptionsAreOneLineErrors) {
  if (!fs::exists(synth_exe())) GTEST_SKIP() << "dropfit-synth not built";
  TempDir dir;
  const std::string base = shell_quote(synth_exe().string()) + " --out " + shell_quote((dir / "s").string()) +
                           " --truth " + shell_quote((dir / "t.json").string());
  EXPECT_EQ(shell(base + " --world moon", dir / "l1"), 1);
  EXPECT_NE(read_text(dir / "l1").find("--world 'moon'"), std::string::npos) << read_text(dir / "l1");
  EXPECT_EQ(shell(base + " --effect hysteresis_elastic=1.5", dir / "l2"), 1);
  EXPECT_NE(read_text(dir / "l2").find("[0, 1)"), std::string::npos) << read_text(dir / "l2");
  EXPECT_EQ(shell(base + " --param k9_n_m=3", dir / "l3"), 1);
  EXPECT_NE(read_text(dir / "l3").find("unknown parameter"), std::string::npos) << read_text(dir / "l3");
  EXPECT_FALSE(fs::exists(dir / "s" / "session.toml"));  // nothing written
}

}  // namespace
}  // namespace dropfit::clitest
