// dropfit gather on results as `dropfit run` and `dropfit table` write them:
// models labelled as the run labelled them (the closed loop as closed_loop,
// not as the model it extends), one row per results folder and model however
// often a folder is reached, and a table's fit gathered beside sessions.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

// A session's results: summary.csv, Model 4's fit and the closed loop's (a
// Model 4 with an effect term), as the run writes them.
void write_session_results(const fs::path& dir) {
  write_text(dir / ".dropfit-output", "Written by dropfit.\n");
  write_text(dir / "summary.csv",
             "trial,accepted,impact_velocity_m_s,impact_velocity_ci_m_s,max_deformation_m,peak_force_n,time_to_peak_s,"
             "tilt_deg,video_offset_ms,reject_reason\n"
             "trial1,yes,4.3,0.01,0.088,5593,0.03,1.2,0.1,\"\"\n"
             "trial2,no,NaN,NaN,NaN,NaN,NaN,NaN,NaN,\"force spike\"\n");
  write_text(dir / "fits/model4/fit.json",
             R"({"model": "model4", "parameters": {"k1_n_m": 72000, "r1_n_s_m": 260},
                 "trials": [{"id": "trial1", "rms_force_pct_peak": 4.0}], "warnings": []})");
  write_text(dir / "fits/closed_loop/fit.json",
             R"({"model": "model4", "parameters": {"k1_n_m": 70000, "r1_n_s_m": 250, "k1_cubic_n_m3": 2.6e6},
                 "trials": [{"id": "trial1", "rms_force_pct_peak": 1.5}], "warnings": ["w"]})");
  write_text(dir / "report.html", "<html></html>");
}

// `dropfit table`'s outputs: fit.json with "source": "table", predictions.csv.
void write_table_results(const fs::path& dir) {
  write_text(dir / ".dropfit-output", "Written by dropfit.\n");
  write_text(dir / "fit.json",
             R"({"model": "model1", "source": "table", "parameters": {"k1_n_m": 84000, "r1_n_s_m": 900},
                 "trials": [{"id": "1", "rms_force_pct_peak": null}, {"id": "2", "rms_force_pct_peak": null},
                            {"id": "3", "rms_force_pct_peak": null}],
                 "heldout_peak_force_pct_max": 7.5, "warnings": []})");
  write_text(dir / "predictions.csv", "trial,train\n1,yes\n2,yes\n3,yes\n");
  write_text(dir / "report.html", "<html></html>");
}

TEST(Gather, LabelsAsInTheRunOneRowPerFolderAndTables) {
  TempDir dir;
  write_session_results(dir / "lab" / "sessionA");
  write_table_results(dir / "lab" / "table1");
  // sessionA given itself, again with a trailing slash, and through its parent.
  const CliRun r = run_dropfit({"gather", (dir / "lab" / "sessionA").string(), (dir / "lab" / "sessionA").string() + "/",
                                (dir / "lab").string(), "--out", (dir / "archive").string()},
                               dir.path());
  ASSERT_EQ(r.exit_code, 0) << r.describe();
  EXPECT_NE(r.out.find("2 results folder(s)"), std::string::npos) << r.describe();
  const std::vector<std::string> csv = lines_of(read_text(dir / "archive" / "archive.csv"));
  ASSERT_EQ(csv.size(), 1u + 3u) << read_text(dir / "archive" / "archive.csv");
  EXPECT_EQ(csv[0],
            "session,results,source,trials,accepted,model,fitted_model,k1_cubic_n_m3,k1_n_m,r1_n_s_m,"
            "mean_rms_force_pct_peak,max_rms_force_pct_peak,heldout_peak_force_pct_max,warnings");
  const std::string a = fs::absolute(dir / "lab" / "sessionA").lexically_normal().string();
  const std::string t = fs::absolute(dir / "lab" / "table1").lexically_normal().string();
  EXPECT_EQ(csv[1], "sessionA," + a + ",session,2,1,closed_loop,model4,2.6e+06,70000,250,1.5,1.5,,1");
  EXPECT_EQ(csv[2], "sessionA," + a + ",session,2,1,model4,model4,,72000,260,4,4,,0");
  EXPECT_EQ(csv[3], "table1," + t + ",table,3,3,table:model1,model1,,84000,900,,,7.5,0");
  const std::string html = read_text(dir / "archive" / "archive.html");
  EXPECT_NE(html.find("closed_loop"), std::string::npos);
  EXPECT_NE(html.find("table:model1"), std::string::npos);
}

}  // namespace
}  // namespace dropfit::clitest
