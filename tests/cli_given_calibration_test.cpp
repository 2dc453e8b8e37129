// A lab that calibrated with a wand: DLT coefficients in the manifest
// ([calibration] dlt_coefficients), no calibration frame. The session is a
// short synthetic one whose coefficients are computed here from its own
// frame (calibration::calibrate, as `dropfit calibrate` does), written as
// easyWand writes them, and the frame files deleted. `calibrate`,
// `reconstruct` and `run` must then work, and reconstruct exactly as the
// frame-calibrated session does.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "capture/io.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

// Every number of a CSV text with a header, row by row ("NaN" -> NaN).
std::vector<std::vector<double>> numbers(const std::string& text) {
  std::vector<std::vector<double>> rows;
  std::istringstream in(text);
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::vector<double> row;
    std::istringstream fields(line);
    std::string f;
    while (std::getline(fields, f, ',')) row.push_back(f == "NaN" || f.empty() ? NAN : std::stod(f));
    rows.push_back(row);
  }
  return rows;
}

TEST(CliGivenCalibration, WandCalibratedSessionRunsEndToEnd) {
  TempDir dir;
  const fs::path framed = dir / "framed";
  const fs::path wand = dir / "wand";
  write_synthetic_session(framed);
  write_synthetic_session(wand);

  // The coefficients, from the frame, as `calibrate` computes them.
  const Session s = capture::read_session(wand.string());
  std::vector<calibration::Marker> markers;
  for (const auto& m : s.frame) markers.push_back({m.id, m.lab_m, m.role == MarkerRole::Check});
  std::vector<calibration::CameraView> views;
  for (const auto& image : s.images) {
    calibration::CameraView view{image.camera, {}};
    for (const auto& o : image.observations) view.observations.emplace_back(o.id, o.image_px);
    views.push_back(view);
  }
  const calibration::CalibrationResult cal = calibration::calibrate(markers, views);
  // easyWand's file: 11 rows, one column per camera, no header.
  std::string coefs;
  for (int i = 0; i < 11; ++i) {
    for (std::size_t c = 0; c < cal.cameras.size(); ++c)
      coefs += fmt::format("{}{:.17g}", c ? "," : "", cal.cameras[c].camera.dlt(i));
    coefs += "\n";
  }
  write_text(wand / "calibration" / "wand_dltCoefs.csv", coefs);
  write_text(wand / "session.toml", read_text(wand / "session.toml") +
                                        "\n[calibration]\ndlt_coefficients = \"calibration/wand_dltCoefs.csv\"\n");
  fs::remove(wand / "calibration" / "frame.csv");
  for (const auto& camera : s.manifest.video.cameras) fs::remove(wand / "calibration" / (camera + ".csv"));
  const auto before = listing(wand);

  const CliRun calibrate = run_dropfit({"calibrate", wand.string(), "--out", (dir / "c").string()}, dir.path());
  ASSERT_EQ(calibrate.exit_code, 0) << calibrate.describe();
  EXPECT_NE(calibrate.out.find("coefficients given"), std::string::npos) << calibrate.describe();
  EXPECT_NE(calibrate.out.find("the accuracy was not checked"), std::string::npos) << calibrate.describe();

  const CliRun rec_wand = run_dropfit({"reconstruct", wand.string(), "--out", (dir / "rw").string()}, dir.path());
  ASSERT_EQ(rec_wand.exit_code, 0) << rec_wand.describe();
  const CliRun rec_framed =
      run_dropfit({"reconstruct", framed.string(), "--out", (dir / "rf").string()}, dir.path());
  ASSERT_EQ(rec_framed.exit_code, 0) << rec_framed.describe();
  for (const auto& trial : s.manifest.trials) {
    const auto a = numbers(read_text(dir / "rw" / "trials" / trial.id / "xyzpts.csv"));
    const auto b = numbers(read_text(dir / "rf" / "trials" / trial.id / "xyzpts.csv"));
    ASSERT_EQ(a.size(), b.size());
    ASSERT_GT(a.size(), 100u);
    int finite = 0;
    for (std::size_t r = 0; r < a.size(); ++r) {
      ASSERT_EQ(a[r].size(), b[r].size());
      for (std::size_t c = 0; c < a[r].size(); ++c) {
        if (std::isnan(b[r][c])) {
          EXPECT_TRUE(std::isnan(a[r][c]));
          continue;
        }
        // The same coefficients (written with 17 digits, so exactly) give
        // the same reconstruction; xyzpts prints 9 significant digits of
        // values below 1 m, and 1e-8 m allows for its last digit (any real
        // difference in calibration moves points by 1e-5 m and more).
        EXPECT_NEAR(a[r][c], b[r][c], 1e-8) << trial.id << " row " << r << " column " << c;
        ++finite;
      }
    }
    EXPECT_GT(finite, 1000);
  }

  const CliRun run = run_dropfit({"run", wand.string(), "--out", (dir / "run").string()}, dir.path());
  ASSERT_EQ(run.exit_code, 0) << run.describe();
  EXPECT_NE(run.out.find("2 of 2 trials accepted"), std::string::npos) << run.describe();
  EXPECT_TRUE(fs::exists(dir / "run" / "fit.json")) << run.describe();
  EXPECT_EQ(listing(wand), before);  // the session folder is never modified
}

}  // namespace
}  // namespace dropfit::clitest
