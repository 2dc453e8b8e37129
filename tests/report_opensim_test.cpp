// The version-2 output writers on values with known answers: DLT
// coefficients converted to a bottom-left image origin, DLTdv's xyzres.csv,
// and the OpenSim TRC and ExternalLoads .mot files parsed back.
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "core/error.h"
#include "report/opensim.h"
#include "report/results.h"
#include "support/cameras.h"

namespace dropfit {
namespace {

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) out.push_back(line);
  return out;
}

std::vector<std::string> fields(const std::string& line, char sep) {
  std::vector<std::string> out;
  std::string f;
  std::istringstream in(line);
  while (std::getline(in, f, sep)) out.push_back(f);
  if (!line.empty() && line.back() == sep) out.emplace_back();
  return out;
}

calibration::Camera pinhole_camera(int index) {
  const auto cams = testsupport::two_cameras();
  return calibration::Camera::from_image_from_lab(cams[index].name, cams[index].image_from_lab());
}

// u, v of the 11-coefficient DLT as the spec writes it.
Eigen::Vector2d dlt_project(const calibration::Dlt11& L, const Eigen::Vector3d& X) {
  const double d = L[8] * X.x() + L[9] * X.y() + L[10] * X.z() + 1.0;
  return {(L[0] * X.x() + L[1] * X.y() + L[2] * X.z() + L[3]) / d,
          (L[4] * X.x() + L[5] * X.y() + L[6] * X.z() + L[7]) / d};
}

TEST(ReportDlt, BottomLeftCoefficientsGiveHeightMinusV) {
  const double height_px = 1024.0;
  for (int c = 0; c < 2; ++c) {
    const calibration::Camera camera = pinhole_camera(c);
    const calibration::Dlt11 bl = report::dlt_bottom_left(camera.dlt, height_px);
    for (const Eigen::Vector3d& X : {Eigen::Vector3d(0.1, -0.2, 0.3), Eigen::Vector3d(-0.4, 0.25, 0.0),
                                    Eigen::Vector3d(0.45, 0.3, 0.8)}) {
      const Eigen::Vector2d top = dlt_project(camera.dlt, X);
      const Eigen::Vector2d bottom = dlt_project(bl, X);
      // Exact algebra: only rounding (pixel values ~1e3, coefficients ~1e3).
      EXPECT_NEAR(bottom.x(), top.x(), 1e-9) << "u unchanged";
      EXPECT_NEAR(bottom.y(), height_px - top.y(), 1e-9) << "v' = H - v";
      EXPECT_GT(std::abs(bottom.y() - top.y()), 1.0) << "the test point is not on the mid-line";
    }
    // Its own inverse.
    EXPECT_LT((report::dlt_bottom_left(bl, height_px) - camera.dlt).norm(), 1e-9 * camera.dlt.norm());
  }
}

TEST(ReportDlt, CoefficientFileHasNoHeaderElevenRowsOneColumnPerCamera) {
  const std::vector<calibration::Camera> cams = {pinhole_camera(0), pinhole_camera(1)};
  const auto top = lines_of(report::dlt_coefficients_csv(cams));
  const auto bottom = lines_of(report::dlt_coefficients_csv(cams, 1024.0));
  ASSERT_EQ(top.size(), 11u);
  ASSERT_EQ(bottom.size(), 11u);
  for (int i = 0; i < 11; ++i) {
    const auto t = fields(top[i], ','), b = fields(bottom[i], ',');
    ASSERT_EQ(t.size(), 2u);
    ASSERT_EQ(b.size(), 2u);
    for (int c = 0; c < 2; ++c) {
      const double expect_top = cams[c].dlt[i];
      const double expect_bottom = report::dlt_bottom_left(cams[c].dlt, 1024.0)[i];
      // Written with 15 significant digits.
      EXPECT_NEAR(std::stod(t[c]), expect_top, 1e-13 * std::max(1.0, std::abs(expect_top))) << i;
      EXPECT_NEAR(std::stod(b[c]), expect_bottom, 1e-13 * std::max(1.0, std::abs(expect_bottom))) << i;
    }
  }
}

reconstruction::Trajectories two_point_trajectories() {
  reconstruction::Trajectories t;
  t.lab_m.resize(3, 6);
  t.lab_m << 0.1, 0.2, 0.3, -0.1, -0.2, 0.5,  //
      0.11, 0.21, 0.29, NAN, NAN, NAN,          //
      0.12, 0.22, 0.28, -0.12, -0.22, 0.45;
  t.residual_px.resize(3, 2);
  t.residual_px << 0.25, 0.5, 0.3, NAN, 0.125, 0.75;
  return t;
}

TEST(ReportDltdv, XyzresNamesColumnsAfterThePointsWithDltres) {
  const auto lines = lines_of(report::xyzres_csv(two_point_trajectories(), {"imp_front"}));
  ASSERT_EQ(lines.size(), 4u);
  EXPECT_EQ(lines[0], "imp_front_dltres,pt2_dltres");
  EXPECT_EQ(lines[1], "0.25,0.5");
  EXPECT_EQ(lines[2], "0.3,NaN");
}

TEST(ReportOpenSim, TrcHeaderAndMillimetresInOpenSimsFrame) {
  const auto traj = two_point_trajectories();
  Eigen::VectorXd times(3);
  times << -0.002, -0.001, 0.0;
  const std::string text = report::markers_trc(traj, {"a", "b"}, times, 1000.0);
  const auto lines = lines_of(text);
  ASSERT_EQ(lines.size(), 5u + 3u);
  EXPECT_EQ(fields(lines[0], '\t'), (std::vector<std::string>{"PathFileType", "4", "(X/Y/Z)", "markers.trc"}));
  const auto keys = fields(lines[1], '\t'), values = fields(lines[2], '\t');
  ASSERT_EQ(keys.size(), 8u);
  ASSERT_EQ(values.size(), 8u);
  std::map<std::string, std::string> header;
  for (int i = 0; i < 8; ++i) header[keys[i]] = values[i];
  EXPECT_EQ(header["DataRate"], "1000");
  EXPECT_EQ(header["CameraRate"], "1000");
  EXPECT_EQ(header["NumFrames"], "3");
  EXPECT_EQ(header["NumMarkers"], "2");
  EXPECT_EQ(header["Units"], "mm");
  EXPECT_EQ(header["OrigDataStartFrame"], "1");
  EXPECT_EQ(fields(lines[3], '\t'), (std::vector<std::string>{"Frame#", "Time", "a", "", "", "b", "", ""}));
  EXPECT_EQ(fields(lines[4], '\t'), (std::vector<std::string>{"", "", "X1", "Y1", "Z1", "X2", "Y2", "Z2"}));
  for (int f = 0; f < 3; ++f) {
    const auto row = fields(lines[5 + f], '\t');
    ASSERT_EQ(row.size(), 8u);
    EXPECT_EQ(std::stoi(row[0]), f + 1);
    EXPECT_DOUBLE_EQ(std::stod(row[1]), times[f]);
    for (int p = 0; p < 2; ++p) {
      const Eigen::Vector3d lab = traj.point(f, p);
      const double x = std::stod(row[2 + 3 * p]), y = std::stod(row[3 + 3 * p]), z = std::stod(row[4 + 3 * p]);
      if (!lab.allFinite()) {
        EXPECT_TRUE(std::isnan(x) && std::isnan(y) && std::isnan(z)) << "a gap stays a gap";
        continue;
      }
      // OpenSim: x = lab X, y = lab Z (up), z = -lab Y; millimetres (9 digits).
      EXPECT_NEAR(x, 1e3 * lab.x(), 1e-6);
      EXPECT_NEAR(y, 1e3 * lab.z(), 1e-6);
      EXPECT_NEAR(z, -1e3 * lab.y(), 1e-6);
    }
  }
  EXPECT_THROW(report::markers_trc(traj, {}, Eigen::VectorXd::Zero(2), 1000.0), Error);
}

// A load at a known point (cx, cy) with a known free moment T about the
// vertical: the plate's moments about its centre are Mz = cx Fy - cy Fx + T,
// and the COP is (cx, cy). ground_reaction must give back the point and T.
TEST(ReportOpenSim, GroundReactionRecoversPointAndFreeMoment) {
  forceplate::Resultants plate;
  plate.t_s = Eigen::VectorXd::LinSpaced(2, 0.0, 0.001);
  plate.f_n.resize(2, 3);
  plate.f_n << 30.0, -40.0, 2000.0, 1.0, 1.0, 10.0;
  const double cx = 0.05, cy = -0.08, free_moment = 3.5;
  plate.m_n_m.resize(2, 3);
  plate.m_n_m << 0.0, 0.0, cx * -40.0 - cy * 30.0 + free_moment, 0.0, 0.0, 0.0;
  plate.cop_m.resize(2, 2);
  plate.cop_m << cx, cy, NAN, NAN;  // second sample below the COP threshold
  const auto g = report::ground_reaction(plate, 0);
  EXPECT_NEAR(g.point_m.x(), cx, 1e-15);
  EXPECT_NEAR(g.point_m.y(), cy, 1e-15);
  EXPECT_EQ(g.point_m.z(), 0.0);
  EXPECT_NEAR(g.torque_n_m.z(), free_moment, 1e-12);
  const auto quiet = report::ground_reaction(plate, 1);
  EXPECT_TRUE(quiet.point_m.isZero()) << "no NaN for OpenSim where the COP is undefined";

  forceplate::ForceTrial trial;
  trial.plate = plate;
  const auto lines = lines_of(report::grf_mot(trial));
  ASSERT_EQ(lines.size(), 7u + 2u);
  EXPECT_EQ(lines[0], "grf.mot");
  EXPECT_EQ(lines[1], "version=1");
  EXPECT_EQ(lines[2], "nRows=2");
  EXPECT_EQ(lines[3], "nColumns=10");
  EXPECT_EQ(lines[4], "inDegrees=no");
  EXPECT_EQ(lines[5], "endheader");
  EXPECT_EQ(fields(lines[6], '\t'),
            (std::vector<std::string>{"time", "ground_force_vx", "ground_force_vy", "ground_force_vz",
                                      "ground_force_px", "ground_force_py", "ground_force_pz", "ground_torque_x",
                                      "ground_torque_y", "ground_torque_z"}));
  const auto row = fields(lines[7], '\t');
  ASSERT_EQ(row.size(), 10u);
  std::vector<double> v;
  for (const auto& f : row) v.push_back(std::stod(f));
  // OpenSim frame: (x, y, z) = (lab X, lab Z, -lab Y).
  EXPECT_DOUBLE_EQ(v[1], 30.0);
  EXPECT_DOUBLE_EQ(v[2], 2000.0);
  EXPECT_DOUBLE_EQ(v[3], 40.0);
  EXPECT_DOUBLE_EQ(v[4], cx);
  EXPECT_DOUBLE_EQ(v[5], 0.0);
  EXPECT_DOUBLE_EQ(v[6], -cy);
  EXPECT_DOUBLE_EQ(v[7], 0.0);
  EXPECT_NEAR(v[8], free_moment, 1e-8);
  EXPECT_DOUBLE_EQ(v[9], 0.0);
}

// A BioWare export of Fx Fy Fz only: no centre of pressure. Every loaded
// sample's point and torque are NaN in grf.mot, never the plate centre.
TEST(ReportOpenSim, NoMomentsNoPlateCentreCentreOfPressure) {
  Eigen::MatrixXd columns = Eigen::MatrixXd::Constant(3, 8, NAN);
  columns.leftCols(3) << 10.0, 5.0, 900.0, 12.0, 4.0, 2400.0, 0.0, 0.0, 1.0;
  const forceplate::Resultants plate =
      forceplate::from_resultant_columns(Eigen::VectorXd::LinSpaced(3, 0.0, 0.002), columns);
  ASSERT_FALSE(plate.cop_unavailable.empty());
  forceplate::ForceTrial trial;
  trial.plate = plate;
  const auto lines = lines_of(report::grf_mot(trial));
  ASSERT_EQ(lines.size(), 7u + 3u);
  for (std::size_t r = 7; r < 10; ++r) {
    const auto row = fields(lines[r], '\t');
    ASSERT_EQ(row.size(), 10u);
    EXPECT_NE(row[2], "NaN") << "the force is known";
    for (std::size_t c = 4; c < 10; ++c) EXPECT_EQ(row[c], "NaN") << lines[r];
  }
  EXPECT_DOUBLE_EQ(std::stod(fields(lines[8], '\t')[2]), 2400.0);
}

}  // namespace
}  // namespace dropfit
