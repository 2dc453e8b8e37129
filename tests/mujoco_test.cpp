// The simulator exports proven in a simulator: each MJCF that
// report::mjcf_xml writes (Models 3 and 4) is loaded in MuJoCo as it is,
// the 24 kg impactor is dropped on it, and the ground reaction force (the
// force the mat's bottom joint passes to the world, zeroed with the mat at
// rest, as the plate reads it) is compared with fitting::simulate of the same
// parameters. Built only when CMake finds MuJoCo (libmujoco-dev).
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "fitting/models.h"
#include "report/export.h"

namespace dropfit {
namespace {

namespace fs = std::filesystem;

struct Trace {
  std::vector<double> t_s, grf_n;
};

// The exported mat with the impactor added as the user of the file would:
// a 24 kg box on a vertical slide joint, its face at the mat's top surface,
// moving down at `velocity_m_s` at t = 0 (first contact). Returns the plate
// force every step for `duration_s`.
Trace drop_in_mujoco(const std::string& mat_xml, double mass_kg, double velocity_m_s, double duration_s,
                     int* bad_acceleration_warnings = nullptr) {
  const std::string impactor = fmt::format(
      "    <body name=\"impactor\" pos=\"0 0 0\">\n"
      "      <joint name=\"impactor_z\" type=\"slide\" axis=\"0 0 1\"/>\n"
      "      <inertial pos=\"0 0 0\" mass=\"{}\" diaginertia=\"1 1 1\"/>\n"
      "      <geom name=\"impactor_face\" type=\"box\" size=\"0.125 0.125 0.05\"/>\n"
      "    </body>\n",
      mass_kg);
  std::string xml = mat_xml;
  const auto at = xml.rfind("  </worldbody>");
  EXPECT_NE(at, std::string::npos);
  xml.insert(at, impactor);
  const fs::path path = fs::temp_directory_path() / fmt::format("dropfit_mujoco_{}.xml", ::getpid());
  std::ofstream(path) << xml;
  char error[1000] = "";
  mjModel* m = mj_loadXML(path.string().c_str(), nullptr, error, sizeof error);
  fs::remove(path);
  EXPECT_NE(m, nullptr) << "MuJoCo refused the exported MJCF: " << error;
  if (!m) return {};
  mjData* d = mj_makeData(m);
  // The mat top: the contact geom's top face, with the mat at rest.
  mj_forward(m, d);
  const int contact = mj_name2id(m, mjOBJ_GEOM, "mat_contact");
  const int imp_body = mj_name2id(m, mjOBJ_BODY, "impactor");
  const int imp_joint = mj_name2id(m, mjOBJ_JOINT, "impactor_z");
  const int bottom_joint = mj_name2id(m, mjOBJ_JOINT, "mat_bottom_z");
  EXPECT_GE(contact, 0);
  EXPECT_GE(bottom_joint, 0);
  const double top_z = d->geom_xpos[3 * contact + 2] + m->geom_size[3 * contact + 2];
  d->qpos[m->jnt_qposadr[imp_joint]] = top_z + 0.05;  // the box's centre: its face on the mat top
  d->qvel[m->jnt_dofadr[imp_joint]] = -velocity_m_s;
  double mat_mass_kg = 0.0;
  for (int b = 1; b < m->nbody; ++b)
    if (b != imp_body) mat_mass_kg += m->body_mass[b];
  const double g = -m->opt.gravity[2];
  const int dof = m->jnt_dofadr[bottom_joint];
  Trace trace;
  while (d->time < duration_s) {
    mj_step(m, d);
    // qfrc_passive: the bottom joint's spring and damper force on the bottom
    // layer, which the ground (the plate) bears; minus the mat's weight.
    trace.t_s.push_back(d->time);
    trace.grf_n.push_back(d->qfrc_passive[dof] - mat_mass_kg * g);
  }
  if (bad_acceleration_warnings) *bad_acceleration_warnings = d->warning[mjWARN_BADQACC].number;
  mj_deleteData(d);
  mj_deleteModel(m);
  return trace;
}

double interpolate(const Trace& tr, double t) {
  if (tr.t_s.empty() || t < tr.t_s.front()) return tr.grf_n.empty() ? NAN : tr.grf_n.front();
  for (std::size_t i = 1; i < tr.t_s.size(); ++i) {
    if (tr.t_s[i] >= t) {
      const double w = (t - tr.t_s[i - 1]) / (tr.t_s[i] - tr.t_s[i - 1]);
      return (1 - w) * tr.grf_n[i - 1] + w * tr.grf_n[i];
    }
  }
  return tr.grf_n.back();
}

void expect_mujoco_matches_simulate(fitting::ModelKind kind, double velocity_m_s) {
  const fitting::MatParams p = fitting::paper_table2(kind);
  const std::string xml = report::mjcf_xml(kind, p, report::MatGeometry{});
  const double duration_s = 0.25;
  const Trace mj = drop_in_mujoco(xml, 24.0, velocity_m_s, duration_s);
  ASSERT_FALSE(mj.t_s.empty());
  fitting::Impact impact;
  impact.mass_kg = 24.0;
  impact.velocity_m_s = velocity_m_s;
  impact.gravity_m_s2 = 9.81;
  impact.duration_s = duration_s;
  impact.output_dt_s = 2.5e-4;
  const fitting::Simulation ref = fitting::simulate(kind, p, impact);
  const double peak = ref.grf_n.maxCoeff();
  double worst = 0.0, worst_t = 0.0, mj_peak = 0.0;
  for (Eigen::Index i = 0; i < ref.t_s.size(); ++i) {
    const double f = interpolate(mj, ref.t_s[i]);
    mj_peak = std::max(mj_peak, f);
    if (std::abs(f - ref.grf_n[i]) > worst) {
      worst = std::abs(f - ref.grf_n[i]);
      worst_t = ref.t_s[i];
    }
  }
  const std::string name = fitting::model_name(kind);
  ::testing::Test::RecordProperty(name + "_worst_pct_of_peak", std::to_string(100.0 * worst / peak));
  ::testing::Test::RecordProperty(name + "_peak_n", std::to_string(peak));
  ::testing::Test::RecordProperty(name + "_mujoco_peak_n", std::to_string(mj_peak));
  // The bar: the simulator's ground reaction within 1 % of the peak at every
  // instant of the contact and after. Measured: Model 4 0.22 %, Model 3
  // 0.32 % (the stiff but not rigid contact and the 0.01 kg surface body);
  // with a 1e-4 s timestep and solref 2e-4 s the same drop is off by 3.3 %
  // and 2.3 %; with the contact parameters mixed with the impactor's
  // defaults (no priority) by 39 % (Model 3) and more than the peak (Model 4).
  EXPECT_LE(worst, 0.01 * peak) << name << ": largest |MuJoCo - simulate| " << worst << " N at " << worst_t * 1e3
                                << " ms; peak " << peak << " N (MuJoCo " << mj_peak << " N)";
}

TEST(MuJoCoExport, Model4DropMatchesSimulateWithinOnePercentOfPeak) {
  expect_mujoco_matches_simulate(fitting::ModelKind::Model4, 5.0);
}

TEST(MuJoCoExport, Model3DropMatchesSimulateWithinOnePercentOfPeak) {
  expect_mujoco_matches_simulate(fitting::ModelKind::Model3, 5.0);
}

// The file's stated stable step is the real limit of its springs: a stiff
// surface spring (k1 at the fitter's upper bound, 3e7 N/m, on the 0.01 kg
// surface body) with light damping integrates with bounded forces a little
// below the stated step and blows up a little above it. The exported file
// itself runs at a quarter of it.
TEST(MuJoCoExport, TheStatedStableTimestepIsTheLimit) {
  fitting::MatParams p = fitting::paper_table2(fitting::ModelKind::Model4);
  p.k1_n_m = 3e7;
  p.r1_n_s_m = p.r2_n_s_m = p.r3_n_s_m = 3.0;
  const std::string xml = report::mjcf_xml(fitting::ModelKind::Model4, p, report::MatGeometry{});
  const double limit_s = report::mjcf_max_stable_timestep_s(fitting::ModelKind::Model4, p);
  // omega of the 0.01 kg body on 3e7 N/m above a much heavier layer: about
  // sqrt(3e7 / 0.01) = 5.5e4 rad/s, so the limit is close to 2 / 5.5e4 s.
  EXPECT_NEAR(limit_s, 2.0 / std::sqrt(3e7 / 0.01), 0.02 * limit_s);
  EXPECT_NE(xml.find(fmt::format("data=\"{:.6g}\"", limit_s)), std::string::npos);
  EXPECT_NE(xml.find(fmt::format("timestep=\"{:.6g}\"", 0.25 * limit_s)), std::string::npos);
  auto with_step = [&](double step_s) {
    std::string x = xml;
    const auto at = x.find("timestep=\"");
    const auto end = x.find('"', at + 10);
    x.replace(at + 10, end - at - 10, fmt::format("{:.9g}", step_s));
    return x;
  };
  auto worst = [](const Trace& t) {
    double w = 0.0;
    for (double f : t.grf_n) w = std::isfinite(f) ? std::max(w, std::abs(f)) : INFINITY;
    return w;
  };
  int warnings_below = 0, warnings_above = 0;
  const Trace below = drop_in_mujoco(with_step(0.9 * limit_s), 24.0, 4.0, 0.05, &warnings_below);
  const Trace above = drop_in_mujoco(with_step(1.2 * limit_s), 24.0, 4.0, 0.05, &warnings_above);
  // A 4 m/s drop on this mat peaks near 5 kN; unstable integration grows
  // without bound (MuJoCo then warns of a bad acceleration and resets).
  EXPECT_EQ(warnings_below, 0);
  EXPECT_LT(worst(below), 2e4);
  EXPECT_TRUE(warnings_above > 0 || worst(above) > 1e6) << "worst " << worst(above) << " N";
}

}  // namespace
}  // namespace dropfit
