// End-to-end tests of the dropfit binary on bad input. Each test writes a
// short synthetic session (samples/generator) into its own fresh folder,
// spoils one thing the way a lab could, runs the commands that read it and
// checks the contract: a non-zero exit, exactly one line on stderr starting
// "dropfit: error:" that names what is wrong (file, line and column where
// there is one), no output folder or file written, and the session folder
// unchanged (every entry's size and modification time).
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "capture/io.h"
#include "samples/generator/synth.h"
#include "support/cli_harness.h"

namespace dropfit::clitest {
namespace {

class CliErrors : public ::testing::Test {
 protected:
  void SetUp() override { synthetic_ = write_synthetic_session(session()); }

  fs::path session() const { return dir_ / "session"; }
  fs::path out() const { return dir_ / "out"; }
  const synth::SyntheticSession& synthetic() const { return synthetic_; }

  // Runs `dropfit COMMAND SESSION --out OUT` for each command and checks the
  // contract; returns the error line of each run.
  std::vector<std::string> expect_refused(const std::vector<std::string>& commands) {
    return expect_refused_to(commands, out());
  }
  std::vector<std::string> expect_refused_to(const std::vector<std::string>& commands, const fs::path& out_dir) {
    std::vector<std::string> lines;
    for (const auto& command : commands) {
      const auto before = listing(session());
      const CliRun run = run_dropfit({command, session().string(), "--out", out_dir.string()}, dir_.path());
      expect_one_line_error(run);
      EXPECT_EQ(listing(session()), before) << "the session folder changed\n" << run.describe();
      EXPECT_FALSE(fs::exists(out())) << "an output folder was written\n" << run.describe();
      // Nothing beside the session and the runs' captured output.
      for (const auto& entry : fs::directory_iterator(dir_.path())) {
        const std::string name = entry.path().filename().string();
        EXPECT_TRUE(name == "session" || name == "link" || name.rfind("run", 0) == 0)
            << "unexpected " << name << "\n" << run.describe();
      }
      lines.push_back(run.err);
    }
    return lines;
  }

  TempDir dir_;

 private:
  synth::SyntheticSession synthetic_;
};

// Each run costs a process start (a few tenths of a second), so each bad
// input is run through the commands whose code paths differ for it:
// calibrate reads the manifest and calibration files itself; reconstruct
// and process read the whole session (capture::read_session), and process
// has the most outputs to hold back.

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

// 1-based line number of the last line of a text file.
int line_count(const std::string& text) {
  return static_cast<int>(std::count(text.begin(), text.end(), '\n')) + (text.empty() || text.back() == '\n' ? 0 : 1);
}

// The text with field `field` (0-based) of line `line` (1-based) of a
// comma-separated file replaced; `column` gets the 1-based character
// position where that field starts.
std::string replace_csv_field(const std::string& text, int line, int field, const std::string& value, int& column) {
  std::istringstream in(text);
  std::string out, row;
  for (int n = 1; std::getline(in, row); ++n) {
    if (n == line) {
      std::size_t start = 0;
      for (int f = 0; f < field; ++f) start = row.find(',', start) + 1;
      const std::size_t end = std::min(row.find(',', start), row.size());
      row.replace(start, end - start, value);
      column = static_cast<int>(start) + 1;
    }
    out += row + "\n";
  }
  return out;
}

// ---------------------------------------------------------------------------

// A flat calibration board: every marker at one height. An 11-parameter DLT
// is singular on coplanar points (spec: calibration/frame.csv).
TEST_F(CliErrors, CoplanarCalibrationMarkers) {
  std::vector<CalibrationMarker> frame = synthetic().session.frame;
  std::vector<CalibrationImage> images;
  for (const auto& camera : synthetic().truth.cameras) {
    CalibrationImage image;
    image.camera = camera.camera.name;
    for (auto& marker : frame) {
      marker.lab_m.z() = 0.1;
      image.observations.push_back({marker.id, synth::project_px(camera, marker.lab_m)});
    }
    images.push_back(image);
  }
  ASSERT_EQ(images.size(), 2u);
  capture::write_frame_csv((session() / "calibration" / "frame.csv").string(), frame);
  for (const auto& image : images)
    capture::write_camera_csv((session() / "calibration" / (image.camera + ".csv")).string(), image);

  for (const auto& line : expect_refused({"calibrate", "process"})) {
    EXPECT_TRUE(contains(line, "coplanar")) << line;
    EXPECT_TRUE(contains(line, "cam1")) << line;
  }
}

TEST_F(CliErrors, FewerThanSixFitMarkers) {
  std::vector<CalibrationMarker> frame = synthetic().session.frame;
  int n_fit = 0;
  for (auto& marker : frame) marker.role = n_fit++ < 5 ? MarkerRole::Fit : MarkerRole::Check;
  capture::write_frame_csv((session() / "calibration" / "frame.csv").string(), frame);

  for (const auto& line : expect_refused({"calibrate"})) {
    EXPECT_TRUE(contains(line, "cam1")) << line;
    EXPECT_TRUE(contains(line, "5 calibration points given")) << line;
    EXPECT_TRUE(contains(line, "needs at least 6")) << line;
  }
}

TEST_F(CliErrors, CameraMarkerNotInFrame) {
  const fs::path cam2 = session() / "calibration" / "cam2.csv";
  const std::string text = read_text(cam2) + "c99,512.25,400.5\n";
  write_text(cam2, text);
  const std::string where = fmt::format("{}:{}:1 [id]", cam2.string(), line_count(text));
  for (const auto& line : expect_refused({"calibrate", "reconstruct"})) {
    EXPECT_TRUE(contains(line, where)) << line << "expected " << where;
    EXPECT_TRUE(contains(line, "c99")) << line;
  }
}

TEST_F(CliErrors, MalformedNumberInFrameNamesFileLineAndColumn) {
  const fs::path frame = session() / "calibration" / "frame.csv";
  int column = 0;
  write_text(frame, replace_csv_field(read_text(frame), 4, 2, "0.1x", column));
  ASSERT_GT(column, 1);
  const std::string where = fmt::format("{}:4:{} [y_m]", frame.string(), column);
  for (const auto& line : expect_refused({"calibrate"})) {
    EXPECT_TRUE(contains(line, where)) << line << "expected " << where;
    EXPECT_TRUE(contains(line, "'0.1x'")) << line;
  }
}

TEST_F(CliErrors, MalformedNumberInTracksNamesFileLineAndColumn) {
  const fs::path xypts = session() / "trials" / "trial2" / "xypts.csv";
  const std::string text = read_text(xypts);
  std::istringstream header(text.substr(0, text.find('\n')));
  std::string name;
  for (int f = 0; f <= 5; ++f) std::getline(header, name, ',');
  int column = 0;
  write_text(xypts, replace_csv_field(text, 51, 5, "12.5.3", column));
  ASSERT_GT(column, 1);
  const std::string where = fmt::format("{}:51:{} [{}]", xypts.string(), column, name);
  for (const auto& line : expect_refused({"process"})) {
    EXPECT_TRUE(contains(line, where)) << line << "expected " << where;
    EXPECT_TRUE(contains(line, "'12.5.3'")) << line;
  }
}

TEST_F(CliErrors, UnknownManifestKey) {
  const fs::path manifest = session() / "session.toml";
  const std::string text = read_text(manifest);
  const std::size_t width = text.find("\nwidth_m = ");
  ASSERT_NE(width, std::string::npos);
  const std::size_t insert_at = text.find('\n', width + 1) + 1;
  write_text(manifest, text.substr(0, insert_at) + "colour = \"blue\"\n" + text.substr(insert_at));
  const int line = static_cast<int>(std::count(text.begin(), text.begin() + insert_at, '\n')) + 1;
  const std::string where = fmt::format("{}:{}:1 [mat.colour]", manifest.string(), line);
  for (const auto& err : expect_refused({"calibrate", "reconstruct"})) {
    EXPECT_TRUE(contains(err, where)) << err << "expected " << where;
    EXPECT_TRUE(contains(err, "unknown key")) << err;
  }
}

TEST_F(CliErrors, MissingForceFile) {
  const fs::path force = session() / "trials" / "trial2" / "force.txt";
  fs::remove(force);
  for (const auto& line : expect_refused({"process"})) {
    EXPECT_TRUE(contains(line, force.string() + ": file not found")) << line;
  }
}

TEST_F(CliErrors, MissingCameraFile) {
  const fs::path cam2 = session() / "calibration" / "cam2.csv";
  fs::remove(cam2);
  for (const auto& line : expect_refused({"calibrate"})) {
    EXPECT_TRUE(contains(line, cam2.string() + ": file not found")) << line;
  }
}

TEST_F(CliErrors, MissingSessionFolder) {
  const fs::path missing = dir_ / "no-such-session";
  const CliRun run = run_dropfit({"process", missing.string(), "--out", out().string()}, dir_.path());
  expect_one_line_error(run);
  EXPECT_TRUE(contains(run.err, missing.string())) << run.describe();
  EXPECT_FALSE(fs::exists(out())) << run.describe();
  EXPECT_FALSE(fs::exists(missing)) << run.describe();
}

TEST_F(CliErrors, UsageErrorIsOneLineToo) {
  const auto before = listing(session());
  const CliRun run = run_dropfit({"calibrate", session().string()}, dir_.path());  // no --out
  expect_one_line_error(run);
  EXPECT_TRUE(contains(run.err, "--out")) << run.describe();
  EXPECT_EQ(listing(session()), before);
}

TEST_F(CliErrors, OutputInsideTheSessionIsRefused) {
  fs::create_directory_symlink(session(), dir_ / "link");
  for (const fs::path& inside :
       {session() / "results", session(), session() / ".." / "session" / "out", dir_ / "link" / "results"}) {
    for (const auto& line : expect_refused_to({"calibrate"}, inside)) {
      EXPECT_TRUE(contains(line, "inside the session folder")) << line;
    }
    EXPECT_FALSE(fs::exists(session() / "results"));
    EXPECT_FALSE(fs::exists(session() / "out"));
  }
  // process, with the most to write, holds everything back too.
  for (const auto& line : expect_refused_to({"process"}, session() / "results")) {
    EXPECT_TRUE(contains(line, "inside the session folder")) << line;
  }
  EXPECT_FALSE(fs::exists(session() / "results"));
}

// An option out of range names the option and the value, in a few words
// (not CLI11's 309-digit upper bound).
TEST_F(CliErrors, OptionOutOfRangeNamesOptionAndValue) {
  for (const std::string value : {"-1", "abc"}) {
    const CliRun run = run_dropfit({"run", session().string(), "--out", out().string(), "--jobs", value}, dir_.path());
    expect_one_line_error(run);
    EXPECT_TRUE(contains(run.err, "--jobs")) << run.describe();
    EXPECT_TRUE(contains(run.err, "'" + value + "' is not a number >= 0")) << run.describe();
    EXPECT_LT(run.err.size(), 200u) << run.describe();
    EXPECT_FALSE(fs::exists(out()));
  }
}

}  // namespace
}  // namespace dropfit::clitest
