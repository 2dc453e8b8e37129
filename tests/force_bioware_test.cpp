// BioWare text exports as they come (docs/formats.md, "Files as
// other tools write them"): the real exports of
// shared/real/kistler-bioware-biomdp (skipped when absent), and small
// exports written here for the variants: header versions, several plates,
// subsets of the columns, units, UTF-16 with either byte order.
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <vector>

#include "capture/force_io.h"
#include "capture/io.h"
#include "core/error.h"
#include "forceplate/forceplate.h"
#include "samples/generator/synth.h"
#include "support/temp_dir.h"
#include "support/shared_data.h"

namespace fs = std::filesystem;
using namespace dropfit;
using namespace dropfit::capture;

namespace {

using dropfit::testsupport::TempDir;

fs::path real(const std::string& name) {
  return dropfit::testsupport::shared_path("real") / "kistler-bioware-biomdp" / name;
}

template <class F>
InputError input_error(F&& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e;
  }
  ADD_FAILURE() << "no InputError";
  return InputError("", 0, 0, "", "");
}

// UTF-8 text (ASCII here, plus one 2-byte and one 3-byte character) as
// UTF-16 with a byte-order mark.
std::string utf16(const std::string& utf8, bool big_endian) {
  std::u16string u;
  for (std::size_t i = 0; i < utf8.size();) {
    const auto c = static_cast<unsigned char>(utf8[i]);
    char32_t cp = c;
    int len = 1;
    if (c >= 0xE0 && i + 2 < utf8.size()) {
      cp = ((c & 0x0F) << 12) | ((utf8[i + 1] & 0x3F) << 6) | (utf8[i + 2] & 0x3F);
      len = 3;
    } else if (c >= 0xC0 && i + 1 < utf8.size()) {
      cp = ((c & 0x1F) << 6) | (utf8[i + 1] & 0x3F);
      len = 2;
    }
    u += static_cast<char16_t>(cp);
    i += len;
  }
  std::string out = big_endian ? std::string("\xFE\xFF") : std::string("\xFF\xFE");
  for (char16_t ch : u) {
    const char hi = static_cast<char>(ch >> 8), lo = static_cast<char>(ch & 0xFF);
    out += big_endian ? hi : lo;
    out += big_endian ? lo : hi;
  }
  return out;
}

// A two-plate export with Fz Mx My Ax Ay per plate (Ax Ay in mm), BioWare
// 5.4 header lines, a units line starting with a tab, CR LF line ends.
std::string two_plate_export() {
  std::string s =
      "BioWare Version 5.4.3.0 Export\r\n"
      "Device:\tKistler Grande1 9287CA\tKistler Grande1 9287CA\r\n"
      "Samples (#):\t5\t5\t5\t5\t5\t5\t5\t5\t5\t5\r\n"
      "Rate (Hz):\t1000.000000\t1000.000000\t1000.000000\t1000.000000\t1000.000000\t1000.000000\t1000.000000\t"
      "1000.000000\t1000.000000\t1000.000000\r\n"
      "Contact period start (sample #):\t0\t0\r\n"
      "Normalized force (N):\t1.000000\t1.000000\r\n"
      "Date\tMay 10, 2023  12:26:05\r\n"
      "Name\tJos\xC3\xA9 \xE2\x82\xAC\r\n"
      "abs time (s)\tFz\tMx\tMy\tAx\tAy\tFz\tMx\tMy\tAx\tAy\r\n"
      "\tN\tN.m\tN.m\tmm\tmm\tN\tN.m\tN.m\tmm\tmm\r\n";
  for (int i = 0; i < 5; ++i) {
    s += std::to_string(1.0 + 0.001 * i).substr(0, 5);
    // Plate 1: Fz 100 + i, Mx 1, My -2, Ax 20 mm, Ay -10 mm; plate 2: Fz 500 + i, Mx 3, My 4, Ax Ay empty at i = 0.
    // Appended piece by piece: GCC 12 reports a false -Wrestrict on "literal" + std::string&&.
    s += '\t';
    s += std::to_string(100 + i);
    s += "\t1\t-2\t20.0\t-10.0\t";
    s += std::to_string(500 + i);
    s += "\t3\t4\t";
    s += i == 0 ? "\t" : "-8\t6";
    s += "\r\n";
  }
  return s;
}

TEST(BioWareExport, TwoPlatesSubsetUnitsAndHeaderVariants) {
  TempDir dir;
  const std::string path = dir.write("force.txt", two_plate_export());
  const BioWareExport ex = read_bioware_export(path);
  EXPECT_EQ(ex.version, "5.4.3.0");
  EXPECT_DOUBLE_EQ(ex.sample_rate_hz, 1000.0);
  ASSERT_EQ(ex.n_plates, 2);
  EXPECT_EQ(ex.present, (std::array<bool, 8>{false, false, true, true, true, false, true, true}));
  ASSERT_EQ(ex.abs_time_s.size(), 5);
  EXPECT_DOUBLE_EQ(ex.abs_time_s[4], 1.004);
  EXPECT_DOUBLE_EQ(ex.plates[0](3, 2), 103.0);
  EXPECT_DOUBLE_EQ(ex.plates[0](0, 6), 0.020);  // mm -> m
  EXPECT_DOUBLE_EQ(ex.plates[0](0, 7), -0.010);
  EXPECT_TRUE(std::isnan(ex.plates[0](0, 0)));  // no Fx in the export
  EXPECT_DOUBLE_EQ(ex.plates[1](2, 2), 502.0);
  EXPECT_DOUBLE_EQ(ex.plates[1](2, 4), 4.0);
  EXPECT_TRUE(std::isnan(ex.plates[1](0, 6)));  // empty Ax: unloaded
  EXPECT_DOUBLE_EQ(ex.plates[1](1, 6), -0.008);

  ForcePlateSpec plate;
  plate.pretrigger_fraction = 0.4;
  plate.plate = 2;
  const ForceRecord r = read_force(path, plate);
  EXPECT_EQ(r.layout, ForceLayout::Resultants);
  EXPECT_EQ(r.pretrigger_samples, 2);
  EXPECT_NEAR(r.t_s[2], 0.0, 1e-12);
  EXPECT_DOUBLE_EQ(r.data(4, 2), 504.0);
  EXPECT_TRUE(std::isnan(r.data(4, 0)));
  EXPECT_FALSE(r.plate_geometry_m.has_value());

  plate.plate = 3;
  const InputError e = input_error([&] { read_force(path, plate); });
  EXPECT_EQ(e.field(), "forceplate.plate");
  EXPECT_EQ(e.line(), 9);  // the column header
  EXPECT_NE(std::string(e.what()).find("2 plates"), std::string::npos) << e.what();
}

TEST(BioWareExport, Utf16EitherByteOrderReadsLikeUtf8) {
  TempDir dir;
  const BioWareExport utf8 = read_bioware_export(dir.write("a.txt", two_plate_export()));
  for (bool be : {false, true}) {
    SCOPED_TRACE(be ? "UTF-16 BE" : "UTF-16 LE");
    const BioWareExport u = read_bioware_export(dir.write(be ? "be.txt" : "le.txt", utf16(two_plate_export(), be)));
    EXPECT_EQ(u.version, utf8.version);
    ASSERT_EQ(u.n_plates, 2);
    EXPECT_TRUE(u.abs_time_s.isApprox(utf8.abs_time_s));
    for (int p = 0; p < 2; ++p)
      EXPECT_TRUE((u.plates[p].array() == utf8.plates[p].array() ||
                   (u.plates[p].array().isNaN() && utf8.plates[p].array().isNaN()))
                      .all());
  }
  // An error in a UTF-16 file names the line as in the text.
  std::string bad = two_plate_export();
  bad.replace(bad.find("\t1\t-2\t20.0"), 3, "\tx\t");
  const InputError e = input_error([&] { read_bioware_export(dir.write("bad.txt", utf16(bad, false))); });
  EXPECT_EQ(e.line(), 11);
  EXPECT_EQ(e.field(), "Mx");
  // UTF-16 without a byte-order mark is refused with the likely reason.
  const std::string no_bom = utf16(two_plate_export(), false).substr(2);
  const InputError e2 = input_error([&] { read_bioware_export(dir.write("nobom.txt", no_bom)); });
  EXPECT_NE(std::string(e2.what()).find("byte-order mark"), std::string::npos) << e2.what();
}

TEST(BioWareExport, RefusedWithTheReason) {
  TempDir dir;
  auto variant = [&](const std::string& from, const std::string& to) {
    std::string s = two_plate_export();
    const std::size_t at = s.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    s.replace(at, from.size(), to);
    return dir.write("v.txt", s);
  };
  ForcePlateSpec plate;
  plate.pretrigger_fraction = 0.1;  // not about the trigger
  // No Fz: no ground reaction force.
  std::string p = variant("abs time (s)\tFz\tMx\tMy\tAx\tAy\tFz", "abs time (s)\tFx\tMx\tMy\tAx\tAy\tFx");
  InputError e = input_error([&] { read_force(p, plate); });
  EXPECT_EQ(e.field(), "Fz");
  EXPECT_NE(std::string(e.what()).find("no Fz"), std::string::npos) << e.what();
  // Plates naming different columns.
  p = variant("Ax\tAy\r\n", "Ax\tMz\r\n");
  e = input_error([&] { read_bioware_export(p); });
  EXPECT_EQ(e.field(), "Mz");
  EXPECT_EQ(e.line(), 9);
  // Rates that disagree between columns.
  p = variant("Rate (Hz):\t1000.000000", "Rate (Hz):\t500.000000");
  e = input_error([&] { read_bioware_export(p); });
  EXPECT_EQ(e.field(), "Rate (Hz)");
  EXPECT_EQ(e.line(), 4);
  // Rate unlike the manifest's.
  plate.sample_rate_hz = 2000.0;
  e = input_error([&] { read_force(dir.write("w.txt", two_plate_export()), plate); });
  EXPECT_EQ(e.field(), "Rate (Hz)");
  plate.sample_rate_hz = 1000.0;
  // Unknown unit.
  p = variant("\tmm\tmm\tN", "\tcm\tmm\tN");
  e = input_error([&] { read_bioware_export(p); });
  EXPECT_EQ(e.field(), "Ax");
  EXPECT_EQ(e.line(), 10);
  // Fewer rows than "Samples (#):" says.
  std::string s = two_plate_export();
  s.erase(s.rfind("1.004"));
  e = input_error([&] { read_bioware_export(dir.write("cut.txt", s)); });
  EXPECT_EQ(e.field(), "Samples");
  EXPECT_NE(std::string(e.what()).find("truncated"), std::string::npos) << e.what();
}

// A record with Fx Fy Fz only: the forces are processed, the centre of
// pressure is NaN throughout and the result says why.
TEST(BioWareExport, WithoutMomentsNoCentreOfPressure) {
  const int n = 1000;
  Eigen::VectorXd t = Eigen::VectorXd::LinSpaced(n, -0.3, -0.3 + (n - 1) * 1e-3);
  Eigen::MatrixXd cols = Eigen::MatrixXd::Constant(n, 8, std::numeric_limits<double>::quiet_NaN());
  for (int i = 0; i < n; ++i) {
    const double tau = t[i] + 0.002;  // contact 2 ms before the trigger
    const double fz = tau > 0 && tau < 0.1 ? 3000.0 * std::pow(std::sin(3.14159265358979 * tau / 0.1), 2) : 0.0;
    cols(i, 0) = 0.01 * fz + 0.2 * std::sin(0.37 * i);
    cols(i, 1) = -0.02 * fz + 0.2 * std::cos(0.51 * i);
    cols(i, 2) = fz + 0.5 * std::sin(1.3 * i) + 3.0;  // small noise and an offset
  }
  const forceplate::Resultants raw = forceplate::from_resultant_columns(t, cols, 50.0, -0.04);
  EXPECT_EQ(raw.absent, (std::vector<std::string>{"Mx", "My", "Mz"}));
  EXPECT_FALSE(raw.cop_unavailable.empty());
  forceplate::ProcessOptions o;
  o.pretrigger_samples = 300;
  const forceplate::ForceTrial ft = forceplate::process(raw, o);
  // Peak 3000 N: the sin^2 pulse sampled at 1 ms with 0.5 N noise -> 2 N.
  EXPECT_NEAR(ft.peak_fz_n, 3000.0, 2.0);
  EXPECT_NEAR(ft.offset[2], 3.0, 0.2);
  EXPECT_TRUE(std::isnan(ft.offset[3]));
  EXPECT_TRUE(ft.plate.cop_m.array().isNaN().all());
  EXPECT_TRUE(ft.plate.m_n_m.array().isNaN().all());
  EXPECT_NE(ft.report().find("no centre of pressure"), std::string::npos) << ft.report();
  EXPECT_NE(ft.report().find("Mx My Mz"), std::string::npos) << ft.report();
  // Fz absent: refused.
  Eigen::MatrixXd no_fz = cols;
  no_fz.col(2).setConstant(std::numeric_limits<double>::quiet_NaN());
  EXPECT_THROW(forceplate::from_resultant_columns(t, no_fz, 50.0, -0.04), Error);
}

// Mutated exports (bytes replaced, deleted, tabs and line ends inserted, in
// UTF-8 and UTF-16): read or refused with an InputError, never anything else.
TEST(BioWareExport, MutatedExportsReadOrRefused) {
  TempDir dir;
  std::mt19937 rng(5);
  const std::string base = two_plate_export();
  const char alphabet[] = "\t\r\n0123456789.-eNmxF \xFF\xFE";
  int refused = 0, read = 0;
  for (int trial = 0; trial < 400; ++trial) {
    std::string s = base;
    for (int k = 0; k < 1 + trial % 3; ++k) {
      const std::size_t at = rng() % s.size();
      const char c = alphabet[rng() % (sizeof(alphabet) - 1)];
      switch (rng() % 3) {
        case 0: s[at] = c; break;
        case 1: s.erase(at, 1 + rng() % 4); break;
        default: s.insert(at, 1, c);
      }
    }
    if (trial % 5 == 0) s = utf16(s, trial % 10 == 0);
    const std::string path = dir.write("m.txt", s);
    try {
      const BioWareExport ex = read_bioware_export(path);
      ASSERT_GE(ex.n_plates, 1);
      ASSERT_EQ(ex.plates[0].rows(), ex.abs_time_s.size());
      ++read;
    } catch (const InputError& e) {
      EXPECT_EQ(e.file(), path);
      ++refused;
    }
  }
  // Both outcomes occur (a digit changed in a value still reads).
  EXPECT_GT(refused, 50);
  EXPECT_GT(read, 50);
}

// [forceplate] plate: written when not 1, read back, checked.
TEST(BioWareManifest, PlateKey) {
  synth::SynthOptions o;
  o.impact_velocities_m_s = {5.0};
  Manifest m = synth::make_session(o).session.manifest;
  TempDir dir;
  const std::string path = dir.write("session.toml", "");
  EXPECT_EQ(m.forceplate.plate, 1);
  m.forceplate.plate = 2;
  write_manifest(path, m);
  EXPECT_EQ(read_manifest(path).forceplate.plate, 2);
  std::ifstream in(path);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  text.replace(text.find("plate = 2"), 9, "plate = 0");
  const std::string bad = dir.write("bad.toml", text);
  const InputError e = input_error([&] { read_manifest(bad); });
  EXPECT_EQ(e.field(), "forceplate.plate");
}

// ---------------------------------------------------------------------------
// Real exports
// ---------------------------------------------------------------------------

TEST(BioWareReal, DropJumpTwoPlates) {
  DROPFIT_NEED_SHARED(real("kistler_DJ_2plates.txt"));
  const BioWareExport ex = read_bioware_export(real("kistler_DJ_2plates.txt").string());
  EXPECT_EQ(ex.version, "5.4.3.0");
  ASSERT_EQ(ex.n_plates, 2);
  EXPECT_EQ(ex.present, (std::array<bool, 8>{true, true, true, false, false, false, false, false}));
  ASSERT_EQ(ex.abs_time_s.size(), 8000);
  EXPECT_DOUBLE_EQ(ex.plates[0](0, 2), 7.819648);  // first row, as printed
  EXPECT_DOUBLE_EQ(ex.plates[1](0, 2), 706.158540);
  EXPECT_NEAR(ex.plates[0].col(2).maxCoeff(), 5040.0, 5.0);  // README: peak about 5040 N

  // Through read_force and the force plate: plate 1, the landing at sample
  // 2933 (first Fz above 25 N) as the trigger sample.
  ForcePlateSpec plate;
  plate.pretrigger_fraction = 2933.0 / 8000.0;
  const ForceRecord r = read_force(real("kistler_DJ_2plates.txt").string(), plate);
  const forceplate::Resultants raw = forceplate::from_resultant_columns(r.t_s, r.data, 50.0, plate.az0_m);
  forceplate::ProcessOptions o;
  o.pretrigger_fraction = *plate.pretrigger_fraction;
  o.sample_rate_hz = 1000.0;
  const forceplate::ForceTrial ft = forceplate::process(raw, o);
  EXPECT_NEAR(ft.peak_fz_n, 5040.0, 15.0);
  EXPECT_TRUE(ft.plate.cop_m.array().isNaN().all());
  EXPECT_FALSE(ft.cop_unavailable.empty());
}

TEST(BioWareReal, CounterMovementJumpFxFyFzOnly) {
  DROPFIT_NEED_SHARED(real("kistler_CMJ_1plate.txt"));
  const BioWareExport ex = read_bioware_export(real("kistler_CMJ_1plate.txt").string());
  EXPECT_EQ(ex.version, "5.2.1.3");
  ASSERT_EQ(ex.n_plates, 1);
  ASSERT_EQ(ex.abs_time_s.size(), 8000);
  EXPECT_DOUBLE_EQ(ex.plates[0](0, 2), 670.500366);
  EXPECT_DOUBLE_EQ(ex.plates[0](2, 1), -0.169880);
  const ForceRecord r = read_force(real("kistler_CMJ_1plate.txt").string(), ForcePlateSpec{});
  EXPECT_EQ(r.data.rows(), 8000);
  EXPECT_TRUE(r.data.col(3).array().isNaN().all());
}

TEST(BioWareReal, CentreOfPressureExportInMetres) {
  DROPFIT_NEED_SHARED(real("kistler_COP.txt"));
  const BioWareExport ex = read_bioware_export(real("kistler_COP.txt").string());
  EXPECT_EQ(ex.version, "5.1.1.0");
  EXPECT_DOUBLE_EQ(ex.sample_rate_hz, 50.0);
  ASSERT_EQ(ex.abs_time_s.size(), 500);
  EXPECT_EQ(ex.present, (std::array<bool, 8>{false, false, false, false, false, false, true, true}));
  EXPECT_DOUBLE_EQ(ex.plates[0](0, 6), 0.013748);  // metres as printed
  EXPECT_DOUBLE_EQ(ex.plates[0](0, 7), 0.010516);
  // As a trial's force record: refused, there is no Fz.
  ForcePlateSpec plate;
  plate.sample_rate_hz = 50.0;
  const InputError e = input_error([&] { read_force(real("kistler_COP.txt").string(), plate); });
  EXPECT_EQ(e.field(), "Fz");
  EXPECT_EQ(e.line(), 18);
}

}  // namespace
