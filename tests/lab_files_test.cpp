// Lab files as other tools write them: force exports found under the names
// labs keep (BioWare's own names, .C3D in upper case) and by their content.
// Tests that read ../shared/real skip when it is absent, and fail under
// CI=true (where it must be present).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>

#include <cmath>

#include "capture/force_io.h"
#include "forceplate/forceplate.h"
#include "capture/io.h"
#include "core/error.h"
#include "support/c3d_writer.h"
#include "support/temp_dir.h"

namespace dropfit::capture {
namespace {

namespace fs = std::filesystem;
using testsupport::TempDir;
using testsupport::write_text;

fs::path real(const std::string& name) {
  return fs::path(DROPFIT_SOURCE_DIR) / ".." / "shared" / "real" / "kistler-bioware-biomdp" / name;
}

// True when ../shared/real is there; under CI=true its absence is a failure.
bool have_real() {
  if (fs::exists(real("kistler_DJ_2plates.txt"))) return true;
  const char* ci = std::getenv("CI");
  if (ci && std::string(ci) == "true") ADD_FAILURE() << real("") << " is absent under CI=true";
  return false;
}

std::string bioware_text() {
  return "BioWare Version 5.4.3.0 Export\r\nRate (Hz):\t1000.000000\r\n"
         "abs time (s)\tFx\tFy\tFz\r\n\tN\tN\tN\r\n0.000\t0\t0\t1\r\n0.001\t0\t0\t2\r\n";
}

std::string kistler_text() {
  return "Device\tKistler 9281B\nSample rate\t1000\nSamples\t2\nPretrigger samples\t1\n\n"
         "Time(s)\tFx12\tFx34\tFy14\tFy23\tFz1\tFz2\tFz3\tFz4\n-0.001\t0\t0\t0\t0\t0\t0\t0\t0\n"
         "0.000\t0\t0\t0\t0\t1\t1\t1\t1\n";
}

TEST(ForceFileFinding, ContractNamesInAnyCaseOfTheExtension) {
  TempDir dir;
  write_text(dir / "t/force.C3D", std::string(512, '\0'));
  EXPECT_EQ(find_force_file(dir.file("t")), dir.file("t/force.C3D"));
  write_text(dir / "t/force.txt", kistler_text());
  try {
    find_force_file(dir.file("t"));
    ADD_FAILURE() << "two force files accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), dir.file("t"));
    EXPECT_NE(e.reason().find("force.C3D and force.txt"), std::string::npos) << e.what();
  }
}

TEST(ForceFileFinding, ByContentUnderTheNamesLabsKeep) {
  TempDir dir;
  // A trial folder as DLTdv and BioWare leave it: the marker table and
  // offsets with the trial's prefix, and BioWare's export under its own name.
  write_text(dir / "t/drop3xypts.csv", "pt1_cam1_X,pt1_cam1_Y\n1,2\n");
  write_text(dir / "t/drop3offsets.csv", "cam1_offset\n0.000000\n");
  write_text(dir / "t/notes.txt", "dropped from 1.2 m\n");
  write_text(dir / "t/Drop 3 plate1.txt", bioware_text());
  EXPECT_EQ(force_file_kind(dir.file("t/Drop 3 plate1.txt")), ForceFileKind::BioWareText);
  EXPECT_EQ(force_file_kind(dir.file("t/notes.txt")), ForceFileKind::None);
  EXPECT_EQ(find_force_file(dir.file("t")), dir.file("t/Drop 3 plate1.txt"));
  // The export is read from that name like force.txt.
  ForcePlateSpec plate;
  plate.pretrigger_fraction = 0.5;  // two samples: no impact to find a trigger in
  const ForceRecord r = read_force(find_force_file(dir.file("t")), plate);
  EXPECT_EQ(r.data.rows(), 2);
  EXPECT_EQ(r.data(1, 2), 2.0);
  // A Kistler eight-channel export beside it: two candidates, both named.
  write_text(dir / "t/raw.txt", kistler_text());
  EXPECT_EQ(force_file_kind(dir.file("t/raw.txt")), ForceFileKind::KistlerText);
  try {
    find_force_file(dir.file("t"));
    ADD_FAILURE() << "two force exports accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), dir.file("t/force.txt"));
    EXPECT_NE(e.reason().find("Drop 3 plate1.txt and raw.txt"), std::string::npos) << e.what();
  }
  // None: force.txt reported missing, as before.
  TempDir empty;
  write_text(empty / "t/notes.txt", "nothing\n");
  EXPECT_EQ(find_force_file(empty.file("t")), empty.file("t/force.txt"));
}

TEST(ForceFileFinding, RealBioWareExportsUnderTheirOwnNames) {
  if (!have_real()) GTEST_SKIP() << "../shared/real absent";
  for (const char* name : {"kistler_DJ_2plates.C3D", "kistler_DJ_2plates.txt", "kistler_CMJ_1plate.c3d"}) {
    TempDir dir;
    fs::create_directories(dir / "trial1");
    fs::copy_file(real(name), dir / "trial1" / name);
    write_text(dir / "trial1/trial1xypts.csv", "pt1_cam1_X,pt1_cam1_Y\n1,2\n");
    EXPECT_EQ(find_force_file(dir.file("trial1")), (dir / "trial1" / name).string()) << name;
    ForcePlateSpec plate;
    plate.pretrigger_fraction = 0.1;
    const ForceRecord r = read_force(find_force_file(dir.file("trial1")), plate);
    // The drop jump's 8000 samples; the counter-movement jump's record.
    if (std::string(name).find("DJ") != std::string::npos) {
      EXPECT_EQ(r.data.rows(), 8000) << name;
      EXPECT_NEAR(r.data.col(r.layout == ForceLayout::EightChannel ? 4 : 2).maxCoeff(), 0.0, 6000.0) << name;
    } else {
      EXPECT_GT(r.data.rows(), 1000) << name;
    }
  }
}

// ---------------------------------------------------------------------------
// The trigger from the data when the export carries none

// Through the force plate's own processing, which refuses a trigger sample
// more than 10 ms from Fz's first threshold crossing.
forceplate::ForceTrial processed(const ForceRecord& r, const ForcePlateSpec& plate) {
  const forceplate::Resultants raw =
      r.layout == ForceLayout::EightChannel
          ? forceplate::from_eight_channels(r.t_s, r.data,
                                            {r.plate_geometry_m->x(), r.plate_geometry_m->y(), r.plate_geometry_m->z()})
          : forceplate::from_resultant_columns(r.t_s, r.data, 50.0, plate.az0_m);
  forceplate::ProcessOptions o;
  o.pretrigger_samples = r.pretrigger_samples;
  o.trigger_threshold_n = plate.trigger_threshold_n;
  o.sample_rate_hz = plate.sample_rate_hz;
  return forceplate::process(raw, o);
}

TEST(TriggerFromData, RealDropJumpAlignedOnItsLanding) {
  if (!have_real()) GTEST_SKIP() << "../shared/real absent";
  // No pretrigger_fraction: the lab had to find 2933 / 8000 = 0.366625 by
  // hand (0.36 and 0.37 both put the trigger more than 10 ms off).
  ForcePlateSpec plate;
  ASSERT_FALSE(plate.pretrigger_fraction);
  for (const char* name : {"kistler_DJ_2plates.txt", "kistler_DJ_2plates.C3D"}) {
    const ForceRecord r = read_force(real(name).string(), plate);
    EXPECT_TRUE(r.trigger_from_data) << name;
    EXPECT_NEAR(r.pretrigger_samples, 2933, 1) << name << ": " << r.trigger;
    EXPECT_NE(r.trigger.find("from the data"), std::string::npos) << r.trigger;
    EXPECT_NEAR(r.t_s(r.pretrigger_samples), 0.0, 1e-9) << name;
    const forceplate::ForceTrial ft = processed(r, plate);
    EXPECT_NEAR(ft.peak_fz_n, 5040.0, 20.0) << name;
  }
  // A fraction given still wins.
  plate.pretrigger_fraction = 0.25;
  EXPECT_EQ(read_force(real("kistler_DJ_2plates.txt").string(), plate).pretrigger_samples, 2000);
}

// A BioWare export whose record starts loaded: someone stands on the plate
// (700 N, swaying 5 N), steps off, the plate rests with a slow zero drift,
// then the impact. The trigger is the impact's crossing above the quiet
// stretch before it.
TEST(TriggerFromData, QuietBeforeImpactWhenTheRecordStartsLoaded) {
  TempDir dir;
  std::string s = "BioWare Version 5.3.0.7 Export\nRate (Hz):\t1000.000000\nabs time (s)\tFz\n\tN\n";
  for (int i = 0; i < 3000; ++i) {
    double fz = 0.002 * i + 0.4 * std::sin(0.7 * i);                                // drift and noise
    if (i < 400) fz += 700.0 + 5.0 * std::sin(0.05 * i);                             // standing
    if (i >= 400 && i < 500) fz += 700.0 * (500 - i) / 100.0;                        // stepping off
    if (i >= 2000) fz += 6000.0 * std::exp(-0.5 * std::pow((i - 2040) / 15.0, 2));  // the impact
    s += fmt::format("{:.3f}\t{:.6f}\n", 0.001 * i, fz);
  }
  write_text(dir / "drop.txt", s);
  ForcePlateSpec plate;
  const ForceRecord r = read_force(dir.file("drop.txt"), plate);
  // The impact starts at i = 2000 with 6000 exp(-0.5 (40 / 15)^2) = 171 N,
  // past 25 N above the quiet level (the drift's 4 N there) at once.
  EXPECT_EQ(r.pretrigger_samples, 2000) << r.trigger;
  // The quiet level is the stretch just before it (samples 1950-1999, drift
  // 3.9-4.0 N), not the standing start.
  const std::optional<DataTrigger> t = trigger_sample_from_data(r, plate.trigger_threshold_n);
  ASSERT_TRUE(t);
  EXPECT_NEAR(t->quiet_level_n, 3.95, 0.2);
  // A record with no impact: refused, naming Fz.
  std::string flat = "BioWare Version 5.3.0.7 Export\nRate (Hz):\t1000.000000\nabs time (s)\tFz\n\tN\n";
  for (int i = 0; i < 500; ++i) flat += fmt::format("{:.3f}\t{:.6f}\n", 0.001 * i, 0.4 * std::sin(0.7 * i));
  write_text(dir / "flat.txt", flat);
  try {
    read_force(dir.file("flat.txt"), plate);
    ADD_FAILURE() << "a record without an impact was given a trigger";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "Fz");
    EXPECT_NE(e.reason().find("pretrigger_fraction"), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------------------
// Every error located, number ranges included; trial ids and folders checked
// when the manifest is read

const char* kManifest = R"([session]
name = "lab"
[impactor]
mass_kg = 24.0
footprint_m = [0.25, 0.25]
base_markers = ["imp"]
[mat]
length_m = 0.9
width_m = 0.6
surface_markers = []
[[mat.layers]]
name = "foam"
thickness_m = 0.1
mass_kg = 3.0
[video]
cameras = ["cam1", "cam2"]
frame_rate_hz = 1000
points = ["imp"]
trigger_frame = 0
[forceplate]
sample_rate_hz = 1000
trigger_threshold_n = 25.0
a_m = 0.12
b_m = 0.2
az0_m = -0.04
mat_top_z_m = 0.1
[[trial]]
id = "t1"
dir = "trials/t1"
)";

void expect_manifest_error(const std::string& trial_lines, const std::string& field, const std::string& reason) {
  TempDir dir;
  std::string text = kManifest;
  text.replace(text.find("[[trial]]"), std::string::npos, trial_lines);
  write_text(dir / "session.toml", text);
  try {
    read_manifest(dir.file("session.toml"));
    ADD_FAILURE() << "accepted: " << trial_lines;
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), dir.file("session.toml"));
    EXPECT_EQ(e.line(), 28) << e.what();  // the line of the offending key
    EXPECT_EQ(e.field(), field) << e.what();
    EXPECT_NE(e.reason().find(reason), std::string::npos) << e.what();
    EXPECT_EQ(std::string(e.what()).find('\0'), std::string::npos) << "a NUL in the message";
  }
}

TEST(LocatedErrors, TrialIdsAndFoldersCheckedWhenTheManifestIsRead) {
  // Without pretrigger_fraction the manifest is read (the trigger comes from the data).
  {
    TempDir dir;
    write_text(dir / "session.toml", kManifest);
    const Manifest m = read_manifest(dir.file("session.toml"));
    EXPECT_FALSE(m.forceplate.pretrigger_fraction);
    EXPECT_EQ(m.trials.at(0).id, "t1");
  }
  expect_manifest_error("[[trial]]\nid = \"t\\u0000x\"\ndir = \"trials/t1\"\n", "trial[0].id",
                        "control character \\x00 at character 2");
  expect_manifest_error("[[trial]]\nid = \"" + std::string(300, 'a') + "\"\ndir = \"trials/t1\"\n", "trial[0].id",
                        "300 characters, more than 128");
  expect_manifest_error("[[trial]]\nid = \"a/b\"\ndir = \"trials/t1\"\n", "trial[0].id", "not a plain file name");
  expect_manifest_error("[[trial]]\nid = \"..\"\ndir = \"trials/t1\"\n", "trial[0].id", "not a plain file name");
  expect_manifest_error("[[trial]]\ndir = \"../other/t1\"\nid = \"t1\"\n", "trial[0].dir", "leaves the session folder");
  expect_manifest_error("[[trial]]\ndir = \"trials/../../t1\"\nid = \"t1\"\n", "trial[0].dir",
                        "leaves the session folder");
  expect_manifest_error("[[trial]]\ndir = \"/data/t1\"\nid = \"t1\"\n", "trial[0].dir", "is absolute");
  expect_manifest_error("[[trial]]\ndir = \".\"\nid = \"t1\"\n", "trial[0].dir", "the session folder itself");
}

TEST(LocatedErrors, TrialFolderLinkedOutsideTheSessionIsRefused) {
  TempDir dir;
  write_text(dir / "session/session.toml", kManifest);
  fs::create_directories(dir / "elsewhere/t1");
  write_text(dir / "elsewhere/t1/xypts.csv", "pt1_cam1_X,pt1_cam1_Y\n1,2\n");
  fs::create_directories(dir / "session/trials");
  fs::create_directory_symlink(dir / "elsewhere/t1", dir / "session/trials/t1");
  try {
    read_session(dir.file("session"));
    ADD_FAILURE() << "a trial folder outside the session was read";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), dir.file("session/session.toml"));
    EXPECT_EQ(e.field(), "trial.dir");
    EXPECT_NE(e.reason().find("outside the session folder"), std::string::npos) << e.what();
  }
}

// read_frame_csv of `text` throws an InputError at `line` (and `column`
// when not -1) and `field`, whose reason holds `reason_part`.
void expect_frame_error(const TempDir& dir, const std::string& text, int line, int column, const std::string& field,
                        const std::string& reason_part) {
  write_text(dir / "frame.csv", text);
  try {
    read_frame_csv(dir.file("frame.csv"));
    ADD_FAILURE() << text;
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), line) << e.what();
    if (column != -1) {
      EXPECT_EQ(e.column(), column) << e.what();
    }
    EXPECT_EQ(e.field(), field) << e.what();
    EXPECT_NE(e.reason().find(reason_part), std::string::npos) << e.what();
  }
}

TEST(LocatedErrors, NumbersOutOfRangeNamedWhereWritten) {
  TempDir dir;
  // 1e308 is a finite double, but no lab position: refused at its line and
  // field, not later as "all lie at one lab position".
  expect_frame_error(dir, "id,x_m,y_m,z_m,role\nc01,0,0,0,fit\nc02,1e308,0,0.3,fit\n", 3, 5, "x_m",
                     "out of range for a lab position in metres");
  // A frame written in millimetres (a 0.4 m structure reads 400): refused at
  // the first coordinate beyond 100 m, the reason naming the unit.
  expect_frame_error(dir, "id,x_m,y_m,z_m,role\nc01,-424.0,-266.0,30.0,fit\n", 2, 5, "x_m", "millimetres");
  // 1e400 overflows a double: refused too, located.
  expect_frame_error(dir, "id,x_m,y_m,z_m,role\nc01,0,0,1e400,fit\n", 2, -1, "z_m", "");
  // Pixels: a camera file and a marker table.
  std::vector<CalibrationMarker> frame = {{"c01", Eigen::Vector3d::Zero(), MarkerRole::Fit}};
  write_text(dir / "cam1.csv", "id,u_px,v_px\nc01,1e300,5\n");
  try {
    read_camera_csv(dir.file("cam1.csv"), "cam1", frame);
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 2);
    EXPECT_EQ(e.field(), "u_px");
  }
  VideoSpec v;
  v.cameras = {"cam1"};
  v.points = {"imp"};
  write_text(dir / "xypts.csv", "pt1_cam1_X,pt1_cam1_Y\n1,2\n3,-4e9\n");
  try {
    read_xypts(dir.file("xypts.csv"), v);
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 3);
    EXPECT_EQ(e.field(), "pt1_cam1_Y");
  }
}

// A stated marker limit instead of a calibration that never ends: the 501st
// marker is refused at its line, 500 are read.
TEST(Bounds, CalibrationMarkerLimitNamedAtItsLine) {
  TempDir dir;
  std::string text = "id,x_m,y_m,z_m,role\n";
  for (int i = 0; i < 500; ++i)
    text += fmt::format("c{},{},{},{},fit\n", i, 0.01 * (i % 10), 0.01 * ((i / 10) % 10), 0.01 * (i / 100));
  write_text(dir / "frame.csv", text);
  EXPECT_EQ(read_frame_csv(dir.file("frame.csv")).size(), 500u);
  write_text(dir / "frame.csv", text + "c500,1,1,1,fit\n");
  try {
    read_frame_csv(dir.file("frame.csv"));
    ADD_FAILURE() << "501 markers accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.line(), 502);
    EXPECT_NE(e.reason().find("more than 500 calibration markers"), std::string::npos) << e.what();
  }
}

// ---------------------------------------------------------------------------
// markers.c3d: 3-D markers in place of the marker table and calibration

// A markers-only C3D as a motion-capture system writes it: integer samples
// scaled by the header's point scale factor (0.1 mm per count), each point's
// fourth word the residual (low byte, in scale units) and camera mask (high
// byte), -1 for a lost marker; labels upper case, padded with blanks; no
// analog channels.
std::string motion_capture_c3d(int n_frames, double rate_hz, testsupport::c3d::C3dProcessor processor) {
  using namespace testsupport::c3d;
  Spec s;
  s.processor = processor;
  s.float_data = false;
  s.point_scale = 0.1;
  s.point_rate_hz = rate_hz;
  s.n_frames = n_frames;
  s.n_points = 2;
  s.n_analog = 0;
  s.analog_per_frame = 0;
  s.points.resize(n_frames, 8);
  for (int f = 0; f < n_frames; ++f) {
    // IMP falls from 500 mm at 1 mm per frame; MAT_N rests at 205 mm.
    const double imp[3] = {10.0, -20.0, 500.0 - f}, mat[3] = {300.0, 0.0, 205.0};
    for (int k = 0; k < 3; ++k) {
      s.points(f, k) = imp[k] / 0.1;
      s.points(f, 4 + k) = mat[k] / 0.1;
    }
    s.points(f, 3) = (0x0C << 8) | 2;              // seen by cameras 3 and 4, residual 0.2 mm
    s.points(f, 7) = f == 3 ? -1.0 : (0x03 << 8) | 1;  // MAT_N lost in frame 3
  }
  s.groups = {{"POINT",
               {num("USED", 2, {}, {2}), num("SCALE", 4, {}, {0.1}), num("RATE", 4, {}, {rate_hz}),
                num("FRAMES", 2, {}, {static_cast<double>(n_frames)}), str("LABELS", 30, {"IMP", "MAT_N"}),
                str("DESCRIPTIONS", 32, {"impactor base", "mat north"}), str("UNITS", 4, {"mm"})}},
              {"ANALOG", {num("USED", 2, {}, {0}), num("RATE", 4, {}, {rate_hz})}}};
  return write_c3d(s);
}

TEST(Markers3d, TrialWithMarkersC3dNeedsNoMarkerTableOrCalibration) {
  for (const auto processor : {testsupport::c3d::C3dProcessor::Intel, testsupport::c3d::C3dProcessor::Mips}) {
    TempDir dir;
    std::string manifest = kManifest;
    manifest.replace(manifest.find("points = [\"imp\"]"), 16, "points = [\"imp\", \"mat_n\"]");
    write_text(dir / "session.toml", manifest);
    write_text(dir / "trials/t1/markers.c3d", motion_capture_c3d(300, 1000.0, processor));
    std::string force = "BioWare Version 5.4.3.0 Export\nRate (Hz):\t1000.000000\nabs time (s)\tFz\n\tN\n";
    for (int i = 0; i < 600; ++i) force += fmt::format("{:.3f}\t{:.3f}\n", 0.001 * i, i >= 300 ? 2000.0 : 0.0);
    write_text(dir / "trials/t1/t1.txt", force);
    const Session s = read_session(dir.path().string());
    ASSERT_EQ(s.trials.size(), 1u);
    const TrialRecording& t = s.trials[0];
    ASSERT_TRUE(t.has_3d_markers());
    EXPECT_EQ(t.markers_path, dir.file("trials/t1/markers.c3d"));
    ASSERT_EQ(t.markers_xyz_m.rows(), 300);
    ASSERT_EQ(t.markers_xyz_m.cols(), 6);
    // Metres in the lab frame: counts x 0.1 mm (float 0.1f: 1e-6 relative).
    EXPECT_NEAR(t.markers_xyz_m(0, 2), 0.500, 1e-6);
    EXPECT_NEAR(t.markers_xyz_m(100, 2), 0.400, 1e-6);
    EXPECT_NEAR(t.markers_xyz_m(100, 0), 0.010, 1e-7);
    EXPECT_NEAR(t.markers_xyz_m(0, 5), 0.205, 1e-6);
    EXPECT_TRUE(std::isnan(t.markers_xyz_m(3, 5)));  // lost, never 0
    EXPECT_EQ(t.tracks.n_frames(), 0);
    EXPECT_TRUE(s.frame.empty());
    EXPECT_FALSE(s.calibration_needed());
    EXPECT_EQ(t.force.pretrigger_samples, 300);

    // A marker table beside it: which is meant is not known.
    write_text(dir / "trials/t1/xypts.csv", "pt1_cam1_X,pt1_cam1_Y\n1,2\n");
    try {
      read_session(dir.path().string());
      ADD_FAILURE() << "markers.c3d and xypts.csv both accepted";
    } catch (const InputError& e) {
      EXPECT_EQ(e.field(), "markers.c3d");
      EXPECT_NE(e.reason().find("markers.c3d and xypts.csv"), std::string::npos) << e.what();
    }
    fs::remove(dir / "trials/t1/xypts.csv");
    // A frame rate other than the manifest's: refused naming POINT:RATE.
    write_text(dir / "trials/t1/markers.c3d", motion_capture_c3d(300, 200.0, processor));
    try {
      read_session(dir.path().string());
      ADD_FAILURE() << "200 Hz markers accepted for a 1000 Hz manifest";
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), dir.file("trials/t1/markers.c3d"));
      EXPECT_EQ(e.field(), "POINT:RATE");
    }
  }
}

}  // namespace
}  // namespace dropfit::capture
