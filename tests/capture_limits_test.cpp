// Bounded readers: no regular expression on unbounded
// input, limits on names, point and camera counts and file sizes, UTF-8
// checked before the TOML parser, symbolic-link loops named as such; every
// error names its file. Each case was a crash, a hang, gigabytes of memory
// or a misleading message before.
#include <fmt/format.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>

#include "capture/io.h"
#include "core/error.h"
#include "support/temp_dir.h"

namespace dropfit::capture {
namespace {

namespace fs = std::filesystem;

// A fresh folder per test (removed at the end) and text helpers.
using testsupport::line_of;
using testsupport::read_text;
using testsupport::TempDir;
using testsupport::write_text;

// `fn` must throw InputError naming `file`, `line` and `column` (when >= 0)
// and `field`, with `reason_part` in its reason; the message names the file.
void expect_input_error(const std::function<void()>& fn, const std::string& file, int line, int column,
                        const std::string& field, const std::string& reason_part) {
  try {
    fn();
    ADD_FAILURE() << "no InputError thrown (expected " << file << ")";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), file) << e.what();
    EXPECT_EQ(e.line(), line) << e.what();
    if (column >= 0) {
      EXPECT_EQ(e.column(), column) << e.what();
    }
    EXPECT_EQ(e.field(), field) << e.what();
    EXPECT_NE(std::string(e.what()).find(file), std::string::npos) << e.what();
    EXPECT_NE(e.reason().find(reason_part), std::string::npos) << e.what();
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected InputError, got: " << e.what();
  }
}

Manifest manifest() {
  Manifest m;
  m.impactor.base_markers = {"a"};
  m.mat.surface_markers = {"b"};
  m.mat.layers = {{"foam", 0.1, 1.0}};
  m.video.cameras = {"cam1", "cam2"};
  m.video.points = {"a", "b"};
  m.trials = {{"t1", "trials/t1"}};
  return m;
}

// The manifest text with the line starting `key =` replaced by `replacement`.
std::string with_line(const std::string& text, const std::string& key, const std::string& replacement) {
  const std::size_t at = text.find("\n" + key + " =");
  EXPECT_NE(at, std::string::npos) << key;
  const std::size_t end = text.find('\n', at + 1);
  return text.substr(0, at + 1) + replacement + text.substr(end);
}

TEST(CaptureLimits, LongHeaderFieldWithoutCommaIsAnErrorNotACrash) {
  // Was: SIGSEGV in the Argus-layout regular expression (stack overflow).
  TempDir dir;
  VideoSpec v = manifest().video;
  const std::string path = dir.file("xypts.csv");
  write_text(path, std::string(30000, 'x') + "\n1\n");
  expect_input_error([&] { read_xypts(path, v); }, path, 1, 1, std::string(60, 'x') + "... (30000 characters)",
                     "more than any point name allows");
  // Long but shaped like a column: the same, before any pattern is tried.
  write_text(path, std::string(30000, 'p') + "_cam_1_x\n1\n");
  expect_input_error([&] { read_xypts(path, v); }, path, 1, 1, std::string(60, 'p') + "... (30008 characters)",
                     "30008 characters");
  // Just short enough to be a name: an ordinary "not in the manifest".
  const std::string name = std::string(250, 'q');
  write_text(path, name + "_cam_1_x," + name + "_cam_1_y\n1,2\n");
  expect_input_error([&] { read_xypts(path, v); }, path, 1, 1, name + "_cam_1_x", "is not in the manifest");
}

TEST(CaptureLimits, MillionsOfSeparatorsCostNoMoreThanTheHeader) {
  TempDir dir;
  VideoSpec v = manifest().video;
  const std::string path = dir.file("xypts.csv");
  // A data row of 4 million commas: refused by its field count (was: a
  // vector of 4 million fields first).
  write_text(path, "pt1_cam1_X,pt1_cam1_Y\n1,2\n" + std::string(4000000, ',') + "\n");
  expect_input_error([&] { read_xypts(path, v); }, path, 3, 3, "", "fields, the column header (line 1) has 2");
  // A header of 4 million commas: more columns than 2 points x 2 cameras x 2.
  write_text(path, std::string(4000000, ',') + "\n");
  expect_input_error([&] { read_xypts(path, v); }, path, 1, 9, "", "more than 8 columns");
}

TEST(CaptureLimits, PointAndCameraCountsAndNameLengthsAreBounded) {
  // Was: 20,000 points took 3.3 GB, 100,000 took 16 GB and hung.
  TempDir dir;
  const std::string path = dir.file("session.toml");
  write_manifest(path, manifest());
  const std::string base = read_text(path);
  std::string points = "points = [";
  for (int i = 0; i < 20000; ++i) points += fmt::format("{}\"p{}\"", i ? ", " : "", i);
  points += "]";
  std::string text = with_line(base, "points", points);
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "points ="), 10, "video.points",
                     "20000 names, more than the 1000");
  // 1000 points are accepted (the limit itself).
  points = "points = [\"a\", \"b\"";
  for (int i = 2; i < 1000; ++i) points += fmt::format(", \"p{}\"", i);
  write_text(path, with_line(base, "points", points + "]"));
  EXPECT_EQ(read_manifest(path).video.points.size(), 1000u);
  // 17 cameras.
  std::string cameras = "cameras = [";
  for (int i = 0; i < 17; ++i) cameras += fmt::format("{}\"cam{}\"", i ? ", " : "", i + 1);
  text = with_line(base, "cameras", cameras + "]");
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "cameras ="), 11, "video.cameras",
                     "17 names, more than the 16");
  // A name of 300 characters.
  text = with_line(base, "points", "points = [\"a\", \"b\", \"" + std::string(300, 'n') + "\"]");
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "points ="), 21, "video.points[2]",
                     "a name of 300 bytes");
}

TEST(CaptureLimits, FilesOverTwoGibibytesAreRefusedUnread) {
  TempDir dir;
  const std::string path = dir.file("xypts.csv");
  write_text(path, "pt1_cam1_X,pt1_cam1_Y\n");
  std::error_code ec;
  fs::resize_file(path, (2ull << 30) + 1, ec);  // sparse: no disk used
  if (ec) GTEST_SKIP() << "cannot make a sparse file here: " << ec.message();
  expect_input_error([&] { read_xypts(path, manifest().video); }, path, 0, 0, "",
                     "2147483649 bytes, more than the 2147483648");
  fs::remove(path);
  // The manifest's own cap is 4 MiB.
  const std::string toml = dir.file("session.toml");
  write_manifest(toml, manifest());
  write_text(toml, read_text(toml) + "# " + std::string(5 << 20, 'c') + "\n");
  expect_input_error([&] { read_manifest(toml); }, toml, 0, 0, "", "more than the 4194304 bytes");
}

TEST(CaptureLimits, ManifestMustBeUtf8BeforeTheTomlParserSeesIt) {
  TempDir dir;
  const std::string path = dir.file("session.toml");
  write_manifest(path, manifest());
  const std::string base = read_text(path);
  // A Latin-1 byte in a string: not UTF-8, located by line and column.
  std::string text = with_line(base, "name", "name = \"M\xFCller\"");
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "name ="), 10, "", "not UTF-8");
  // An overlong encoding of '/' (0xC0 0xAF): invalid too.
  text = with_line(base, "name", "name = \"a\xC0\xAF\"");
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "name ="), 10, "", "not UTF-8");
  // A no-break space (U+00A0) where TOML allows whitespace: refused here,
  // before toml++ (whose handling of it is undefined behaviour).
  text = with_line(base, "name", "name\xC2\xA0= \"x\"");
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "name"), 5, "", "non-ASCII character");
  // Non-ASCII inside strings and comments is valid TOML and accepted.
  text = with_line(base, "name", "name = \"M\xC3\xBCller \xE2\x80\x94 mat\"  # \xC2\xA0" "comment \xF0\x9F\x98\x80");
  write_text(path, text);
  EXPECT_EQ(read_manifest(path).name, "M\xC3\xBCller \xE2\x80\x94 mat");
  // A multi-line string with an escaped line end does not lose the line count.
  text = with_line(base, "name", "name = \"\"\"a \\\nb\"\"\"\nmodelx = \xC2\xA0");
  write_text(path, text);
  expect_input_error([&] { read_manifest(path); }, path, line_of(text, "modelx"), 10, "", "non-ASCII character");
}

TEST(CaptureLimits, SymlinkLoopIsNamedAsSuch) {
  TempDir dir;
  const std::string a = dir.file("a.csv");
  const std::string b = dir.file("b.csv");
  fs::create_symlink(b, a);
  fs::create_symlink(a, b);
  expect_input_error([&] { read_xypts(a, manifest().video); }, a, 0, 0, "", "symbolic link loop");
  expect_input_error([&] { read_frame_csv(a); }, a, 0, 0, "", "symbolic link loop");
  // The manifest too.
  fs::create_directories(dir.path() / "s");
  fs::create_symlink(dir.file("s/session.toml"), dir.file("s/session.toml"));
  expect_input_error([&] { read_session(dir.file("s")); }, dir.file("s/session.toml"), 0, 0, "",
                     "symbolic link loop");
  // A dangling link is not "not found" either.
  fs::create_symlink(dir.file("nowhere.csv"), dir.file("dangling.csv"));
  expect_input_error([&] { read_frame_csv(dir.file("dangling.csv")); }, dir.file("dangling.csv"), 0, 0, "",
                     "broken symbolic link");
}

}  // namespace
}  // namespace dropfit::capture
