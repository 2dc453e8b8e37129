// A session whose trials bring 3-D markers from an optoelectronic system
// (markers.c3d) in place of camera tracks and a calibration, through the
// whole pipeline. The markers are the demo session's own trajectories as
// its cameras reconstruct them, written as motion-capture systems write
// C3D files (floating point in mm, or integers at 0.1 mm per count; labels
// upper case; the residual word -1 where a marker was lost): the same
// drops measured by another system must give the same trials and mat.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "capture/io.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"
#include "support/c3d_writer.h"
#include "support/temp_dir.h"

namespace dropfit {
namespace {

namespace fs = std::filesystem;
const fs::path kDemo = fs::path(DROPFIT_SOURCE_DIR) / "samples" / "demo-session";

// One trial's trajectories (metres, NaN in gaps) as a C3D POINT section.
std::string markers_c3d(const reconstruction::Trajectories& t, const std::vector<std::string>& labels,
                        double rate_hz, bool float_data) {
  using namespace testsupport::c3d;
  Spec s;
  s.processor = C3dProcessor::Intel;
  s.float_data = float_data;
  s.point_scale = 0.1;  // mm per count (integer files); the residual's unit in both
  s.point_rate_hz = rate_hz;
  s.n_frames = t.n_frames();
  s.n_points = t.n_points();
  s.n_analog = 0;
  s.analog_per_frame = 0;
  s.points.resize(s.n_frames, 4 * s.n_points);
  for (int f = 0; f < s.n_frames; ++f) {
    for (int p = 0; p < s.n_points; ++p) {
      const bool seen = t.point(f, p).allFinite();
      for (int k = 0; k < 3; ++k) {
        const double mm = seen ? 1e3 * t.lab_m(f, 3 * p + k) : 0.0;
        s.points(f, 4 * p + k) = float_data ? mm : std::round(mm / 0.1);
      }
      // Residual 0.2 mm (2 counts) seen by cameras 1 and 2; -1 when lost.
      s.points(f, 4 * p + 3) = seen ? (0x03 << 8) | 2 : -1.0;
    }
  }
  std::vector<std::string> upper;
  for (std::string l : labels) {
    for (char& c : l) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
    upper.push_back(l);
  }
  s.groups = {{"POINT",
               {num("USED", 2, {}, {static_cast<double>(s.n_points)}), num("SCALE", 4, {}, {float_data ? -0.1 : 0.1}),
                num("RATE", 4, {}, {rate_hz}), num("FRAMES", 2, {}, {static_cast<double>(s.n_frames)}),
                str("LABELS", 20, upper), str("UNITS", 4, {"mm"})}},
              {"ANALOG", {num("USED", 2, {}, {0}), num("RATE", 4, {}, {rate_hz})}}};
  return write_c3d(s);
}

// The demo session with each trial's marker table replaced by markers.c3d
// and no calibration folder.
void write_markers_session(const fs::path& dir, const pipeline::SessionState& cameras, bool float_data) {
  fs::create_directories(dir);
  fs::copy_file(kDemo / "session.toml", dir / "session.toml");
  const Manifest& man = cameras.session.manifest;
  for (std::size_t i = 0; i < cameras.session.trials.size(); ++i) {
    const fs::path trial_dir = dir / man.trials[i].dir;
    fs::create_directories(trial_dir);
    fs::copy_file(kDemo / man.trials[i].dir / "force.txt", trial_dir / "force.txt");
    std::ofstream(trial_dir / "markers.c3d", std::ios::binary)
        << markers_c3d(cameras.trials[i].trajectories, man.video.points, man.video.frame_rate_hz, float_data);
  }
}

class MarkersC3dRun : public ::testing::TestWithParam<bool> {};

TEST_P(MarkersC3dRun, SameTrialsAndMatAsTheCameras) {
  const bool float_data = GetParam();
  pipeline::BuildOptions options;
  options.models = {fitting::ModelKind::Model4};
  const pipeline::SessionState cameras = pipeline::build(kDemo.string(), options);
  ASSERT_EQ(cameras.accepted(), 5);

  testsupport::TempDir tmp;
  write_markers_session(tmp.path() / "session", cameras, float_data);
  const Session read = capture::read_session((tmp.path() / "session").string());
  EXPECT_FALSE(read.calibration_needed());
  const pipeline::SessionState markers = pipeline::build(read, options);

  EXPECT_TRUE(markers.calibration.after.cameras.empty());
  ASSERT_EQ(markers.trials.size(), cameras.trials.size());
  // Positions to the file's precision: float32 mm (1e-4 mm at 1 m) or
  // 0.1 mm counts (0.05 mm rounding, far below the 0.3 mm digitising noise
  // the free-fall fit already averages).
  const double velocity_tol_m_s = float_data ? 1e-5 : 1e-3;
  const double deformation_tol_m = float_data ? 1e-6 : 1e-4;
  for (std::size_t i = 0; i < cameras.trials.size(); ++i) {
    const trial::TrialResult& c = cameras.trials[i].result;
    const trial::TrialResult& m = markers.trials[i].result;
    SCOPED_TRACE(c.id);
    EXPECT_TRUE(m.accepted) << m.reject_reason;
    EXPECT_NEAR(m.impact_velocity_m_s, c.impact_velocity_m_s, velocity_tol_m_s);
    EXPECT_NEAR(m.max_deformation_m, c.max_deformation_m, deformation_tol_m);
    EXPECT_DOUBLE_EQ(m.peak_force_n, c.peak_force_n);
    // No camera calibration: the interval is the free-fall fit's alone,
    // never wider than the cameras' (which adds the calibration's scale).
    EXPECT_GT(m.impact_velocity_ci_m_s, 0.0);
    EXPECT_LE(m.impact_velocity_ci_m_s, c.impact_velocity_ci_m_s * 1.05);
    EXPECT_EQ(m.calibration_uncertainty.rfind("none: the markers come from an optoelectronic system", 0), 0u)
        << m.calibration_uncertainty;
    EXPECT_EQ(c.calibration_uncertainty, "check markers");
    EXPECT_TRUE(std::isnan(m.reprojection_residual_px));
    EXPECT_EQ(pipeline::trial_source(markers, i).markers_file, "markers.c3d");
    EXPECT_EQ(pipeline::trial_source(cameras, i).markers_file, "");
  }

  // The same mat: the final model's parameters within 1 % of the cameras'
  // (the integer file's rounding moves the velocities by tenths of a mm/s).
  const fitting::FitResult* fc = cameras.final_fit();
  const fitting::FitResult* fm = markers.final_fit();
  ASSERT_TRUE(fc && fm);
  EXPECT_EQ(markers.final_label(), cameras.final_label());
  ASSERT_EQ(fm->estimates.size(), fc->estimates.size());
  for (std::size_t k = 0; k < fc->estimates.size(); ++k)
    EXPECT_NEAR(fm->estimates[k].value, fc->estimates[k].value, 0.01 * std::abs(fc->estimates[k].value))
        << fc->estimates[k].name;

  // One note for the five trials, not five.
  int marker_notes = 0;
  for (const auto& note : markers.notes) {
    if (note.find("3-D markers as an optoelectronic system gave them") == std::string::npos) continue;
    ++marker_notes;
    EXPECT_EQ(note.rfind("trials trial1, trial2, trial3, trial4, trial5: ", 0), 0u) << note;
  }
  EXPECT_EQ(marker_notes, 1);

  // The run's files: no calibration outputs, every trial.json names its markers.
  report::OutputSet out;
  pipeline::add_run_outputs(out, markers);
  EXPECT_EQ(out.files().count("calibration.json"), 0u);
  ASSERT_EQ(out.files().count("trials/trial1/trial.json"), 1u);
  EXPECT_NE(out.files().at("trials/trial1/trial.json").find("\"markers\": \"markers.c3d\""), std::string::npos);
  EXPECT_NE(out.files().at("fit.json").find("\"k1"), std::string::npos);
}

INSTANTIATE_TEST_SUITE_P(FloatAndInteger, MarkersC3dRun, ::testing::Values(true, false),
                         [](const auto& info) { return std::string(info.param ? "FloatMm" : "IntegerCounts"); });

}  // namespace
}  // namespace dropfit
