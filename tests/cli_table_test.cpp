// `dropfit table` end to end on the paper's Table 1 (samples/paper/table1.csv):
// the leave-one-out peak-force errors in fit.json against the same errors
// computed here, independently, with fitting::fit_table from a different
// starting point; the report shows them; bad rows are refused with the
// file, line, column and field, and nothing is written.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "fitting/table_fit.h"
#include "fitting/models.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

using nlohmann::json;

const fs::path kTable1 = fs::path(DROPFIT_SOURCE_DIR) / "samples" / "paper" / "table1.csv";

// The table read here with a few lines of our own (not report::parse_impact_table).
std::vector<fitting::TableTrial> read_table1() {
  std::istringstream in(read_text(kTable1));
  std::string line;
  std::getline(in, line);  // header: trial,impact_velocity_m_s,max_deformation_m,peak_force_n
  std::vector<fitting::TableTrial> out;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::stringstream ss(line);
    std::string cell[4];
    for (auto& c : cell) std::getline(ss, c, ',');
    out.push_back({cell[0], std::stod(cell[1]), std::stod(cell[2]), std::stod(cell[3])});
  }
  return out;
}

TEST(CliTable, LeaveOneOutErrorsMatchAnIndependentFitAndAppearInTheReport) {
  TempDir dir;
  const fs::path out = dir / "out";
  const CliRun run = run_dropfit({"table", kTable1.string(), "--out", out.string()}, dir.path());
  ASSERT_EQ(run.exit_code, 0) << run.describe();
  const json doc = json::parse(read_text(out / "fit.json"));
  EXPECT_EQ(doc.at("model"), "model1");
  EXPECT_EQ(doc.at("train"), json::array({"3"})) << "default: the median-velocity impact";
  ASSERT_EQ(doc.at("leave_one_out").size(), 5u);

  const auto table = read_table1();
  ASSERT_EQ(table.size(), 5u);
  const std::string html = read_text(out / "report.html");
  double worst_diff = 0.0;
  for (std::size_t i = 0; i < table.size(); ++i) {
    // The command's left-out fit, as the library makes it from the
    // command's own options, must be what the file says; and an independent
    // search (another start, 20 random starts, another seed) must find no
    // better optimum of the same cost: the table-mode cost has more than one
    // minimum (a stiff spring and a damper-dominated one) and a flat valley,
    // so the optima are compared by their cost, not by their parameters.
    fitting::TableFitOptions mine = fitting::table_options(fitting::ModelKind::Model1, 24.0, 2.44, 3.66);
    for (std::size_t j = 0; j < table.size(); ++j)
      if (j != i) mine.train_ids.push_back(table[j].id);
    const fitting::TableFitResult command_fit = fitting::fit_table(table, mine);
    fitting::TableFitOptions o = mine;
    o.base.k1_n_m = 80000.0;
    o.base.r1_n_s_m = 500.0;
    o.starts = 20;
    o.seed = 42;
    const fitting::TableFitResult fit = fitting::fit_table(table, o);

    const json& held = doc["leave_one_out"][i];
    ASSERT_EQ(held.at("held_out"), table[i].id);
    const double got = held.at("peak_force_pct_diff").get<double>();
    EXPECT_NEAR(got, command_fit.trials[i].peak_force_pct_diff, 1e-9) << "impact " << table[i].id;
    // No clearly better optimum than the command's. The cost is the
    // simulated peak and deepest travel of a sampled simulation, a surface
    // with kinks where the peak moves from one sample to the next, so
    // Levenberg-Marquardt stalls within a few tenths of a per cent of the
    // valley's floor (docs/models.md, table mode).
    EXPECT_LE(command_fit.cost, fit.cost * 1.005) << "impact " << table[i].id;
    worst_diff = std::max(worst_diff, std::abs(got - fit.trials[i].peak_force_pct_diff));
    // The report shows each left-out error as the command prints it.
    EXPECT_NE(html.find(fmt::format("{:+.1f}", got)), std::string::npos) << "report lacks " << got;
  }
  RecordProperty("worst_loo_pct_point_difference", std::to_string(worst_diff));
  // The summary numbers agree with the rows.
  double max_abs = 0.0;
  for (const auto& h : doc["leave_one_out"]) max_abs = std::max(max_abs, std::abs(h["peak_force_pct_diff"].get<double>()));
  EXPECT_DOUBLE_EQ(doc.at("heldout_peak_force_pct_max").get<double>(), max_abs);
  EXPECT_NE(html.find("Leave one out"), std::string::npos);
  EXPECT_NE(html.find(fmt::format("Largest |error| {:.1f} %", max_abs)), std::string::npos);
  // The linear model's known failure on Table 1 (the paper's reason for
  // more elements): it over-predicts the slowest impact and under-predicts
  // the fastest when left out.
  EXPECT_GT(doc["leave_one_out"][0]["peak_force_pct_diff"].get<double>(), 2.0);
  EXPECT_LT(doc["leave_one_out"][4]["peak_force_pct_diff"].get<double>(), -2.0);
  // Closing the loop ran (diagnosis' table stage) and reached the report.
  const json loop = json::parse(read_text(out / "diagnosis.json"));
  EXPECT_EQ(loop.at("baseline_model"), "model1");
  EXPECT_NE(html.find("Closing the loop"), std::string::npos);
  // fit.json is a parameter file `dropfit simulate` takes: trial 3 (the
  // training impact, matched exactly) comes back at its measured peak.
  const CliRun sim = run_dropfit({"simulate", "--params", (out / "fit.json").string(), "--velocity", "5.25", "--dt",
                                  "0.0005", "--out", (dir / "sim.csv").string()},
                                 dir.path());
  ASSERT_EQ(sim.exit_code, 0) << sim.describe();
  std::istringstream csv(read_text(dir / "sim.csv"));
  std::string line;
  std::getline(csv, line);
  double peak = 0.0;
  while (std::getline(csv, line)) peak = std::max(peak, std::stod(line.substr(line.find(',') + 1)));
  EXPECT_NEAR(peak, 7054.0, 7.0);  // 0.1 %: the fit matches its one training impact to ~1 N
}

struct BadTable {
  const char* name;
  std::string text;
  std::string where;  // expected in the error: file:line[:column] [field]
};

TEST(CliTable, BadRowsNameFileLineAndFieldAndWriteNothing) {
  const std::string header = "trial,impact_velocity_m_s,max_deformation_m,peak_force_n\n";
  const std::vector<BadTable> cases = {
      {"not_a_number", header + "1,4.30,0.088,5593\n2,4.8x,0.099,6341\n3,5.25,0.100,7054\n",
       ":3:2 [impact_velocity_m_s]"},
      {"negative_force", header + "1,4.30,0.088,5593\n2,4.80,0.099,-6341\n3,5.25,0.100,7054\n", ":3:4 [peak_force_n]"},
      {"duplicate_trial", header + "1,4.30,0.088,5593\n1,4.80,0.099,6341\n3,5.25,0.100,7054\n", ":3:1 [trial]"},
      {"millimetres", header + "1,4.30,88,5593\n2,4.80,99,6341\n3,5.25,100,7054\n", ":2:3 [max_deformation_m]"},
      {"missing_column", "trial,impact_velocity_m_s,max_deformation_m\n1,4.3,0.088\n", ":1 [peak_force_n]"},
      {"unknown_column", "trial,impact_velocity,peak_force_n\n1,4.3,5593\n", ":1:2 [impact_velocity]"},
      {"short_row", header + "1,4.30,0.088,5593\n2,4.80,0.099\n", ":3: 3 fields"},
  };
  for (const auto& c : cases) {
    TempDir dir;
    const fs::path table = dir / (std::string(c.name) + ".csv");
    write_text(table, c.text);
    const fs::path out = dir / "out";
    const CliRun run = run_dropfit({"table", table.string(), "--out", out.string()}, dir.path());
    expect_one_line_error(run);
    EXPECT_NE(run.err.find(table.string() + c.where), std::string::npos) << c.name << ": " << run.err;
    EXPECT_FALSE(fs::exists(out)) << c.name << ": nothing written";
  }
}

}  // namespace
}  // namespace dropfit::clitest
