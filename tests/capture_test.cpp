// Tests of the session-format readers and writers (capture/io.h). Each test
// writes its own files into a fresh temporary folder.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "capture/io.h"
#include "core/error.h"
#include "support/temp_dir.h"
#include "support/shared_data.h"

namespace dropfit::capture {
namespace {

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// A fresh folder per test (removed at the end) and text helpers.
using testsupport::line_of;
using testsupport::read_text;
using testsupport::TempDir;
using testsupport::write_text;

// Runs `fn`, which must throw InputError located at file/line/field; the
// column is checked when >= 0, and must merely be known (> 0) when -1. The message must name the file, the line and the field.
void expect_input_error(const std::function<void()>& fn, const std::string& file, int line, int column,
                        const std::string& field, const std::string& reason_part = "") {
  try {
    fn();
    ADD_FAILURE() << "no InputError thrown (expected " << file << ":" << line << " [" << field << "])";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_EQ(e.file(), file) << what;
    EXPECT_EQ(e.line(), line) << what;
    if (column >= 0) {
      EXPECT_EQ(e.column(), column) << what;
    } else {
      EXPECT_GT(e.column(), 0) << what;
    }
    EXPECT_EQ(e.field(), field) << what;
    EXPECT_NE(what.find(file), std::string::npos) << what;
    if (line > 0) {
      EXPECT_NE(what.find(fmt::format(":{}", line)), std::string::npos) << what;
    }
    if (!field.empty()) {
      EXPECT_NE(what.find("[" + field + "]"), std::string::npos) << what;
    }
    if (!reason_part.empty()) {
      EXPECT_NE(e.reason().find(reason_part), std::string::npos) << what;
    }
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected InputError, got: " << e.what();
  }
}

Manifest test_manifest() {
  Manifest m;
  m.name = "mat \"sample\" 2026-03";
  m.gravity_m_s2 = 9.80665;
  m.impactor.mass_kg = 24.137;
  m.impactor.footprint_m = {0.251, 0.249};
  m.impactor.base_markers = {"imp_base_front", "imp_base_back"};
  m.impactor.base_marker_height_m = 0.0123;
  m.mat.length_m = 0.9;
  m.mat.width_m = 0.6;
  m.mat.surface_markers = {"mat_n", "mat_s"};
  m.mat.layers = {{"carpet", 0.005, 0.0}, {"stiff", 0.05, 2.44}, {"soft", 0.15, 3.66}};
  m.video.cameras = {"cam1", "cam2"};
  m.video.frame_rate_hz = 1000.0;
  m.video.points = {"imp_base_front", "imp_base_back", "mat_n", "mat_s"};
  m.video.trigger_frame = 3;
  m.forceplate.model = "Kistler 9281B";
  m.forceplate.sample_rate_hz = 2000.0;
  m.forceplate.trigger_threshold_n = 25.0;
  m.forceplate.pretrigger_fraction = 0.1;
  m.forceplate.a_m = 0.12;
  m.forceplate.b_m = 0.2;
  m.forceplate.az0_m = -0.04;
  m.forceplate.mat_top_z_m = 0.205 + 1.0 / 3.0;  // needs all 17 digits to round-trip
  m.trials = {{"trial1", "trials/trial1"}, {"trial2", "trials/trial2"}};
  return m;
}

MarkerTracks2D test_tracks(const Manifest& m, int n_frames, double phase) {
  MarkerTracks2D t;
  t.points = m.video.points;
  t.cameras = m.video.cameras;
  t.uv_px.resize(n_frames, 2 * t.n_points() * t.n_cameras());
  for (int f = 0; f < n_frames; ++f)
    for (int c = 0; c < t.uv_px.cols(); ++c) t.uv_px(f, c) = 100.0 + 37.1234567 * c + 3.3 * std::sin(phase + 0.7 * f + c);
  t.uv_px(0, 0) = kNaN;  // not digitised in the first frame
  t.uv_px(0, 1) = kNaN;
  t.uv_px(n_frames - 1, t.column(3, 1)) = kNaN;
  t.uv_px(n_frames - 1, t.column(3, 1) + 1) = kNaN;
  return t;
}

ForceRecord eight_channel_record(int n, int pretrigger, double rate_hz) {
  ForceRecord r;
  r.layout = ForceLayout::EightChannel;
  r.sample_rate_hz = rate_hz;
  r.pretrigger_samples = pretrigger;
  r.trigger = "Fz > 25 N";
  r.t_s.resize(n);
  r.data.resize(n, 8);
  for (int i = 0; i < n; ++i) {
    r.t_s(i) = (i - pretrigger) / rate_hz;
    for (int c = 0; c < 8; ++c) r.data(i, c) = 10.0 * c + 1.234567 * std::cos(0.3 * i + c);
  }
  return r;
}

ForceRecord bioware_record(int n, int pretrigger, double rate_hz) {
  ForceRecord r;
  r.layout = ForceLayout::Resultants;
  r.sample_rate_hz = rate_hz;
  r.pretrigger_samples = pretrigger;
  r.t_s.resize(n);
  r.data.resize(n, 8);
  for (int i = 0; i < n; ++i) {
    r.t_s(i) = (i - pretrigger) / rate_hz;
    for (int c = 0; c < 6; ++c) r.data(i, c) = 100.0 * c - 50.0 + 2.5 * std::sin(0.2 * i + c);
    r.data(i, 6) = 0.0123456 * std::cos(0.1 * i);  // Ax, m
    r.data(i, 7) = -0.0234567 * std::sin(0.1 * i);
  }
  r.data(0, 6) = kNaN;  // centre of pressure undefined while unloaded
  return r;
}

Session test_session() {
  Session s;
  s.manifest = test_manifest();
  for (int i = 0; i < 12; ++i) {
    CalibrationMarker m;
    m.id = fmt::format("c{}", i + 1);
    m.lab_m = {-0.4 + 0.0731234567 * i, 0.25 - 0.0412345678 * (i % 5), 0.1 * (i % 3) + 1e-5 * i};
    m.role = i % 4 == 3 ? MarkerRole::Check : MarkerRole::Fit;
    s.frame.push_back(m);
  }
  for (int c = 0; c < 2; ++c) {
    CalibrationImage image;
    image.camera = s.manifest.video.cameras[c];
    for (int i = 0; i < 12; ++i) {
      if (c == 1 && i == 5) continue;  // hidden from camera 2
      image.observations.push_back({s.frame[i].id, {412.3123456 + 13.7 * i + c, 288.0712345 - 9.1 * i}});
    }
    s.images.push_back(image);
  }
  // trial1: eight-channel; trial2: BioWare with the manifest's pretrigger share.
  const int n2 = 37;
  for (int t = 0; t < 2; ++t) {
    TrialRecording trial;
    trial.spec = s.manifest.trials[t];
    trial.tracks = test_tracks(s.manifest, 9 + t, 0.5 * t);
    trial.force = t == 0 ? eight_channel_record(40, 4, 2000.0)
                         : bioware_record(n2, trigger_sample_from_fraction(0.1, n2), 2000.0);
    s.trials.push_back(trial);
  }
  return s;
}

// Matrices equal within `tol`, NaN exactly where the other is NaN.
void expect_near_nan(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b, double tol) {
  ASSERT_EQ(a.rows(), b.rows());
  ASSERT_EQ(a.cols(), b.cols());
  for (Eigen::Index i = 0; i < a.rows(); ++i)
    for (Eigen::Index j = 0; j < a.cols(); ++j) {
      if (std::isnan(b(i, j))) {
        EXPECT_TRUE(std::isnan(a(i, j))) << "(" << i << "," << j << ")";
      } else {
        EXPECT_NEAR(a(i, j), b(i, j), tol) << "(" << i << "," << j << ")";
      }
    }
}

// Every file below `root` with its size and content.
std::map<std::string, std::string> snapshot(const fs::path& root) {
  std::map<std::string, std::string> out;
  for (const auto& entry : fs::recursive_directory_iterator(root)) {
    const std::string rel = fs::relative(entry.path(), root).string();
    if (entry.is_directory())
      out[rel] = "<dir>";
    else
      out[rel] = read_text(entry.path().string()) + "|" +
                 std::to_string(fs::last_write_time(entry.path()).time_since_epoch().count());
  }
  return out;
}

// ---------------------------------------------------------------------------

TEST(CaptureSession, MatThicknessAndMassSumTheLayers) {
  const Manifest m = test_manifest();
  EXPECT_NEAR(m.mat.thickness_m(), 0.205, 1e-15);
  EXPECT_NEAR(m.mat.mass_kg(), 6.10, 1e-15);
}

TEST(CaptureIo, SessionRoundTrip) {
  TempDir dir;
  const Session in = test_session();
  write_session(dir.path().string(), in);
  const Session out = read_session(dir.path().string());

  const Manifest& a = out.manifest;
  const Manifest& b = in.manifest;
  // Manifest values are written at full precision: exact.
  EXPECT_EQ(a.name, b.name);
  EXPECT_EQ(a.gravity_m_s2, b.gravity_m_s2);
  EXPECT_EQ(a.impactor.mass_kg, b.impactor.mass_kg);
  EXPECT_EQ(a.impactor.footprint_m, b.impactor.footprint_m);
  EXPECT_EQ(a.impactor.base_markers, b.impactor.base_markers);
  EXPECT_EQ(a.impactor.base_marker_height_m, b.impactor.base_marker_height_m);
  EXPECT_EQ(a.mat.length_m, b.mat.length_m);
  EXPECT_EQ(a.mat.width_m, b.mat.width_m);
  EXPECT_EQ(a.mat.surface_markers, b.mat.surface_markers);
  ASSERT_EQ(a.mat.layers.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(a.mat.layers[i].name, b.mat.layers[i].name);
    EXPECT_EQ(a.mat.layers[i].thickness_m, b.mat.layers[i].thickness_m);
    EXPECT_EQ(a.mat.layers[i].mass_kg, b.mat.layers[i].mass_kg);
  }
  EXPECT_EQ(a.video.cameras, b.video.cameras);
  EXPECT_EQ(a.video.points, b.video.points);
  EXPECT_EQ(a.video.frame_rate_hz, b.video.frame_rate_hz);
  EXPECT_EQ(a.video.trigger_frame, b.video.trigger_frame);
  EXPECT_EQ(a.video.image_origin, ImageOrigin::TopLeft);
  EXPECT_FALSE(a.video.image_height_px.has_value());
  EXPECT_EQ(a.forceplate.model, b.forceplate.model);
  EXPECT_EQ(a.forceplate.sample_rate_hz, b.forceplate.sample_rate_hz);
  EXPECT_EQ(a.forceplate.trigger_threshold_n, b.forceplate.trigger_threshold_n);
  EXPECT_EQ(a.forceplate.pretrigger_fraction, b.forceplate.pretrigger_fraction);
  EXPECT_EQ(a.forceplate.a_m, b.forceplate.a_m);
  EXPECT_EQ(a.forceplate.b_m, b.forceplate.b_m);
  EXPECT_EQ(a.forceplate.az0_m, b.forceplate.az0_m);
  EXPECT_EQ(a.forceplate.mat_top_z_m, b.forceplate.mat_top_z_m);
  ASSERT_EQ(a.trials.size(), 2u);
  EXPECT_EQ(a.trials[1].id, "trial2");
  EXPECT_EQ(a.trials[1].dir, "trials/trial2");

  // frame.csv: %.9g metres, relative error below 5e-9.
  ASSERT_EQ(out.frame.size(), in.frame.size());
  for (std::size_t i = 0; i < in.frame.size(); ++i) {
    EXPECT_EQ(out.frame[i].id, in.frame[i].id);
    EXPECT_EQ(out.frame[i].role, in.frame[i].role);
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(out.frame[i].lab_m[k], in.frame[i].lab_m[k], 1e-9);
  }
  // Camera files: pixels %.6f.
  ASSERT_EQ(out.images.size(), 2u);
  for (int c = 0; c < 2; ++c) {
    EXPECT_EQ(out.images[c].camera, in.images[c].camera);
    ASSERT_EQ(out.images[c].observations.size(), in.images[c].observations.size());
    for (std::size_t i = 0; i < in.images[c].observations.size(); ++i) {
      EXPECT_EQ(out.images[c].observations[i].id, in.images[c].observations[i].id);
      EXPECT_NEAR((out.images[c].observations[i].image_px - in.images[c].observations[i].image_px).norm(), 0.0, 1e-6);
    }
  }
  ASSERT_EQ(out.trials.size(), 2u);
  for (int t = 0; t < 2; ++t) {
    const TrialRecording& ta = out.trials[t];
    const TrialRecording& tb = in.trials[t];
    EXPECT_EQ(ta.spec.id, tb.spec.id);
    EXPECT_EQ(ta.tracks.points, tb.tracks.points);
    EXPECT_EQ(ta.tracks.cameras, tb.tracks.cameras);
    expect_near_nan(ta.tracks.uv_px, tb.tracks.uv_px, 5.01e-7);
    EXPECT_EQ(ta.force.layout, tb.force.layout);
    EXPECT_EQ(ta.force.sample_rate_hz, tb.force.sample_rate_hz);
    EXPECT_EQ(ta.force.pretrigger_samples, tb.force.pretrigger_samples);
    expect_near_nan(ta.force.t_s, tb.force.t_s, 1e-6);
    EXPECT_EQ(ta.force.t_s(ta.force.pretrigger_samples), 0.0);
  }
  EXPECT_EQ(out.trials[0].force.trigger, "Fz > 25 N");
  expect_near_nan(out.trials[0].force.data, in.trials[0].force.data, 5.01e-7);
  // BioWare: forces and moments %.6f, centre of pressure %.6f mm = 5e-10 m.
  expect_near_nan(out.trials[1].force.data.leftCols(6), in.trials[1].force.data.leftCols(6), 5.01e-7);
  expect_near_nan(out.trials[1].force.data.rightCols(2), in.trials[1].force.data.rightCols(2), 5.01e-10);
}

TEST(CaptureIo, BottomLeftArgusSessionRoundTrip) {
  TempDir dir;
  Session in = test_session();
  in.manifest.video.image_origin = ImageOrigin::BottomLeft;
  in.manifest.video.image_height_px = 1080.0;
  write_session(dir.path().string(), in, XyptsLayout::Argus);
  // On disk: Argus names, v measured up from the bottom edge.
  const std::string text = read_text((dir.path() / "trials/trial1/xypts.csv").string());
  EXPECT_EQ(text.rfind("imp_base_front_cam_1_x,imp_base_front_cam_1_y,", 0), 0u);
  const Session out = read_session(dir.path().string());
  EXPECT_EQ(out.manifest.video.image_origin, ImageOrigin::BottomLeft);
  EXPECT_EQ(out.manifest.video.image_height_px.value_or(0.0), 1080.0);
  for (int t = 0; t < 2; ++t) expect_near_nan(out.trials[t].tracks.uv_px, in.trials[t].tracks.uv_px, 1.01e-6);
}

TEST(CaptureIo, ReadsCsvAsSpreadsheetsWriteIt) {
  TempDir dir;
  // UTF-8 BOM, CR LF, quoted header names, columns reordered, blanks
  // around fields, a leading '+', trailing blank lines.
  const std::string frame_path = dir.file("frame.csv");
  write_text(frame_path,
             "\xEF\xBB\xBF\"role\",\"id\",\"z_m\",\"y_m\",\"x_m\"\r\n"
             "fit,\"c 1\", 0.125 ,-2.5e-1,+1\r\n"
             "check,c2,0,0,0\r\n\r\n\r\n");
  const auto frame = read_frame_csv(frame_path);
  ASSERT_EQ(frame.size(), 2u);
  EXPECT_EQ(frame[0].id, "c 1");
  EXPECT_EQ(frame[0].lab_m, Eigen::Vector3d(1.0, -0.25, 0.125));
  EXPECT_EQ(frame[0].role, MarkerRole::Fit);
  EXPECT_EQ(frame[1].role, MarkerRole::Check);
  const std::string cam_path = dir.file("cam1.csv");
  write_text(cam_path, "v_px,u_px,id\n288.07,412.31,c2\n");
  const CalibrationImage image = read_camera_csv(cam_path, "cam1", frame);
  ASSERT_EQ(image.observations.size(), 1u);
  EXPECT_EQ(image.observations[0].id, "c2");
  EXPECT_EQ(image.observations[0].image_px, Eigen::Vector2d(412.31, 288.07));
}

TEST(CaptureIo, ThreeXyptsLayoutsAndBottomLeftReadTheSame) {
  TempDir dir;
  const Manifest m = test_manifest();
  const MarkerTracks2D truth = test_tracks(m, 6, 0.0);
  write_xypts(dir.file("a.csv"), truth, XyptsLayout::Dltdv83);
  write_xypts(dir.file("b.csv"), truth, XyptsLayout::Dltdv84);
  write_xypts(dir.file("c.csv"), truth, XyptsLayout::Argus);
  const double height = 1024.0;
  write_xypts(dir.file("d.csv"), truth, XyptsLayout::Argus, ImageOrigin::BottomLeft, height);

  EXPECT_EQ(read_text(dir.file("a.csv")).substr(0, 22), "pt1_cam1_X,pt1_cam1_Y,");
  EXPECT_EQ(read_text(dir.file("b.csv")).substr(0, 40), "imp_base_front_cam1_U,imp_base_front_cam");
  EXPECT_EQ(read_text(dir.file("c.csv")).substr(0, 24), "imp_base_front_cam_1_x,i");

  const MarkerTracks2D a = read_xypts(dir.file("a.csv"), m.video);
  const MarkerTracks2D b = read_xypts(dir.file("b.csv"), m.video);
  const MarkerTracks2D c = read_xypts(dir.file("c.csv"), m.video);
  VideoSpec bottom = m.video;
  bottom.image_origin = ImageOrigin::BottomLeft;
  bottom.image_height_px = height;
  const MarkerTracks2D d = read_xypts(dir.file("d.csv"), bottom);
  expect_near_nan(a.uv_px, truth.uv_px, 5.01e-7);
  expect_near_nan(b.uv_px, a.uv_px, 0.0);
  expect_near_nan(c.uv_px, a.uv_px, 0.0);
  expect_near_nan(d.uv_px, truth.uv_px, 5.01e-7);

  // A bottom-left value by hand: v_top = 1024 - 100.25 = 923.75.
  write_text(dir.file("e.csv"), "imp_base_back_cam_2_y,imp_base_back_cam_2_x\n100.25,7.5\n1,2\n3,4\n4,5\n");
  const MarkerTracks2D e = read_xypts(dir.file("e.csv"), bottom);
  EXPECT_DOUBLE_EQ(e.uv(0, 1, 1).x(), 7.5);
  EXPECT_DOUBLE_EQ(e.uv(0, 1, 1).y(), 923.75);
}

TEST(CaptureIo, XyptsColumnsInAnyOrderAndAbsentPointsAreNaN) {
  TempDir dir;
  Manifest m = test_manifest();
  m.video.trigger_frame = 0;
  // DLTdv 8.4 columns shuffled; mat_s absent from the file; mat_n only in cam2.
  write_text(dir.file("x.csv"),
             "mat_n_cam2_V,imp_base_back_cam1_U,imp_base_front_cam2_V,imp_base_front_cam1_U,imp_base_back_cam2_U,"
             "imp_base_front_cam1_V,imp_base_back_cam1_V,mat_n_cam2_U,imp_base_front_cam2_U,imp_base_back_cam2_V\n"
             "1,2,3,4,5,6,7,8,9,10\n"
             "11,12,13,14,15,16,17,18,19,20\n");
  const MarkerTracks2D t = read_xypts(dir.file("x.csv"), m.video);
  ASSERT_EQ(t.n_frames(), 2);
  ASSERT_EQ(t.uv_px.cols(), 16);
  EXPECT_EQ(t.uv(1, 0, 0), Eigen::Vector2d(14, 16));  // imp_base_front cam1
  EXPECT_EQ(t.uv(1, 0, 1), Eigen::Vector2d(19, 13));  // imp_base_front cam2
  EXPECT_EQ(t.uv(0, 1, 0), Eigen::Vector2d(2, 7));    // imp_base_back cam1
  EXPECT_EQ(t.uv(0, 1, 1), Eigen::Vector2d(5, 10));   // imp_base_back cam2
  EXPECT_EQ(t.uv(0, 2, 1), Eigen::Vector2d(8, 1));    // mat_n cam2
  for (int f = 0; f < 2; ++f) {
    EXPECT_TRUE(t.uv(f, 2, 0).array().isNaN().all());  // mat_n cam1: not in the file
    EXPECT_TRUE(t.uv(f, 3, 0).array().isNaN().all());  // mat_s: not in the file
    EXPECT_TRUE(t.uv(f, 3, 1).array().isNaN().all());
  }
}

TEST(CaptureIo, EmptyAndNaNFieldsStayNaN) {
  TempDir dir;
  Manifest m = test_manifest();
  m.video.points = {"p"};
  m.video.cameras = {"cam1", "cam2"};
  m.video.trigger_frame = 0;
  write_text(dir.file("x.csv"),
             "pt1_cam1_X,pt1_cam1_Y,pt1_cam2_X,pt1_cam2_Y\r\n"
             ",NaN,nan, \r\n"
             "0,0.0,-0,1e2\r\n"
             "NAN,,,\r\n");
  const MarkerTracks2D t = read_xypts(dir.file("x.csv"), m.video);
  ASSERT_EQ(t.n_frames(), 3);
  EXPECT_TRUE(t.uv_px.row(0).array().isNaN().all());
  EXPECT_TRUE(t.uv_px.row(2).array().isNaN().all());
  EXPECT_EQ(t.uv_px.row(1), Eigen::RowVector4d(0, 0, 0, 100));
  EXPECT_FALSE(t.uv_px.row(1).array().isNaN().any());
}

TEST(CaptureIo, ReadsHandWrittenManifest) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  write_text(path, R"(# as a lab would write it
[session]
name = "lab"

[impactor]
mass_kg = 24
footprint_m = [0.25, 0.25]
base_markers = ["a"]

[mat]
length_m = 0.90
width_m = 0.60
surface_markers = []
[[mat.layers]]
name = "carpet"
thickness_m = 0.005
mass_kg = 0
[[mat.layers]]
name = "foam"
thickness_m = 0.2
mass_kg = 6.1

[video]
cameras = ["left", "right"]
frame_rate_hz = 500
points = ["a", "b"]
trigger_frame = 250
image_origin = "bottom-left"
image_height_px = 768

[forceplate]
sample_rate_hz = 1000
trigger_threshold_n = 20
pretrigger_fraction = 0.2
a_m = 0.12
b_m = 0.2
az0_m = -0.04
mat_top_z_m = 0.205

[[trial]]
id = "t1"
dir = "t1"
)");
  const Manifest m = read_manifest(path);
  EXPECT_EQ(m.gravity_m_s2, 9.81);  // default
  EXPECT_EQ(m.impactor.mass_kg, 24.0);
  EXPECT_EQ(m.impactor.base_marker_height_m, 0.0);
  EXPECT_NEAR(m.mat.thickness_m(), 0.205, 1e-15);
  EXPECT_EQ(m.video.cameras, (std::vector<std::string>{"left", "right"}));
  EXPECT_EQ(m.video.frame_rate_hz, 500.0);
  EXPECT_EQ(m.video.trigger_frame, 250);
  EXPECT_EQ(m.video.image_origin, ImageOrigin::BottomLeft);
  EXPECT_EQ(m.video.image_height_px.value_or(0.0), 768.0);
  EXPECT_EQ(m.forceplate.pretrigger_fraction, 0.2);
  EXPECT_EQ(m.forceplate.model, "");
  ASSERT_EQ(m.trials.size(), 1u);
  EXPECT_EQ(m.trials[0].dir, "t1");
}

TEST(CaptureIo, ReadsKistlerEightChannelInAnyColumnOrder) {
  TempDir dir;
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  // Channel columns shuffled; truth Fz1..Fz4 = 1, 2, 3, 4 N * row.
  std::string text =
      "Device\tKistler 9281B\nSample rate\t1000\nSamples\t5\nPretrigger samples\t2\nTrigger\tFz > 25 N\n\n"
      "Time(s)\tFz4\tFx12\tFz1\tFy23\tFx34\tFz2\tFy14\tFz3\n";
  for (int i = 0; i < 5; ++i) {
    const double k = i + 1;
    text += std::to_string((i - 2) * 0.001) + "\t" + std::to_string(4 * k) + "\t0.5\t" + std::to_string(1 * k) +
            "\t-0.25\t0.75\t" + std::to_string(2 * k) + "\t0.125\t" + std::to_string(3 * k) + "\n";
  }
  write_text(dir.file("force.txt"), text);
  const ForceRecord r = read_force(dir.file("force.txt"), plate);
  EXPECT_EQ(r.layout, ForceLayout::EightChannel);
  EXPECT_EQ(r.sample_rate_hz, 1000.0);
  EXPECT_EQ(r.pretrigger_samples, 2);
  EXPECT_EQ(r.trigger, "Fz > 25 N");
  ASSERT_EQ(r.data.rows(), 5);
  EXPECT_NEAR(r.t_s(0), -0.002, 1e-12);
  EXPECT_EQ(r.t_s(2), 0.0);
  // Columns Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4.
  EXPECT_EQ(r.data.row(3), (Eigen::Matrix<double, 1, 8>() << 0.5, 0.75, 0.125, -0.25, 4, 8, 12, 16).finished());
  // Resultants by the eight-channel formulas: Fz = sum, Fx = Fx12 + Fx34.
  EXPECT_NEAR(r.data.row(4).segment(4, 4).sum(), 50.0, 1e-12);
  EXPECT_NEAR(r.data(4, 0) + r.data(4, 1), 1.25, 1e-12);
}

TEST(CaptureIo, ReadsBiowareResultantsInSI) {
  TempDir dir;
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  plate.pretrigger_fraction = 0.25;
  std::string text =
      "Filename:\tdrop_03.dat\nRate (Hz):\t1000\nDuration (s):\t0.010\n\n"
      "abs time (s)\tFx\tFy\tFz\tMx\tMy\tMz\tAx\tAy\tCOFx\n"
      "s\tN\tN\tN\tN.m\tN.m\tN.m\tmm\tmm\tmm\n";
  for (int i = 0; i < 10; ++i)
    text += std::to_string(12.0 + 0.001 * i) + "\t1.5\t-2.5\t" + std::to_string(100.0 * i) + "\t3\t-4\t5\t" +
            std::to_string(10.0 * i) + "\t-25.5\t9\t\n";
  write_text(dir.file("force.txt"), text);
  const ForceRecord r = read_force(dir.file("force.txt"), plate);
  EXPECT_EQ(r.layout, ForceLayout::Resultants);
  ASSERT_EQ(r.data.rows(), 10);
  EXPECT_EQ(r.pretrigger_samples, 3);  // round(0.25 * 10) = round(2.5) = 3
  EXPECT_EQ(r.t_s(3), 0.0);
  EXPECT_NEAR(r.t_s(0), -0.003, 1e-9);
  EXPECT_NEAR(r.t_s(9), 0.006, 1e-9);
  EXPECT_EQ(r.data(7, 2), 700.0);
  EXPECT_NEAR(r.data(7, 6), 0.070, 1e-15);   // 70 mm
  EXPECT_NEAR(r.data(7, 7), -0.0255, 1e-15);  // -25.5 mm
  EXPECT_EQ(r.data(7, 3), 3.0);
}

TEST(CaptureIo, ReadSessionNeverModifiesTheFolder) {
  TempDir dir;
  write_session(dir.path().string(), test_session());
  const auto before = snapshot(dir.path());
  ASSERT_GT(before.size(), 8u);
  (void)read_session(dir.path().string());
  EXPECT_EQ(snapshot(dir.path()), before);
  // No temporary files were left behind by the writers.
  for (const auto& [name, content] : before) EXPECT_EQ(name.find(".tmp"), std::string::npos) << name;
}

// --- bad input ---------------------------------------------------------------

class CaptureBadManifest : public ::testing::Test {
 protected:
  void SetUp() override {
    path_ = dir_.file("session.toml");
    write_manifest(path_, test_manifest());
    text_ = read_text(path_);
  }
  void replace_line(const std::string& prefix, const std::string& replacement) {
    std::istringstream in(text_);
    std::string line, out;
    bool done = false;
    while (std::getline(in, line)) {
      if (!done && line.rfind(prefix, 0) == 0) {
        done = true;
        if (replacement.empty()) continue;
        out += replacement + "\n";
      } else {
        out += line + "\n";
      }
    }
    ASSERT_TRUE(done) << prefix;
    text_ = out;
    write_text(path_, text_);
  }
  TempDir dir_;
  std::string path_;
  std::string text_;
};

TEST_F(CaptureBadManifest, WrittenManifestReadsBack) { EXPECT_NO_THROW(read_manifest(path_)); }

TEST_F(CaptureBadManifest, UnknownKey) {
  replace_line("width_m", "width_m = 0.6\ncolour = \"blue\"");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "colour"), 1, "mat.colour", "unknown key");
}

TEST_F(CaptureBadManifest, UnknownKeyInArrayOfTables) {
  replace_line("thickness_m = 0.05", "thickness_mm = 50");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "thickness_mm"), 1,
                     "mat.layers[1].thickness_mm", "unknown key");
}

TEST_F(CaptureBadManifest, WrongType) {
  replace_line("mass_kg = 24.137", "mass_kg = \"heavy\"");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "mass_kg = \"heavy\""), -1,
                     "impactor.mass_kg", "expected a number");
}

TEST_F(CaptureBadManifest, FloatTriggerFrame) {
  replace_line("trigger_frame", "trigger_frame = 3.5");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "trigger_frame"), -1, "video.trigger_frame",
                     "expected an integer");
}

TEST_F(CaptureBadManifest, MissingRequiredKey) {
  replace_line("a_m", "");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "[forceplate]"), 1, "forceplate.a_m",
                     "missing required key");
}

TEST_F(CaptureBadManifest, NegativeMass) {
  replace_line("mass_kg = 24.137", "mass_kg = -24");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "mass_kg = -24"), -1, "impactor.mass_kg",
                     "positive");
}

TEST_F(CaptureBadManifest, PretriggerFractionOutOfRange) {
  replace_line("pretrigger_fraction", "pretrigger_fraction = 1.0");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "pretrigger_fraction"), -1,
                     "forceplate.pretrigger_fraction", "[0, 1)");
}

TEST_F(CaptureBadManifest, BaseMarkerNotAPoint) {
  replace_line("base_markers", "base_markers = [\"imp_base_front\", \"imp_top\"]");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "base_markers"), -1,
                     "impactor.base_markers[1]", "not one of video.points");
}

TEST_F(CaptureBadManifest, DuplicateCamera) {
  replace_line("cameras", "cameras = [\"cam1\", \"cam1\"]");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "cameras"), -1, "video.cameras[1]",
                     "duplicate");
}

TEST_F(CaptureBadManifest, BottomLeftWithoutHeight) {
  replace_line("image_origin", "image_origin = \"bottom-left\"");
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "image_origin"), -1,
                     "video.image_height_px", "image_height_px");
}

TEST_F(CaptureBadManifest, DuplicateTrialId) {
  replace_line("id = \"trial2\"", "id = \"trial1\"");
  std::istringstream in(text_);
  expect_input_error([&] { read_manifest(path_); }, path_, line_of(text_, "dir = \"trials/trial2\"") - 1, -1,
                     "trial[1].id", "duplicate trial id");
}

TEST_F(CaptureBadManifest, TomlSyntaxError) {
  replace_line("width_m", "width_m = = 0.6");
  try {
    read_manifest(path_);
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), path_);
    EXPECT_EQ(e.line(), line_of(text_, "width_m"));
  }
}

// --- several key/values on one line, separated by ';' --------------------------

// The manifest example of docs/formats.md, verbatim: its layer
// lines put three key/values on one line separated by ';', which TOML does
// not allow but labs will copy.
const char* const kSpecManifest = R"([session]
name = "mat-sample-2026-03"           # free text
gravity_m_s2 = 9.81

[impactor]
mass_kg = 24.0
footprint_m = [0.25, 0.25]            # flat contact face
base_markers = ["imp_base_front", "imp_base_back"]   # markers on the impactor, named in [video].points
base_marker_height_m = 0.0            # height of those markers above the contact face

[mat]
length_m = 0.90
width_m = 0.60
surface_markers = ["mat_n", "mat_s", "mat_e", "mat_w"]  # on the mat's top surface
[[mat.layers]]                        # top to bottom
name = "carpet";  thickness_m = 0.005; mass_kg = 0.0
[[mat.layers]]
name = "stiff";   thickness_m = 0.05;  mass_kg = 2.44
[[mat.layers]]
name = "soft";    thickness_m = 0.15;  mass_kg = 3.66

[video]
cameras = ["cam1", "cam2"]            # order of camN in xypts.csv and of the calibration files
frame_rate_hz = 1000
points = ["imp_base_front", "imp_base_back", "mat_n", "mat_s", "mat_e", "mat_w"]  # ptK in xypts.csv is points[K-1]
trigger_frame = 500                   # 0-based row of xypts.csv recorded at the force-plate trigger instant
# image_origin = "top-left"           # optional; "bottom-left" for Argus and DLTdv 7 files
# image_height_px = 1024              # needed with "bottom-left"

[forceplate]
model = "Kistler 9281B"
sample_rate_hz = 1000
trigger_threshold_n = 25.0
pretrigger_fraction = 0.10            # share of the record before the trigger sample
a_m = 0.120                           # sensor offsets from the plate centre, from the plate's certificate
b_m = 0.200
az0_m = -0.040                        # top-surface offset; negative: surface above the sensor plane
mat_top_z_m = 0.205                   # height of the mat's undeformed top surface in the lab frame

[[trial]]
id = "trial1"
dir = "trials/trial1"
[[trial]]
id = "trial2"
dir = "trials/trial2"
)";

// The line, column (1-based) and text of `needle`'s first occurrence.
struct Place {
  int line = -1;
  int column = -1;
};
Place place_of(const std::string& text, const std::string& needle) {
  const std::size_t at = text.find(needle);
  if (at == std::string::npos) return {};
  const std::size_t line_start = text.rfind('\n', at) == std::string::npos ? 0 : text.rfind('\n', at) + 1;
  return {static_cast<int>(std::count(text.begin(), text.begin() + static_cast<std::ptrdiff_t>(at), '\n')) + 1,
          static_cast<int>(at - line_start) + 1};
}

std::string replaced(std::string text, const std::string& from, const std::string& to) {
  const std::size_t at = text.find(from);
  EXPECT_NE(at, std::string::npos) << from;
  if (at != std::string::npos) text.replace(at, from.size(), to);
  return text;
}

void expect_spec_manifest(const Manifest& m) {
  EXPECT_EQ(m.name, "mat-sample-2026-03");
  EXPECT_EQ(m.gravity_m_s2, 9.81);
  EXPECT_EQ(m.impactor.mass_kg, 24.0);
  ASSERT_EQ(m.mat.layers.size(), 3u);
  EXPECT_EQ(m.mat.layers[0].name, "carpet");
  EXPECT_EQ(m.mat.layers[0].thickness_m, 0.005);
  EXPECT_EQ(m.mat.layers[0].mass_kg, 0.0);
  EXPECT_EQ(m.mat.layers[1].name, "stiff");
  EXPECT_EQ(m.mat.layers[1].thickness_m, 0.05);
  EXPECT_EQ(m.mat.layers[1].mass_kg, 2.44);
  EXPECT_EQ(m.mat.layers[2].name, "soft");
  EXPECT_EQ(m.mat.layers[2].thickness_m, 0.15);
  EXPECT_EQ(m.mat.layers[2].mass_kg, 3.66);
  EXPECT_NEAR(m.mat.thickness_m(), 0.205, 1e-15);
  EXPECT_EQ(m.video.points.size(), 6u);
  EXPECT_EQ(m.video.trigger_frame, 500);
  EXPECT_EQ(m.forceplate.az0_m, -0.040);
  ASSERT_EQ(m.trials.size(), 2u);
  EXPECT_EQ(m.trials[1].dir, "trials/trial2");
}

TEST(CaptureManifestSemicolons, SpecExampleReadsVerbatim) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  write_text(path, kSpecManifest);
  expect_spec_manifest(read_manifest(path));
  // The same with Windows line ends.
  std::string crlf;
  for (char c : std::string(kSpecManifest)) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  write_text(path, crlf);
  expect_spec_manifest(read_manifest(path));
}

// The example as it stands in the spec today (skipped when shared/ is not
// beside the source tree).
TEST(CaptureManifestSemicolons, SpecFileExampleReads) {
  const fs::path spec = dropfit::testsupport::shared_path("spec") / "session-format.md";
  DROPFIT_NEED_SHARED(spec);
  const std::string md = read_text(spec.string());
  const std::size_t open = md.find("```toml\n");
  ASSERT_NE(open, std::string::npos);
  const std::size_t close = md.find("```", open + 8);
  ASSERT_NE(close, std::string::npos);
  TempDir dir;
  const std::string path = dir.file("session.toml");
  write_text(path, md.substr(open + 8, close - open - 8));
  const Manifest m = read_manifest(path);
  ASSERT_FALSE(m.mat.layers.empty());
  EXPECT_EQ(m.mat.layers[0].name, "carpet");
  EXPECT_GT(m.mat.layers[0].thickness_m, 0.0);
}

TEST(CaptureManifestSemicolons, ErrorOnALaterKeyNamesTheOriginalLineAndColumn) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  // A bad value on the second key of a split line.
  std::string text = replaced(kSpecManifest, "thickness_m = 0.05;", "thickness_m = -0.05;");
  write_text(path, text);
  Place p = place_of(text, "-0.05;");
  expect_input_error([&] { read_manifest(path); }, path, p.line, p.column, "mat.layers[1].thickness_m", "positive");
  // An unknown key on the third.
  text = replaced(kSpecManifest, "mass_kg = 3.66", "mass_g = 3660");
  write_text(path, text);
  p = place_of(text, "mass_g");
  expect_input_error([&] { read_manifest(path); }, path, p.line, p.column, "mat.layers[2].mass_g", "unknown key");
  // Columns count characters, not bytes ("é" is two bytes in UTF-8).
  text = replaced(kSpecManifest, "name = \"carpet\";  thickness_m = 0.005",
                  "name = \"tapis \xC3\xA9\";  thickness_m = \"thin\"");
  write_text(path, text);
  p = place_of(text, "\"thin\"");
  expect_input_error([&] { read_manifest(path); }, path, p.line, p.column - 1, "mat.layers[0].thickness_m",
                     "expected a number");
}

TEST(CaptureManifestSemicolons, SyntaxErrorInAPieceNamesTheOriginalPosition) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  // Where toml++ puts the error when the bad piece stands on a line of its own...
  const std::string alone = replaced(kSpecManifest, "name = \"stiff\";   thickness_m = 0.05;  mass_kg = 2.44",
                                     "name = \"stiff\"\n  mass_kg = = 2.44");
  write_text(path, alone);
  int alone_line = 0, alone_column = 0;
  try {
    read_manifest(path);
    FAIL() << "no error";
  } catch (const InputError& e) {
    alone_line = e.line();
    alone_column = e.column();
  }
  ASSERT_EQ(alone_line, place_of(alone, "  mass_kg = = 2.44").line);
  ASSERT_GT(alone_column, 2);
  // ...is where it is reported on the ';' line, shifted by the piece's start.
  const std::string text = replaced(kSpecManifest, "name = \"stiff\";   thickness_m = 0.05;  mass_kg = 2.44",
                                    "name = \"stiff\";   thickness_m = 0.05;  mass_kg = = 2.44");
  write_text(path, text);
  const Place piece = place_of(text, "  mass_kg = = 2.44");
  expect_input_error([&] { read_manifest(path); }, path, piece.line, piece.column - 1 + alone_column, "");
}

TEST(CaptureManifestSemicolons, LinesAfterASplitLineKeepTheirNumbers) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  const std::string text = replaced(kSpecManifest, "trigger_frame = 500", "trigger_frame = 500.5");
  write_text(path, text);
  const Place p = place_of(text, "500.5");
  expect_input_error([&] { read_manifest(path); }, path, p.line, p.column, "video.trigger_frame",
                     "expected an integer");
  // And the missing-key error that names a table header below the split lines.
  const std::string no_az0 = replaced(kSpecManifest, "az0_m = -0.040", "");
  write_text(path, no_az0);
  expect_input_error([&] { read_manifest(path); }, path, place_of(no_az0, "[forceplate]").line, 1,
                     "forceplate.az0_m", "missing required key");
}

TEST(CaptureManifestSemicolons, SemicolonsInStringsAndCommentsAndTrailingOnesAreKept) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  std::string text = replaced(kSpecManifest, "name = \"carpet\";  thickness_m = 0.005; mass_kg = 0.0",
                              "name = \"car;pet\";  'thick' = 1; thickness_m = 0.005; mass_kg = 0.0; # a; b = 2");
  text = replaced(text, "name = \"stiff\";   thickness_m = 0.05;  mass_kg = 2.44",
                  "name = 'stiff;'; thickness_m = 0.05;  mass_kg = 2.44;");
  write_text(path, text);
  // 'thick' is a quoted key: it is split off like any other, then refused
  // as unknown at its own position.
  Place p = place_of(text, "'thick'");
  expect_input_error([&] { read_manifest(path); }, path, p.line, p.column, "mat.layers[0].thick", "unknown key");
  text = replaced(text, "'thick' = 1; ", "");
  write_text(path, text);
  const Manifest m = read_manifest(path);
  ASSERT_EQ(m.mat.layers.size(), 3u);
  EXPECT_EQ(m.mat.layers[0].name, "car;pet");
  EXPECT_EQ(m.mat.layers[0].thickness_m, 0.005);
  EXPECT_EQ(m.mat.layers[1].name, "stiff;");
  EXPECT_EQ(m.mat.layers[1].mass_kg, 2.44);
}

TEST(CaptureManifestSemicolons, AmbiguousLinesAreLeftToTheParser) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  // Not a key after the ';', a ';' in an inline array, an empty piece: not
  // split, so the parser reports the line as written, at or after the ';'.
  for (const auto& [from, to] : std::vector<std::pair<std::string, std::string>>{
           {"name = \"carpet\";  thickness_m = 0.005; mass_kg = 0.0", "name = \"carpet\"; 0.005"},
           {"footprint_m = [0.25, 0.25]", "footprint_m = [0.25; 0.25]"},
           {"name = \"soft\";    thickness_m = 0.15;  mass_kg = 3.66", "name = \"soft\";; thickness_m = 0.15"}}) {
    const std::string text = replaced(kSpecManifest, from, to);
    write_text(path, text);
    const Place line = place_of(text, to);
    const int semicolon = line.column + static_cast<int>(to.find(';'));
    try {
      read_manifest(path);
      ADD_FAILURE() << "no error for " << to;
    } catch (const InputError& e) {
      EXPECT_EQ(e.line(), line.line) << e.what();
      EXPECT_GE(e.column(), semicolon) << e.what();
      EXPECT_LE(e.column(), line.column + static_cast<int>(to.size())) << e.what();
    }
  }
  // A ';' inside a multi-line string is text.
  const std::string text =
      replaced(kSpecManifest, "name = \"mat-sample-2026-03\"", "name = \"\"\"\nfirst; second = 1\n\"\"\"");
  write_text(path, text);
  EXPECT_EQ(read_manifest(path).name, "first; second = 1\n");
}

TEST(CaptureBadInput, MalformedNumberNamesLineColumnAndField) {
  TempDir dir;
  const std::string path = dir.file("frame.csv");
  write_text(path, "id,x_m,y_m,z_m,role\nc01,0.1,0.2,0.3,fit\nc02,0.1,1.2x,0.3,check\n");
  // "1.2x" starts at character 9 of line 3.
  expect_input_error([&] { read_frame_csv(path); }, path, 3, 9, "y_m", "'1.2x' is not a number");
}

TEST(CaptureBadInput, DuplicateFrameId) {
  TempDir dir;
  const std::string path = dir.file("frame.csv");
  write_text(path, "id,x_m,y_m,z_m,role\nc01,0.1,0.2,0.3,fit\nc01,0.1,1.2,0.3,check\n");
  expect_input_error([&] { read_frame_csv(path); }, path, 3, 1, "id", "duplicate id 'c01'");
}

TEST(CaptureBadInput, FrameHeaderMissingColumn) {
  TempDir dir;
  const std::string path = dir.file("frame.csv");
  write_text(path, "id,x_m,y_m,role\nc01,0.1,0.2,fit\n");
  expect_input_error([&] { read_frame_csv(path); }, path, 1, 0, "z_m", "missing column");
}

TEST(CaptureBadInput, CameraIdNotInFrame) {
  TempDir dir;
  const std::string frame_path = dir.file("frame.csv");
  write_text(frame_path, "id,x_m,y_m,z_m,role\nc01,0.1,0.2,0.3,fit\nc02,0.1,1.2,0.3,check\n");
  const std::string cam_path = dir.file("cam2.csv");
  write_text(cam_path, "id,u_px,v_px\nc02,1,2\nc01,3,4\nc17,5,6\n");
  const auto frame = read_frame_csv(frame_path);
  expect_input_error([&] { read_camera_csv(cam_path, "cam2", frame); }, cam_path, 4, 1, "id", "'c17'");
}

TEST(CaptureBadInput, MissingFileInSession) {
  TempDir dir;
  write_session(dir.path().string(), test_session());
  const std::string missing = (dir.path() / "trials/trial2" / "force.txt").string();
  fs::remove(missing);
  expect_input_error([&] { read_session(dir.path().string()); }, missing, 0, 0, "", "file not found");
  const std::string cam = (dir.path() / "calibration" / "cam2.csv").string();
  fs::remove(cam);
  expect_input_error([&] { read_session(dir.path().string()); }, cam, 0, 0, "", "file not found");
}

std::string eight_channel_text(int samples_in_header, int rows, const std::string& columns) {
  std::string text = fmt::format(
      "Device\tKistler 9281B\nSample rate\t1000\nSamples\t{}\nPretrigger samples\t1\nTrigger\tFz > 25 N\n\n{}\n",
      samples_in_header, columns);
  const int n_columns = static_cast<int>(std::count(columns.begin(), columns.end(), '\t'));
  for (int i = 0; i < rows; ++i) {
    text += std::to_string((i - 1) * 0.001);
    for (int c = 0; c < n_columns; ++c) text += "\t1.0";
    text += "\n";
  }
  return text;
}

TEST(CaptureBadInput, EightChannelRecordShorterThanHeader) {
  TempDir dir;
  const std::string path = dir.file("force.txt");
  write_text(path, eight_channel_text(10, 8, "Time(s)\tFx12\tFx34\tFy14\tFy23\tFz1\tFz2\tFz3\tFz4"));
  expect_input_error([&] { read_force(path, ForcePlateSpec{}); }, path, 3, -1, "Samples", "only 8 data rows");
}

TEST(CaptureBadInput, EightChannelMissingChannel) {
  TempDir dir;
  const std::string path = dir.file("force.txt");
  write_text(path, eight_channel_text(4, 4, "Time(s)\tFx12\tFx34\tFy14\tFy23\tFz1\tFz2\tFz4"));
  expect_input_error([&] { read_force(path, ForcePlateSpec{}); }, path, 7, 0, "Fz3", "missing column 'Fz3'");
}

TEST(CaptureBadInput, ForceSampleRateDisagreesWithManifest) {
  TempDir dir;
  const std::string path = dir.file("force.txt");
  write_text(path, eight_channel_text(4, 4, "Time(s)\tFx12\tFx34\tFy14\tFy23\tFz1\tFz2\tFz3\tFz4"));
  ForcePlateSpec plate;
  plate.sample_rate_hz = 2000.0;
  expect_input_error([&] { read_force(path, plate); }, path, 2, -1, "Sample rate", "disagrees");
}

TEST(CaptureBadInput, ForceNonUniformTime) {
  TempDir dir;
  const std::string path = dir.file("force.txt");
  write_text(path,
             "Sample rate\t1000\nSamples\t4\nPretrigger samples\t1\n\n"
             "Time(s)\tFx12\tFx34\tFy14\tFy23\tFz1\tFz2\tFz3\tFz4\n"
             "-0.001\t0\t0\t0\t0\t0\t0\t0\t0\n"
             "0.000\t0\t0\t0\t0\t0\t0\t0\t0\n"
             "0.002\t0\t0\t0\t0\t0\t0\t0\t0\n"
             "0.003\t0\t0\t0\t0\t0\t0\t0\t0\n");
  expect_input_error([&] { read_force(path, ForcePlateSpec{}); }, path, 8, 1, "Time(s)", "non-uniform");
}

TEST(CaptureBadInput, BiowareWithoutRate) {
  TempDir dir;
  const std::string path = dir.file("force.txt");
  write_text(path, "abs time (s)\tFx\tFy\tFz\tMx\tMy\tMz\tAx\tAy\ns\tN\tN\tN\tN.m\tN.m\tN.m\tmm\tmm\n0\t0\t0\t0\t0\t0\t0\t0\t0\n");
  expect_input_error([&] { read_force(path, ForcePlateSpec{}); }, path, 0, 0, "Rate (Hz)", "missing");
}

TEST(CaptureBadInput, XyptsPointNotInManifest) {
  TempDir dir;
  const std::string path = dir.file("xypts.csv");
  write_text(path, "mat_n_cam1_U,mat_n_cam1_V,mat_q_cam1_U,mat_q_cam1_V\n1,2,3,4\n");
  Manifest m = test_manifest();
  m.video.trigger_frame = 0;
  expect_input_error([&] { read_xypts(path, m.video); }, path, 1, 27, "mat_q_cam1_U", "'mat_q'");
}

TEST(CaptureBadInput, XyptsCameraNotInManifest) {
  TempDir dir;
  const std::string path = dir.file("xypts.csv");
  write_text(path, "pt1_cam1_X,pt1_cam1_Y,pt1_cam3_X,pt1_cam3_Y\n1,2,3,4\n");
  Manifest m = test_manifest();
  m.video.trigger_frame = 0;
  expect_input_error([&] { read_xypts(path, m.video); }, path, 1, 23, "pt1_cam3_X", "camera 3");
}

TEST(CaptureBadInput, XyptsMalformedNumberAndShortRow) {
  TempDir dir;
  Manifest m = test_manifest();
  m.video.trigger_frame = 0;
  const std::string path = dir.file("xypts.csv");
  write_text(path, "pt1_cam1_X,pt1_cam1_Y\n1,2\n3,4..5\n");
  expect_input_error([&] { read_xypts(path, m.video); }, path, 3, 3, "pt1_cam1_Y", "not a number");
  write_text(path, "pt1_cam1_X,pt1_cam1_Y\n1,2\n3\n");
  expect_input_error([&] { read_xypts(path, m.video); }, path, 3, 2, "pt1_cam1_Y", "1 fields");
}

TEST(CaptureBadInput, XyptsTriggerFrameBeyondFile) {
  TempDir dir;
  Manifest m = test_manifest();
  m.video.trigger_frame = 2;
  const std::string path = dir.file("xypts.csv");
  write_text(path, "pt1_cam1_X,pt1_cam1_Y\n1,2\n3,4\n");
  expect_input_error([&] { read_xypts(path, m.video); }, path, 0, 0, "video.trigger_frame", "beyond");
}

TEST(CaptureIo, WriteSessionRejectsInconsistentSession) {
  TempDir dir;
  Session s = test_session();
  s.trials[1].force.pretrigger_samples += 1;  // BioWare cannot store it
  EXPECT_THROW(write_session(dir.path().string(), s), Error);
  EXPECT_FALSE(fs::exists(dir.path() / "session.toml"));  // nothing written
  s = test_session();
  s.images.pop_back();
  EXPECT_THROW(write_session(dir.path().string(), s), Error);
}

}  // namespace
}  // namespace dropfit::capture
