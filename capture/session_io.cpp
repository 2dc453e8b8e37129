// The whole session folder; see capture/io.h.
#include "capture/io.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <string_view>

#include "capture/force_io.h"
#include "capture/text_io.h"
#include "core/error.h"

namespace dropfit::capture {

using namespace detail;
namespace fs = std::filesystem;

namespace {
bool exists_entry(const fs::path& p) {
  std::error_code ec;
  return fs::exists(fs::symlink_status(p, ec));
}
}  // namespace

namespace {
// A printable form of a name for a message: control characters as \xNN,
// at most 60 characters shown.
std::string printable(std::string_view s) {
  std::string out;
  for (std::size_t i = 0; i < s.size() && i < 60; ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    out += c < 0x20 || c == 0x7F ? fmt::format("\\x{:02X}", c) : std::string(1, static_cast<char>(c));
  }
  if (s.size() > 60) out += fmt::format("... ({} characters)", s.size());
  return out;
}

std::string control_character(std::string_view s) {
  for (std::size_t i = 0; i < s.size(); ++i) {
    const auto c = static_cast<unsigned char>(s[i]);
    if (c < 0x20 || c == 0x7F) return fmt::format("control character \\x{:02X} at character {}", c, i + 1);
  }
  return {};
}
}  // namespace

std::string trial_id_problem(std::string_view id) {
  constexpr std::size_t kMaxIdChars = 128;
  if (id.empty()) return "empty trial id";
  if (id.size() > kMaxIdChars)
    return fmt::format("trial id \"{}\" has {} characters, more than {} (it names the trial's output folder)",
                       printable(id), id.size(), kMaxIdChars);
  if (const std::string c = control_character(id); !c.empty())
    return fmt::format("trial id \"{}\" holds a {} (it names the trial's output folder)", printable(id), c);
  if (id.find_first_of("/\\") != std::string_view::npos || id == "." || id == "..")
    return fmt::format("trial id \"{}\" is not a plain file name (no '/', '\\', '.' or '..': it names the trial's "
                       "output folder)",
                       printable(id));
  return {};
}

std::string trial_dir_problem(std::string_view dir) {
  if (dir.empty()) return "empty trial dir";
  if (dir.size() > 1024) return fmt::format("trial dir of {} characters, more than 1024", dir.size());
  if (const std::string c = control_character(dir); !c.empty())
    return fmt::format("trial dir \"{}\" holds a {}", printable(dir), c);
  const fs::path p{std::string(dir)};
  if (p.is_absolute() || p.has_root_name() || p.has_root_directory())
    return fmt::format("\"{}\" is absolute; trial dirs are relative to the session folder", printable(dir));
  int depth = 0;
  for (const fs::path& part : p) {
    if (part == "..") --depth;
    else if (!part.empty() && part != ".") ++depth;
    if (depth < 0)
      return fmt::format("\"{}\" leaves the session folder; trial dirs lie inside it", printable(dir));
  }
  if (depth == 0) return fmt::format("\"{}\" is the session folder itself, not a trial folder in it", printable(dir));
  return {};
}

void read_session_calibration(const std::string& root, Session& s) {
  const fs::path dir(root);
  const Manifest& m = s.manifest;
  s.frame.clear();
  s.images.clear();
  s.dlt_coefficients.clear();
  const bool given = !m.calibration.dlt_coefficients.empty();
  if (given) s.dlt_coefficients = read_dlt_coefficients((dir / m.calibration.dlt_coefficients).string(), m.video);
  // With given coefficients the frame only checks them: optional, and a
  // camera without its file saw none of its markers.
  const fs::path frame = dir / "calibration" / "frame.csv";
  if (!given || exists_entry(frame)) {
    s.frame = read_frame_csv(frame.string());
    for (const std::string& camera : m.video.cameras) {
      const fs::path file = dir / "calibration" / (camera + ".csv");
      if (given && !exists_entry(file))
        s.images.push_back(CalibrationImage{camera, {}});
      else
        s.images.push_back(read_camera_csv(file.string(), camera, s.frame));
    }
  }
}

namespace {
// A trial folder that resolves (through symbolic links) outside the session
// folder is refused: the session is what was recorded, and only it is read.
void check_inside(const std::string& root, const TrialSpec& spec, const fs::path& trial_dir) {
  std::error_code ec;
  const fs::path base = fs::weakly_canonical(fs::path(root), ec);
  if (ec) return;
  const fs::path real = fs::weakly_canonical(trial_dir, ec);
  if (ec) return;
  const fs::path rel = real.lexically_relative(base);
  if (rel.empty() || *rel.begin() == "..")
    throw InputError((fs::path(root) / "session.toml").string(), 0, 0, "trial.dir",
                     fmt::format("trial '{}': folder \"{}\" resolves to {}, outside the session folder {}", spec.id,
                                 spec.dir, real.string(), base.string()));
}
}  // namespace

namespace {
// markers.c3d (any case of the extension) in a trial folder, "" when none.
std::string find_markers_c3d(const fs::path& trial_dir) {
  std::error_code ec;
  for (fs::directory_iterator it(trial_dir, ec), end; !ec && it != end; it.increment(ec))
    if (iequals(it->path().filename().string(), "markers.c3d")) return it->path().string();
  return {};
}

// A trial's 3-D markers from markers.c3d: the manifest's points by label, at
// the manifest's frame rate, with its trigger frame inside the record.
void read_trial_markers(const Manifest& m, TrialRecording& trial) {
  const MarkerTrajectories t = read_markers_c3d(trial.markers_path, m.video.points);
  if (std::abs(t.frame_rate_hz - m.video.frame_rate_hz) > 1e-6 * m.video.frame_rate_hz)
    throw InputError(trial.markers_path, 0, 0, "POINT:RATE",
                     fmt::format("frame rate {} Hz disagrees with the manifest's video.frame_rate_hz = {} Hz",
                                 t.frame_rate_hz, m.video.frame_rate_hz));
  if (m.video.trigger_frame >= t.xyz_m.rows())
    throw InputError(trial.markers_path, 0, 0, "video.trigger_frame",
                     fmt::format("trigger_frame {} is beyond the file's {} frames", m.video.trigger_frame,
                                 t.xyz_m.rows()));
  trial.markers_xyz_m = t.xyz_m;
  trial.tracks.points = m.video.points;
  trial.tracks.cameras = m.video.cameras;
  trial.tracks.uv_px.resize(0, 2 * static_cast<Eigen::Index>(m.video.points.size() * m.video.cameras.size()));
}
}  // namespace

Session read_session(const std::string& root) {
  const fs::path dir(root);
  Session s;
  s.root = root;
  s.manifest = read_manifest((dir / "session.toml").string());
  const Manifest& m = s.manifest;
  for (const TrialSpec& spec : m.trials) check_inside(root, spec, dir / spec.dir);
  // Every trial with its own 3-D markers and no calibration in the folder:
  // there is nothing to calibrate.
  const bool all_3d = std::all_of(m.trials.begin(), m.trials.end(), [&](const TrialSpec& t) {
    return !find_markers_c3d(dir / t.dir).empty();
  });
  if (!all_3d || !m.calibration.dlt_coefficients.empty() || exists_entry(dir / "calibration" / "frame.csv"))
    read_session_calibration(root, s);
  for (const TrialSpec& spec : m.trials) {
    TrialRecording trial;
    trial.spec = spec;
    const fs::path trial_dir = dir / spec.dir;
    trial.xypts_path = find_xypts(trial_dir.string());
    trial.markers_path = find_markers_c3d(trial_dir);
    if (trial.has_3d_markers()) {
      if (exists_entry(trial.xypts_path))
        throw InputError(trial_dir.string(), 0, 0, "markers.c3d",
                         fmt::format("the trial folder holds both {} and {}: 3-D markers replace the marker table, "
                                     "so keep the one meant",
                                     fs::path(trial.markers_path).filename().string(),
                                     fs::path(trial.xypts_path).filename().string()));
      trial.xypts_path.clear();
      read_trial_markers(m, trial);
    } else {
      trial.tracks = read_xypts(trial.xypts_path, m.video);
      const std::string offsets = offsets_path(trial.xypts_path);
      if (exists_entry(offsets)) {
        trial.frame_offsets = read_offsets(offsets, static_cast<int>(m.video.cameras.size()));
        if (trial.frame_offsets.per_frame && trial.frame_offsets.frames.rows() != trial.tracks.n_frames())
          throw InputError(offsets, 0, 0, "",
                           fmt::format("{} rows of offsets, but the marker table {} has {} frames (DLTdv writes one "
                                       "row per frame)",
                                       trial.frame_offsets.frames.rows(), trial.xypts_path, trial.tracks.n_frames()));
      }
    }
    trial.force = read_force(find_force_file(trial_dir.string()), m.forceplate);
    s.trials.push_back(std::move(trial));
  }
  return s;
}

void write_session(const std::string& root, const Session& session, XyptsLayout layout) {
  const Manifest& m = session.manifest;
  // Check everything before writing anything.
  std::vector<const CalibrationImage*> images;
  for (const std::string& camera : m.video.cameras) {
    const auto it = std::find_if(session.images.begin(), session.images.end(),
                                 [&](const CalibrationImage& im) { return im.camera == camera; });
    if (it == session.images.end())
      throw Error(fmt::format("write_session: no calibration image for camera '{}'", camera));
    images.push_back(&*it);
  }
  if (session.trials.size() != m.trials.size())
    throw Error(fmt::format("write_session: {} trials but the manifest lists {}", session.trials.size(), m.trials.size()));
  const bool flip = m.video.image_origin == ImageOrigin::BottomLeft;
  if (flip && !(m.video.image_height_px && *m.video.image_height_px > 0.0))
    throw Error("write_session: a bottom-left image origin needs video.image_height_px");
  for (std::size_t i = 0; i < session.trials.size(); ++i) {
    const TrialRecording& t = session.trials[i];
    if (t.spec.id != m.trials[i].id || t.spec.dir != m.trials[i].dir)
      throw Error(fmt::format("write_session: trial {} ('{}' in '{}') differs from the manifest's ('{}' in '{}')", i,
                              t.spec.id, t.spec.dir, m.trials[i].id, m.trials[i].dir));
    if (t.tracks.points != m.video.points || t.tracks.cameras != m.video.cameras)
      throw Error(fmt::format("write_session: trial '{}' tracks' points or cameras are not the manifest's", t.spec.id));
    if (t.force.layout == ForceLayout::Resultants && m.forceplate.pretrigger_fraction &&
        t.force.pretrigger_samples !=
            trigger_sample_from_fraction(*m.forceplate.pretrigger_fraction, static_cast<int>(t.force.data.rows())))
      throw Error(fmt::format("write_session: trial '{}' BioWare record has {} pretrigger samples but the manifest's "
                              "pretrigger_fraction {} of {} samples gives {}",
                              t.spec.id, t.force.pretrigger_samples, *m.forceplate.pretrigger_fraction,
                              t.force.data.rows(),
                              trigger_sample_from_fraction(*m.forceplate.pretrigger_fraction,
                                                           static_cast<int>(t.force.data.rows()))));
  }

  const fs::path dir(root);
  std::error_code ec;
  fs::create_directories(dir / "calibration", ec);
  if (ec) throw Error(fmt::format("write_session: cannot create {}: {}", (dir / "calibration").string(), ec.message()));
  write_manifest((dir / "session.toml").string(), m);
  write_frame_csv((dir / "calibration" / "frame.csv").string(), session.frame);
  for (const CalibrationImage* image : images)
    write_camera_csv((dir / "calibration" / (image->camera + ".csv")).string(), *image);
  for (const TrialRecording& t : session.trials) {
    const fs::path trial_dir = dir / t.spec.dir;
    fs::create_directories(trial_dir, ec);
    if (ec) throw Error(fmt::format("write_session: cannot create {}: {}", trial_dir.string(), ec.message()));
    write_xypts((trial_dir / "xypts.csv").string(), t.tracks, layout, m.video.image_origin,
                flip ? *m.video.image_height_px : 0.0);
    write_force((trial_dir / "force.txt").string(), t.force, m.forceplate.model);
  }
}

}  // namespace dropfit::capture
