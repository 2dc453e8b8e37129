// The C3D reader (capture/c3d.h) and the force / marker records built from it
// (capture/force_io.h): synthetic files written here in all three processor
// formats, integer and floating point; truncated and corrupted files; and
// the real Kistler C3D exports of shared/real/kistler-bioware-biomdp
// against BioWare's own text exports of the same trials.
#include <gtest/gtest.h>
#include <unistd.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "capture/c3d.h"
#include "capture/force_io.h"
#include "capture/io.h"
#include "core/error.h"
#include "forceplate/forceplate.h"
#include "samples/generator/synth.h"
#include "support/c3d_writer.h"
#include "support/temp_dir.h"
#include "support/shared_data.h"

namespace fs = std::filesystem;
using namespace dropfit;
using namespace dropfit::capture;

namespace {

using namespace dropfit::testsupport::c3d;

// Two points and a TYPE 3 plate's eight channels plus one extra channel.
Spec sample_spec(C3dProcessor p, bool float_data) {
  Spec s;
  s.processor = p;
  s.float_data = float_data;
  s.n_frames = 6;
  s.n_points = 2;
  s.n_analog = 9;
  s.analog_per_frame = 10;
  s.points.resize(s.n_frames, 8);
  s.analog.resize(s.n_frames * s.analog_per_frame, s.n_analog);
  for (int f = 0; f < s.n_frames; ++f) {
    for (int pt = 0; pt < 2; ++pt) {
      // Integer files store counts (x 0.1 mm); float files millimetres.
      const double x = 100.0 + 10 * f + pt, y = -50.0 - f, z = 300.5 + 0.5 * pt;
      const double k = float_data ? 1.0 : 1.0 / s.point_scale;
      s.points(f, 4 * pt + 0) = x * k;
      s.points(f, 4 * pt + 1) = y * k;
      s.points(f, 4 * pt + 2) = z * k;
      s.points(f, 4 * pt + 3) = (pt == 1 && f == 2) ? -1.0 : 3.0;  // point 2 invalid in frame 3
    }
  }
  for (int i = 0; i < s.analog.rows(); ++i)
    for (int c = 0; c < s.n_analog; ++c) s.analog(i, c) = (c + 1) * 100 + i - 30;  // counts, signed
  std::vector<double> scale, offset;
  for (int c = 0; c < s.n_analog; ++c) {
    scale.push_back(c < 4 ? 0.04 : 0.16);
    offset.push_back(c == 5 ? 7 : 0);
  }
  s.groups = {
      {"POINT",
       {num("USED", 2, {}, {2}), num("SCALE", 4, {}, {s.float_data ? -s.point_scale : s.point_scale}),
        num("RATE", 4, {}, {100.0}), str("LABELS", 8, {"imp_top", "mat_n"}), str("UNITS", 2, {"mm"})}},
      {"ANALOG",
       {num("USED", 2, {}, {9}), num("RATE", 4, {}, {1000.0}), num("GEN_SCALE", 4, {}, {2.0}),
        num("SCALE", 4, {9}, scale), num("OFFSET", 2, {9}, offset),
        str("UNITS", 2, {"N", "N", "N", "N", "N", "N", "N", "N", "V"})}},
      {"FORCE_PLATFORM",
       {num("USED", 2, {}, {1}), num("TYPE", 2, {1}, {3}), num("ORIGIN", 4, {3, 1}, {120, 200, 40}),
        num("CHANNEL", 2, {8, 1}, {1, 2, 3, 4, 5, 6, 7, 8})}},
  };
  return s;
}

using dropfit::testsupport::TempDir;

// Every check of the synthetic sample, whatever its processor and number format.
void check_sample(const C3dFile& f, const Spec& s) {
  EXPECT_EQ(f.processor, s.processor);
  EXPECT_EQ(f.float_data, s.float_data);
  EXPECT_EQ(f.n_frames, s.n_frames);
  EXPECT_EQ(f.n_points, 2);
  EXPECT_EQ(f.n_analog_channels, 9);
  EXPECT_EQ(f.analog_per_frame, 10);
  EXPECT_DOUBLE_EQ(f.point_rate_hz, 100.0);
  EXPECT_DOUBLE_EQ(f.analog_rate_hz(), 1000.0);
  ASSERT_NE(f.find("point", "labels"), nullptr);
  EXPECT_EQ(f.find("POINT", "LABELS")->strings, (std::vector<std::string>{"imp_top", "mat_n"}));
  // Point coordinates: integer counts x 0.1 mm are exact to float rounding
  // of the scale (0.1f), i.e. 1e-5 relative; float files store floats.
  for (int fr = 0; fr < s.n_frames; ++fr) {
    EXPECT_NEAR(f.points(fr, 0), 100.0 + 10 * fr, 1e-3);
    EXPECT_NEAR(f.points(fr, 1), -50.0 - fr, 1e-3);
    if (fr != 2) {
      EXPECT_NEAR(f.points(fr, 6), 301.0, 1e-3);
    }
    EXPECT_EQ(std::isnan(f.points(fr, 4)), fr == 2) << fr;
  }
  EXPECT_NEAR(f.points(0, 3), 3 * 0.1, 1e-6);  // residual 3 x |scale|
  // Analog: stored values exactly (small integers, exact in float too).
  for (int i = 0; i < f.analog_stored.rows(); ++i)
    for (int c = 0; c < 9; ++c) ASSERT_EQ(f.analog_stored(i, c), (c + 1) * 100 + i - 30) << i << " " << c;
  // Scaled: (stored - offset) x scale x gen_scale; float scale 0.16f.
  const Eigen::MatrixXd si = c3d_analog_scaled(f, {5});
  EXPECT_NEAR(si(0, 0), (600 - 30 - 7) * 0.16 * 2.0, 1e-4);
}

// ---------------------------------------------------------------------------
// Synthetic files
// ---------------------------------------------------------------------------

struct Format {
  C3dProcessor processor;
  bool float_data;
};

class C3dFormats : public ::testing::TestWithParam<Format> {};

TEST_P(C3dFormats, ReadsPointsAnalogAndParameters) {
  const Spec s = sample_spec(GetParam().processor, GetParam().float_data);
  const C3dFile f = parse_c3d(write_c3d(s), "sample.c3d");
  check_sample(f, s);
}

TEST_P(C3dFormats, ForcePlateType3AndMarkers) {
  const Spec s = sample_spec(GetParam().processor, GetParam().float_data);
  TempDir dir;
  const std::string path = dir.write("force.c3d", write_c3d(s));
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  plate.pretrigger_fraction = 0.1;
  const ForceRecord r = read_force(path, plate);  // dispatch on the extension
  EXPECT_EQ(r.layout, ForceLayout::EightChannel);
  ASSERT_EQ(r.data.rows(), 60);
  ASSERT_EQ(r.data.cols(), 8);
  EXPECT_EQ(r.pretrigger_samples, 6);  // round(0.1 x 60)
  EXPECT_NEAR(r.t_s[6], 0.0, 1e-12);
  EXPECT_NEAR(r.t_s[7] - r.t_s[6], 1e-3, 1e-12);
  // Channel 6 (Fz2) of sample 0: (600 - 30 - 7) x 0.16 x 2 N; float 0.16f.
  EXPECT_NEAR(r.data(0, 5), 563 * 0.32, 1e-4);
  EXPECT_NEAR(r.data(10, 0), (100 + 10 - 30) * 0.08, 1e-5);
  ASSERT_TRUE(r.plate_geometry_m.has_value());
  EXPECT_NEAR((*r.plate_geometry_m)[0], 0.120, 1e-9);
  EXPECT_NEAR((*r.plate_geometry_m)[1], 0.200, 1e-9);
  EXPECT_NEAR((*r.plate_geometry_m)[2], -0.040, 1e-9);  // ORIGIN z +40 mm: surface above the sensors

  const MarkerTrajectories m = read_markers_c3d(path, {"MAT_N", "imp_top"});
  ASSERT_EQ(m.xyz_m.rows(), 6);
  ASSERT_EQ(m.xyz_m.cols(), 6);
  EXPECT_NEAR(m.xyz_m(1, 3), 0.110, 1e-6);  // imp_top x at frame 2 in m
  EXPECT_NEAR(m.xyz_m(1, 2), 0.3010, 1e-6);  // mat_n z
  EXPECT_TRUE(std::isnan(m.xyz_m(2, 0)));    // mat_n invalid in frame 3
  EXPECT_DOUBLE_EQ(m.frame_rate_hz, 100.0);
}

INSTANTIATE_TEST_SUITE_P(AllProcessors, C3dFormats,
                         ::testing::Values(Format{C3dProcessor::Intel, false}, Format{C3dProcessor::Intel, true},
                                           Format{C3dProcessor::Dec, false}, Format{C3dProcessor::Dec, true},
                                           Format{C3dProcessor::Mips, false}, Format{C3dProcessor::Mips, true}),
                         [](const auto& info) {
                           const char* p = info.param.processor == C3dProcessor::Intel ? "Intel"
                                           : info.param.processor == C3dProcessor::Dec ? "Dec"
                                                                                       : "Mips";
                           return std::string(p) + (info.param.float_data ? "Float" : "Int");
                         });

// DEC floats against known bit patterns (VAX F: 1.0 is 0x4080 0x0000 as
// little-endian words), independent of this file's writer.
TEST(C3dDec, VaxFloatBitPatterns) {
  Spec s = sample_spec(C3dProcessor::Dec, true);
  std::string bytes = write_c3d(s);
  // Header words 11-12: the frame rate 100.0 = 0.78125 x 2^7: VAX exponent
  // 128 + 7 = 135, mantissa .5625 after the hidden bit: word 0x43C8.
  EXPECT_EQ(static_cast<unsigned char>(bytes[20]), 0xC8);
  EXPECT_EQ(static_cast<unsigned char>(bytes[21]), 0x43);
  EXPECT_EQ(static_cast<unsigned char>(bytes[22]), 0x00);
  EXPECT_EQ(static_cast<unsigned char>(bytes[23]), 0x00);
  // Patch the scale factor (words 7-8) to VAX -1.0 (0xC080 0x0000): float data, scale 1.
  bytes[12] = static_cast<char>(0x80);
  bytes[13] = static_cast<char>(0xC0);
  bytes[14] = 0;
  bytes[15] = 0;
  const C3dFile f = parse_c3d(bytes, "dec.c3d");
  EXPECT_TRUE(f.float_data);
  EXPECT_DOUBLE_EQ(f.point_scale, -1.0);
  EXPECT_DOUBLE_EQ(f.point_rate_hz, 100.0);
}

TEST(C3dForce, Type2ResultantsMovedToThePlateAxis) {
  Spec s = sample_spec(C3dProcessor::Intel, true);
  s.n_analog = 6;
  s.analog.resize(s.n_frames * s.analog_per_frame, 6);
  // Fx Fy Fz (N) Mx My Mz (N mm) about the transducer.
  for (int i = 0; i < s.analog.rows(); ++i) {
    s.analog.row(i) << 10.0, -20.0, 800.0 + i, 4000.0, -8000.0, 500.0;
  }
  s.groups[1] = {"ANALOG",
                 {num("USED", 2, {}, {6}), num("RATE", 4, {}, {1000.0}), num("GEN_SCALE", 4, {}, {1.0}),
                  num("SCALE", 4, {6}, {1, 1, 1, 1, 1, 1}), num("OFFSET", 2, {6}, {0, 0, 0, 0, 0, 0}),
                  str("UNITS", 4, {"N", "N", "N", "Nmm", "Nmm", "Nmm"})}};
  s.groups[2] = {"FORCE_PLATFORM",
                 {num("USED", 2, {}, {1}), num("TYPE", 2, {1}, {2}), num("ORIGIN", 4, {3, 1}, {2.0, -3.0, -41.0}),
                  num("CHANNEL", 2, {6, 1}, {1, 2, 3, 4, 5, 6})}};
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  plate.pretrigger_fraction = 0.1;  // a steady load: no impact to find a trigger in
  const ForceRecord r = force_record_from_c3d(parse_c3d(write_c3d(s), "t2.c3d"), plate);
  EXPECT_EQ(r.layout, ForceLayout::Resultants);
  // Transducer at -ORIGIN = (-2, 3) mm from the centre: Mx += oy Fz, My -= ox Fz.
  const double fz = 800.0;
  EXPECT_NEAR(r.data(0, 2), fz, 1e-9);
  EXPECT_NEAR(r.data(0, 3), 4.0 + 0.003 * fz, 1e-9);
  EXPECT_NEAR(r.data(0, 4), -8.0 + 0.002 * fz, 1e-9);
  EXPECT_NEAR(r.data(0, 5), 0.5 + (-0.002) * (-20.0) - 0.003 * 10.0, 1e-9);
  EXPECT_TRUE(std::isnan(r.data(0, 6)));
  ASSERT_TRUE(r.plate_geometry_m.has_value());
  EXPECT_NEAR((*r.plate_geometry_m)[2], -0.041, 1e-9);
  // The centre of pressure of a point load at (px, py) on the surface:
  // check with a load whose moments about the transducer are known.
  // F = (0, 0, Fz) at P = (30, -10) mm: M about O = (P - O) x F with
  // O = (-2, 3, 41 below) -> Mx = (py - oy) Fz, My = -(px - ox) Fz.
  for (int i = 0; i < s.analog.rows(); ++i) {
    const double f = 900.0;
    s.analog.row(i) << 0.0, 0.0, f, (-10.0 - 3.0) * f, -(30.0 - (-2.0)) * f, 0.0;
  }
  const ForceRecord p = force_record_from_c3d(parse_c3d(write_c3d(s), "t2.c3d"), plate);
  const forceplate::Resultants res = forceplate::from_resultant_columns(p.t_s, p.data, 50.0, (*p.plate_geometry_m)[2]);
  const Eigen::MatrixXd cop = forceplate::centre_of_pressure(res.f_n, res.m_n_m, res.az0_m, 50.0);
  // Float storage of the moments (about 3e4 N mm): 1e-6 relative -> 1e-5 m.
  EXPECT_NEAR(cop(0, 0), 0.030, 1e-5);
  EXPECT_NEAR(cop(0, 1), -0.010, 1e-5);
}

TEST(C3dForce, RefusesWithTheParameterNamed) {
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  plate.pretrigger_fraction = 0.1;  // not about the trigger
  auto expect_field = [&](const Spec& s, const std::string& field, const std::string& part) {
    try {
      force_record_from_c3d(parse_c3d(write_c3d(s), "bad.c3d"), plate);
      ADD_FAILURE() << "accepted; expected an error naming " << field;
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), "bad.c3d");
      EXPECT_EQ(e.field(), field) << e.what();
      EXPECT_NE(std::string(e.what()).find(part), std::string::npos) << e.what();
    }
  };
  Spec s = sample_spec(C3dProcessor::Intel, false);
  s.groups[2].params[1] = num("TYPE", 2, {1}, {4});
  expect_field(s, "FORCE_PLATFORM:TYPE", "type 4");
  s = sample_spec(C3dProcessor::Intel, false);
  s.groups[2].params[3] = num("CHANNEL", 2, {8, 1}, {1, 2, 3, 4, 5, 6, 7, 12});
  expect_field(s, "FORCE_PLATFORM:CHANNEL", "analog channel 12");
  s = sample_spec(C3dProcessor::Intel, false);
  s.groups[1].params[3] = num("SCALE", 4, {4}, {1, 1, 1, 1});
  expect_field(s, "ANALOG:SCALE", "channel 5");
  s = sample_spec(C3dProcessor::Intel, false);
  s.groups[1].params[1] = num("RATE", 4, {}, {2000.0});
  expect_field(s, "ANALOG:RATE", "disagrees");
  s = sample_spec(C3dProcessor::Intel, false);
  s.groups.pop_back();
  expect_field(s, "FORCE_PLATFORM:USED", "missing");
  s = sample_spec(C3dProcessor::Intel, false);
  plate.plate = 2;
  expect_field(s, "FORCE_PLATFORM:USED", "plate = 2");
  plate.plate = 1;
  s = sample_spec(C3dProcessor::Intel, false);
  try {
    markers_from_c3d(parse_c3d(write_c3d(s), "m.c3d"), {"imp_top", "imp_base"});
    ADD_FAILURE() << "a missing label was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "POINT:LABELS");
    EXPECT_NE(std::string(e.what()).find("imp_base"), std::string::npos) << e.what();
  }
}

// Truncated at every length, and single bytes corrupted: an InputError
// naming the file (never a crash, never a bad read: run under the
// sanitizers by the fuzz target too).
TEST(C3dRobust, TruncatedAtEveryLengthIsAnError) {
  const std::string bytes = write_c3d(sample_spec(C3dProcessor::Intel, false));
  // Header word 9: the first data block; 6 frames of (2 points x 4 + 9
  // channels x 10 samples) int16 values follow it. Cut anywhere before
  // their end the file must be refused; cutting only block padding not.
  const std::size_t data_start =
      (static_cast<unsigned char>(bytes[16]) + 256u * static_cast<unsigned char>(bytes[17]) - 1) * 512;
  const std::size_t data_end = data_start + 6 * (2 * 4 + 9 * 10) * 2;
  ASSERT_LE(data_end, bytes.size());
  for (std::size_t n = 0; n <= bytes.size(); ++n) {
    bool accepted = false;
    try {
      parse_c3d(std::string_view(bytes).substr(0, n), "cut.c3d");
      accepted = true;
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), "cut.c3d");
    }
    EXPECT_EQ(accepted, n >= data_end) << "cut to " << n << " bytes";
  }
}

TEST(C3dRobust, CorruptBytesGiveErrorsOrValues) {
  const std::string bytes = write_c3d(sample_spec(C3dProcessor::Mips, true));
  std::mt19937 rng(12);
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  plate.pretrigger_fraction = 0.1;  // not about the trigger
  int refused = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    std::string b = bytes;
    const int flips = 1 + trial % 4;
    for (int k = 0; k < flips; ++k) {
      // Mostly the header and parameter blocks, where the structure is.
      const std::size_t at = rng() % (trial % 2 ? 1024 : b.size());
      b[at] = static_cast<char>(rng() & 0xFF);
    }
    try {
      const C3dFile f = parse_c3d(b, "corrupt.c3d");
      const ForceRecord r = force_record_from_c3d(f, plate);
      EXPECT_EQ(r.data.cols(), 8);
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), "corrupt.c3d");
      EXPECT_FALSE(std::string(e.what()).empty());
      ++refused;
    }
  }
  EXPECT_GT(refused, 100);  // the header bytes alone make many of these invalid
}

TEST(C3dRobust, HeaderErrorsNameTheWord) {
  std::string bytes = write_c3d(sample_spec(C3dProcessor::Intel, false));
  std::string b = bytes;
  b[1] = 0x51;
  try {
    parse_c3d(b, "x.c3d");
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "header byte 2");
  }
  b = bytes;
  b[512 + 3] = 83;
  try {
    parse_c3d(b, "x.c3d");
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "processor type");
  }
  try {
    read_c3d((fs::temp_directory_path() / "dropfit_no_such_file.c3d").string());
    ADD_FAILURE();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("not found"), std::string::npos);
  }
}

TEST(C3dSession, FindForceFile) {
  TempDir dir;
  EXPECT_EQ(find_force_file(dir.path().string()), (dir.path() / "force.txt").string());
  dir.write("force.c3d", "x");
  EXPECT_EQ(find_force_file(dir.path().string()), (dir.path() / "force.c3d").string());
  dir.write("force.txt", "x");
  EXPECT_THROW(find_force_file(dir.path().string()), InputError);
}

// A session whose trial holds force.c3d instead of force.txt: read_session
// takes it, with the C3D's ORIGIN as the plate geometry, and the force plate
// gives the same trial as from the text export.
TEST(C3dSession, TrialWithForceC3d) {
  synth::SynthOptions o;
  o.impact_velocities_m_s = {5.0};
  const synth::SyntheticSession syn = synth::make_session(o);
  TempDir dir;
  const fs::path root = dir.path() / "session";
  write_session(root.string(), syn.session);
  const Manifest& m = syn.session.manifest;
  const ForceRecord& txt = syn.session.trials[0].force;
  ASSERT_EQ(txt.layout, ForceLayout::EightChannel);

  // The eight channels as a float C3D (1000 Hz analog, 10 per point frame),
  // ORIGIN as BioWare writes it (az0 positive).
  Spec s;
  s.float_data = true;
  s.point_rate_hz = m.forceplate.sample_rate_hz / 10.0;
  s.n_points = 0;
  s.n_analog = 8;
  s.analog_per_frame = 10;
  s.n_frames = static_cast<int>(txt.data.rows() / 10);
  ASSERT_EQ(txt.data.rows() % 10, 0);
  s.analog = txt.data;
  s.points.resize(s.n_frames, 0);
  s.groups = {{"POINT", {num("USED", 2, {}, {0}), num("RATE", 4, {}, {s.point_rate_hz})}},
              {"ANALOG",
               {num("USED", 2, {}, {8}), num("RATE", 4, {}, {m.forceplate.sample_rate_hz}),
                num("GEN_SCALE", 4, {}, {1.0}), num("SCALE", 4, {8}, std::vector<double>(8, 1.0)),
                num("OFFSET", 2, {8}, std::vector<double>(8, 0.0))}},
              {"FORCE_PLATFORM",
               {num("USED", 2, {}, {1}), num("TYPE", 2, {1}, {3}),
                num("ORIGIN", 4, {3, 1}, {1e3 * m.forceplate.a_m, 1e3 * m.forceplate.b_m, -1e3 * m.forceplate.az0_m}),
                num("CHANNEL", 2, {8, 1}, {1, 2, 3, 4, 5, 6, 7, 8})}}};
  const fs::path trial_dir = root / m.trials[0].dir;
  fs::remove(trial_dir / "force.txt");
  dir.write((fs::path("session") / m.trials[0].dir / "force.c3d").string(), write_c3d(s));

  const Session read = read_session(root.string());
  const ForceRecord& c3d = read.trials[0].force;
  ASSERT_EQ(c3d.data.rows(), txt.data.rows());
  EXPECT_EQ(c3d.pretrigger_samples, txt.pretrigger_samples);
  EXPECT_LT((c3d.t_s - txt.t_s).cwiseAbs().maxCoeff(), 1e-9);
  // Channels stored as 32-bit floats: 6e-8 relative of at most ~10 kN.
  EXPECT_LT((c3d.data - txt.data).cwiseAbs().maxCoeff(), 1e-3);
  ASSERT_TRUE(c3d.plate_geometry_m.has_value());
  EXPECT_NEAR((*c3d.plate_geometry_m)[2], m.forceplate.az0_m, 1e-7);

  forceplate::ProcessOptions po;
  po.pretrigger_samples = txt.pretrigger_samples;
  po.sample_rate_hz = m.forceplate.sample_rate_hz;
  po.trigger_threshold_n = m.forceplate.trigger_threshold_n;
  const Eigen::Vector3d g = *c3d.plate_geometry_m;
  const auto a = forceplate::process(forceplate::from_eight_channels(c3d.t_s, c3d.data, {g[0], g[1], g[2]}), po);
  const auto b = forceplate::process(
      forceplate::from_eight_channels(txt.t_s, txt.data, {m.forceplate.a_m, m.forceplate.b_m, m.forceplate.az0_m}),
      po);
  EXPECT_NEAR(a.peak_fz_n, b.peak_fz_n, 0.01);
  EXPECT_NEAR(a.contact_time_s, b.contact_time_s, 1e-6);
  EXPECT_NEAR(a.peak_fz_n, syn.truth.trials[0].peak_force_n, 0.05 * syn.truth.trials[0].peak_force_n);

  // Both files: which one is meant is not known.
  dir.write((fs::path("session") / m.trials[0].dir / "force.txt").string(), "x");
  EXPECT_THROW(read_session(root.string()), InputError);
}

// ---------------------------------------------------------------------------
// Real files: shared/real/kistler-bioware-biomdp (skipped when absent)
// ---------------------------------------------------------------------------

fs::path real_dir() {
  return dropfit::testsupport::shared_path("real") / "kistler-bioware-biomdp";
}

double rms(const Eigen::VectorXd& e) { return std::sqrt(e.squaredNorm() / static_cast<double>(e.size())); }

TEST(C3dReal, RawChannelsGiveBioWareFz) {
  DROPFIT_NEED_SHARED(real_dir());
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  struct Case {
    const char* c3d;
    const char* txt;
    int plate;
    double fx_sign;  // BioWare 5.2's CMJ export gives Fx Fy as the reaction (sign flipped), 5.4's as the raw sum
  };
  for (const Case& c : {Case{"kistler_DJ_2plates.C3D", "kistler_DJ_2plates.txt", 1, 1.0},
                        Case{"kistler_DJ_2plates.C3D", "kistler_DJ_2plates.txt", 2, 1.0},
                        Case{"kistler_CMJ_1plate.c3d", "kistler_CMJ_1plate.txt", 1, -1.0}}) {
    SCOPED_TRACE(std::string(c.c3d) + " plate " + std::to_string(c.plate));
    plate.plate = c.plate;
    const ForceRecord r = read_force((real_dir() / c.c3d).string(), plate);
    const BioWareExport bw = read_bioware_export((real_dir() / c.txt).string());
    ASSERT_EQ(r.data.rows(), 8000);
    ASSERT_EQ(bw.plates[c.plate - 1].rows(), 8000);
    ASSERT_TRUE(r.plate_geometry_m.has_value());
    EXPECT_NEAR((*r.plate_geometry_m)[2], -0.058, 1e-9);  // README: az0 = -0.058 m
    const auto res = forceplate::from_eight_channels(
        r.t_s, r.data, {(*r.plate_geometry_m)[0], (*r.plate_geometry_m)[1], (*r.plate_geometry_m)[2]});
    // int16 steps of 0.16 N on each of four Fz channels: 1 N RMS (the
    // issue's bound); measured 0.06-0.26 N.
    EXPECT_LT(rms(res.f_n.col(2) - bw.plates[c.plate - 1].col(2)), 1.0);
    EXPECT_LT(rms(c.fx_sign * res.f_n.col(0) - bw.plates[c.plate - 1].col(0)), 1.0);
    EXPECT_LT(rms(c.fx_sign * res.f_n.col(1) - bw.plates[c.plate - 1].col(1)), 1.0);
  }
  // The drop jump lands on plate 1: peak about 5040 N (README).
  plate.plate = 1;
  const ForceRecord dj = read_force((real_dir() / "kistler_DJ_2plates.C3D").string(), plate);
  EXPECT_NEAR(dj.data.rightCols(4).rowwise().sum().maxCoeff(), 5040.0, 10.0);
}

TEST(C3dReal, CentreOfPressureMatchesBioWare) {
  DROPFIT_NEED_SHARED(real_dir());
  ForcePlateSpec plate;
  plate.sample_rate_hz = 1000.0;
  plate.pretrigger_fraction = 0.1;  // not about the trigger
  const ForceRecord r = read_force((real_dir() / "kistler_COP.c3d").string(), plate);
  const BioWareExport bw = read_bioware_export((real_dir() / "kistler_COP.txt").string());
  ASSERT_EQ(r.data.rows(), 10000);
  ASSERT_EQ(bw.abs_time_s.size(), 500);
  EXPECT_DOUBLE_EQ(bw.sample_rate_hz, 50.0);
  const Eigen::Vector3d g = *r.plate_geometry_m;
  const auto res = forceplate::from_eight_channels(r.t_s, r.data, {g[0], g[1], g[2]});
  // BioWare's 50 Hz export is every 20th sample of the 1000 Hz record.
  const int m = 500;
  Eigen::MatrixXd ours(m, 2);
  for (int i = 0; i < m; ++i) ours.row(i) = res.cop_m.row(20 * i);
  ASSERT_TRUE(ours.allFinite());
  const Eigen::MatrixXd theirs = bw.plates[0].rightCols(2);
  const Eigen::MatrixXd e = (ours.rowwise() - ours.colwise().mean()) - (theirs.rowwise() - theirs.colwise().mean());
  // 0.2 mm (the bound); measured 0.080 / 0.133 mm.
  EXPECT_LT(rms(e.col(0)), 0.2e-3);
  EXPECT_LT(rms(e.col(1)), 0.2e-3);
}

}  // namespace
