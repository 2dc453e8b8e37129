// `dropfit track` on footage exported from frame 399 on (frame_00399.png,
// ...): a seed at frame 399 works, and the marker table's rows are the
// footage's own frame numbers (docs/formats.md, "Footage").
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <string>

#include "calibration/calibration.h"
#include "capture/io.h"
#include "samples/generator/render.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

TEST(CliTrackFrames, SeedAtTheFootagesOwnFrameNumber) {
  TempDir dir;
  const fs::path session = dir / "session";
  write_synthetic_session(session);
  const Manifest manifest = capture::read_manifest((session / "session.toml").string());

  // Two markers moving across a 256 x 256 image, 20 frames, files numbered
  // from 399.
  const int n = 20, first = 399;
  synth::MarkerFootage footage;
  footage.centres_px.resize(n, 4);
  footage.radius_px = {4.0, 4.0};
  for (int f = 0; f < n; ++f) footage.centres_px.row(f) << 60.3 + 1.5 * f, 80.6, 150.2, 60.1 + 2.0 * f;
  synth::FootageOptions render;
  render.width_px = render.height_px = 256;
  const fs::path frames = dir / "cam1_frames";
  fs::create_directories(frames);
  const auto files = synth::write_footage_png(frames.string(), footage, render, "tmp_");
  for (int f = 0; f < n; ++f) fs::rename(files[f], frames / fmt::format("frame_{:05d}.png", first + f));

  const std::string p0 = manifest.video.points[0], p1 = manifest.video.points[1];
  write_text(dir / "seed.csv", fmt::format("point,frame,u_px,v_px\n{},{},61.5,79.8\n{},{},151.0,61.0\n", p0, first,
                                           p1, first));
  const fs::path out = dir / "xypts.csv";
  const CliRun run = run_dropfit({"track", session.string(), "--trial", manifest.trials[0].id, "--camera", "cam1",
                                  "--frames", frames.string(), "--seed", (dir / "seed.csv").string(), "--out",
                                  out.string()},
                                 dir.path());
  ASSERT_EQ(run.exit_code, 0) << run.describe();
  VideoSpec video = manifest.video;
  video.trigger_frame = 0;
  const MarkerTracks2D t = capture::read_xypts(out.string(), video);
  ASSERT_EQ(t.n_frames(), first + n);
  EXPECT_TRUE(t.uv_px.topRows(first).array().isNaN().all());
  for (int f = 0; f < n; ++f)
    for (int p = 0; p < 2; ++p) {
      const Eigen::Vector2d truth = footage.centres_px.row(f).segment<2>(2 * p).transpose();
      // 0.1 px: the tracker's accuracy on lossless frames (tracking_test).
      EXPECT_LT((t.uv(first + f, p, 0) - truth).norm(), 0.1) << "frame " << first + f;
      EXPECT_TRUE(t.uv(first + f, p, 1).array().isNaN().all());  // cam2 not tracked
    }

  // A seed at frame 12, before the footage: one line naming the seed file.
  write_text(dir / "early.csv", fmt::format("point,frame,u_px,v_px\n{},12,61.5,79.8\n", p0));
  const CliRun early = run_dropfit({"track", session.string(), "--trial", manifest.trials[0].id, "--camera", "cam1",
                                    "--frames", frames.string(), "--seed", (dir / "early.csv").string(), "--out",
                                    (dir / "x2.csv").string()},
                                   dir.path());
  expect_one_line_error(early);
  EXPECT_NE(early.err.find((dir / "early.csv").string() + ":2"), std::string::npos) << early.describe();
  EXPECT_NE(early.err.find("first frame is 399"), std::string::npos) << early.describe();
}

// --seed-lab: one file of lab positions for every camera, projected through
// the session's calibration; the seeds snap to the markers there, which are
// then tracked as with pixel seeds (0.1 px). A lab seed naming a point the
// manifest does not have is one line naming the file, line and field.
TEST(CliTrackFrames, LabSeedsProjectThroughTheSessionsCalibration) {
  TempDir dir;
  const fs::path session = dir / "session";
  write_synthetic_session(session);
  const Session s = capture::read_session(session.string());
  // cam1's DLT from the frame's fit markers, as an independent projector.
  std::vector<calibration::Correspondence> fit;
  for (const auto& obs : s.images[0].observations)
    for (const auto& m : s.frame)
      if (m.id == obs.id && m.role == MarkerRole::Fit) fit.push_back({m.id, m.lab_m, obs.image_px});
  const calibration::Camera cam1 = calibration::fit_dlt("cam1", fit).camera;

  // Two markers 0.2 m apart falling 5 mm a frame, 12 frames.
  const Eigen::Vector3d a0(0.0, 0.0, 0.3), b0(0.2, 0.0, 0.3);
  const int n = 12;
  synth::MarkerFootage footage;
  footage.centres_px.resize(n, 4);
  footage.radius_px = {4.0, 4.0};
  for (int f = 0; f < n; ++f) {
    const Eigen::Vector3d down(0.0, 0.0, -0.005 * f);
    footage.centres_px.row(f) << cam1.project(a0 + down).transpose(), cam1.project(b0 + down).transpose();
  }
  synth::FootageOptions render;
  render.width_px = static_cast<int>(footage.centres_px.maxCoeff()) + 64;
  render.height_px = render.width_px;
  const fs::path frames = dir / "cam1_frames";
  fs::create_directories(frames);
  synth::write_footage_png(frames.string(), footage, render, "frame_");

  const std::string p0 = s.manifest.video.points[0], p1 = s.manifest.video.points[1];
  // Lab seeds 3 mm off the markers: the snap finds them.
  write_text(dir / "lab.csv", fmt::format("point,frame,x_m,y_m,z_m\n{},0,0.003,0,0.3\n{},0,0.2,0.003,0.3\n", p0, p1));
  const fs::path out = dir / "xypts.csv";
  const CliRun run = run_dropfit({"track", session.string(), "--trial", s.manifest.trials[0].id, "--camera", "cam1",
                                  "--frames", frames.string(), "--seed-lab", (dir / "lab.csv").string(), "--out",
                                  out.string()},
                                 dir.path());
  ASSERT_EQ(run.exit_code, 0) << run.describe();
  VideoSpec video = s.manifest.video;
  video.trigger_frame = 0;
  const MarkerTracks2D t = capture::read_xypts(out.string(), video);
  ASSERT_EQ(t.n_frames(), n);
  for (int f = 0; f < n; ++f)
    for (int p = 0; p < 2; ++p) {
      const Eigen::Vector2d truth = footage.centres_px.row(f).segment<2>(2 * p).transpose();
      EXPECT_LT((t.uv(f, p, 0) - truth).norm(), 0.1) << "frame " << f << " point " << p;
    }

  write_text(dir / "bad.csv", fmt::format("point,frame,x_m,y_m,z_m\n{},0,0,0,0.3\nnot_a_point,0,0,0,0.3\n", p0));
  const CliRun bad = run_dropfit({"track", session.string(), "--trial", s.manifest.trials[0].id, "--camera", "cam1",
                                  "--frames", frames.string(), "--seed-lab", (dir / "bad.csv").string(), "--out",
                                  (dir / "x2.csv").string()},
                                 dir.path());
  expect_one_line_error(bad);
  EXPECT_NE(bad.err.find((dir / "bad.csv").string() + ":3"), std::string::npos) << bad.describe();
  EXPECT_NE(bad.err.find("not_a_point"), std::string::npos) << bad.describe();
  EXPECT_FALSE(fs::exists(dir / "x2.csv"));
}

}  // namespace
}  // namespace dropfit::clitest
