// The report's building blocks: axis ticks, SVG plots, HTML assembly and
// the all-or-nothing output set.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <vector>

#include "core/error.h"
#include "report/html.h"
#include "report/output.h"
#include "report/plot.h"
#include "report/results.h"
#include "report/session_report.h"

namespace fs = std::filesystem;
using namespace dropfit::report;

TEST(NiceTicks, CoverTheRangeWithRoundSteps) {
  const auto ticks = nice_ticks(0.0, 7054.0);
  ASSERT_GE(ticks.size(), 4u);
  EXPECT_LE(ticks.front(), 0.0);
  EXPECT_GE(ticks.back(), 7054.0);
  const double step = ticks[1] - ticks[0];
  EXPECT_DOUBLE_EQ(step, 2000.0);  // 0, 2000, ..., 8000
}

TEST(LinePlot, DrawsOnePathPerSeriesAndBreaksAtGaps) {
  LinePlot plot{"GRF", "time (ms)", "force (N)", {}, 640, 360};
  const double nan = std::numeric_limits<double>::quiet_NaN();
  plot.series.push_back({"measured", {0, 1, 2, 3, 4}, {0, 10, nan, 30, 40}, "", false, false});
  plot.series.push_back({"model 4", {0, 1, 2, 3, 4}, {0, 12, 22, 31, 39}, "", true, false});
  const std::string s = svg(plot);
  size_t paths = 0;
  for (size_t pos = s.find("class=\"series\""); pos != std::string::npos; pos = s.find("class=\"series\"", pos + 1)) {
    ++paths;
  }
  EXPECT_EQ(paths, 2u);
  // The gap at x = 2 starts a new sub-path: two "M" commands in the first series.
  const size_t first = s.find("class=\"series\" d=\"");
  const size_t end = s.find('"', first + 18);
  const std::string d = s.substr(first + 18, end - first - 18);
  EXPECT_EQ(std::count(d.begin(), d.end(), 'M'), 2);
  EXPECT_NE(s.find("time (ms)"), std::string::npos);
  EXPECT_NE(s.find("model 4"), std::string::npos);
}

TEST(BarPlot, OneBarPerFiniteValue) {
  BarPlot plot{"check markers", "error (mm)", {"c02", "c04", "c06"}, {}, 640, 320};
  plot.groups.push_back({"x", {0.1, -0.2, 0.3}, ""});
  plot.groups.push_back({"y", {0.2, std::nan(""), 0.1}, ""});
  const std::string s = svg(plot);
  size_t bars = 0;
  for (size_t pos = s.find("class=\"bar\""); pos != std::string::npos; pos = s.find("class=\"bar\"", pos + 1)) ++bars;
  EXPECT_EQ(bars, 5u);
}

TEST(HtmlDocument, EscapesTextAndNumbersFigures) {
  HtmlDocument doc("Mat <report>");
  doc.paragraph("k1 < k2 & r1 > 0");
  doc.figure("<svg></svg>", "first");
  doc.figure("<svg></svg>", "second");
  const std::string html = doc.str();
  EXPECT_NE(html.find("Mat &lt;report&gt;"), std::string::npos);
  EXPECT_NE(html.find("k1 &lt; k2 &amp; r1 &gt; 0"), std::string::npos);
  EXPECT_NE(html.find("Figure 2. second"), std::string::npos);
  EXPECT_EQ(html.find("<script"), std::string::npos);
}

TEST(OutputSet, RefusesToWriteIntoTheSessionFolder) {
  const fs::path root = fs::temp_directory_path() / "dropfit-output-test";
  fs::remove_all(root);
  fs::create_directories(root / "session");
  OutputSet out;
  out.add("calibration.json", "{}\n");
  EXPECT_THROW(out.commit((root / "session" / "out").string(), {(root / "session").string()}), dropfit::Error);
  EXPECT_FALSE(fs::exists(root / "session" / "out"));
  out.commit((root / "out").string(), {(root / "session").string()});
  std::ifstream in(root / "out" / "calibration.json");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text, "{}\n");
  fs::remove_all(root);
}

TEST(OutputSet, WritesNothingWhenOneFileCannotBeWritten) {
  const fs::path root = fs::temp_directory_path() / "dropfit-output-partial-test";
  fs::remove_all(root);
  fs::create_directories(root / "out");
  std::ofstream(root / "out" / "trials") << "a file where a folder must go";
  OutputSet out;
  out.add("calibration.json", "{}\n");
  out.add("summary.csv", "trial\n");
  out.add("trials/trial1/trial.json", "{}\n");
  EXPECT_THROW(out.commit((root / "out").string()), dropfit::Error);
  EXPECT_FALSE(fs::exists(root / "out" / "calibration.json"));
  EXPECT_FALSE(fs::exists(root / "out" / "summary.csv"));
  size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(root / "out")) ++entries;
  EXPECT_EQ(entries, 1u);  // only the file that was in the way; no temporary left
  fs::remove_all(root);
}

// The fit's series carry the layers' travel (what the mat-surface markers
// see, through the dish) beside the measured surface, one row a sample,
// the measured gaps empty.
TEST(FitSeriesCsv, CarriesTheLayersTravelBesideTheMeasuredSurface) {
  dropfit::fitting::TrialData measured;
  measured.t_s = Eigen::Vector3d(-0.001, 0.0, 0.001);
  measured.grf_n = Eigen::Vector3d(0.0, 5.0, 400.0);
  measured.impactor_m = Eigen::Vector3d(-0.004, 0.0, 0.004);
  measured.surface_m = Eigen::Vector3d(0.0, std::numeric_limits<double>::quiet_NaN(), 0.0005);
  dropfit::fitting::TrialReport rep;
  rep.simulation.t_s = measured.t_s;
  rep.simulation.grf_n = Eigen::Vector3d(0.0, 0.0, 410.0);
  rep.simulation.impactor_m = Eigen::Vector3d(-0.004, 0.0, 0.0041);
  rep.simulation.surface_m = Eigen::Vector3d(0.0, 0.0, 0.0041);
  rep.simulation.layer1_m = Eigen::Vector3d(0.0, 0.0, 0.0007);
  rep.simulation.layer2_m = Eigen::Vector3d(0.0, 0.0, 0.0002);
  rep.prediction.force_low_n = Eigen::Vector3d(0.0, 0.0, 395.0);
  rep.prediction.force_high_n = Eigen::Vector3d(0.0, 0.0, 425.0);
  const std::string csv = fit_series_csv(measured, rep);
  std::istringstream in(csv);
  std::string header, row;
  std::getline(in, header);
  EXPECT_EQ(header,
            "t_s,measured_fz_n,simulated_fz_n,measured_impactor_m,simulated_impactor_m,measured_surface_m,"
            "simulated_surface_m,simulated_layer1_m,simulated_layer2_m,simulated_fz_low_n,simulated_fz_high_n");
  int rows = 0;
  std::string last;
  while (std::getline(in, row)) {
    ++rows;
    last = row;
    EXPECT_EQ(std::count(row.begin(), row.end(), ','), 10) << row;
  }
  EXPECT_EQ(rows, 3);
  // The last row's two layer columns (within 1e-12 m) and the force band.
  std::vector<double> cols;
  std::istringstream fields(last);
  for (std::string f; std::getline(fields, f, ',');) cols.push_back(std::stod(f));
  ASSERT_EQ(cols.size(), 11u);
  EXPECT_NEAR(cols[7], 0.0007, 1e-12);
  EXPECT_NEAR(cols[8], 0.0002, 1e-12);
  EXPECT_NEAR(cols[9], 395.0, 1e-9);
  EXPECT_NEAR(cols[10], 425.0, 1e-9);
}

// A session whose calibration could not be checked: the report says where the
// impact velocity's calibration term comes from (the trials' own words), and
// says nothing of the kind when the check markers measured it.
TEST(SessionReportHtml, SaysWhenTheCalibrationTermIsDeclared) {
  SessionReport r;
  r.session_name = "s";
  r.trials.resize(1);
  r.trials[0].calibration_uncertainty = "declared: the calibration was not checked";
  EXPECT_NE(session_report_html(r).find("Impact velocity intervals: declared: the calibration was not checked."),
            std::string::npos);
  r.trials[0].calibration_uncertainty = "check markers";
  EXPECT_EQ(session_report_html(r).find("Impact velocity intervals:"), std::string::npos);
}

// The held-out residual's map: one row per model naming its form and the
// term it calls for with each axis's r2, one figure per axis with a series
// per model; nothing without maps.
TEST(SessionReportHtml, ShowsTheHeldOutResidualMap) {
  SessionReport r;
  r.session_name = "s";
  EXPECT_EQ(session_report_html(r).find("The held-out residual's form"), std::string::npos);
  ResidualForm f{"closed_loop", "elastic", "a densification term", 0.12, {}};
  f.axes.push_back({"deflection_m", {0.01, 0.02, 0.03}, {-1.0, 0.5, 4.0}, 0.62});
  f.axes.push_back({"deflection_rate_m_s", {-1.0, 1.0}, {0.1, -0.1}, 0.05});
  f.axes.push_back({"time_since_contact_s", {0.005, 0.015}, {0.3, 0.2}, 0.08});
  f.axes.push_back({"recording_order", {0, 1, 3}, {0.2, 0.1, 0.0}, 0.4});
  ResidualForm g = f;
  g.model = "model6";
  g.form = "none";
  r.residual_forms = {f, g};
  const std::string html = session_report_html(r);
  EXPECT_NE(html.find("<td>closed_loop</td><td>elastic</td><td>a densification term</td><td class=\"num\">0.62</td>"
                      "<td class=\"num\">0.05</td><td class=\"num\">0.08</td><td class=\"num\">0.40</td>"
                      "<td class=\"num\">0.12</td>"),
            std::string::npos);
  EXPECT_NE(html.find("<td>model6</td><td>none</td>"), std::string::npos);
  for (const char* axis : {"deflection (mm)", "deflection rate (m/s, + loading)", "time since contact (ms)",
                           "trial's place in the recording (0 = first)"})
    EXPECT_NE(html.find(std::string("Held-out residual against ") + axis), std::string::npos) << axis;
  EXPECT_NE(html.find("closed_loop (r2 0.62)"), std::string::npos);
  EXPECT_NE(html.find("model6 (r2 0.62)"), std::string::npos);
}
