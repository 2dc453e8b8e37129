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

Session read_session(const std::string& root) {
  const fs::path dir(root);
  Session s;
  s.root = root;
  s.manifest = read_manifest((dir / "session.toml").string());
  const Manifest& m = s.manifest;
  read_session_calibration(root, s);
  for (const TrialSpec& spec : m.trials) {
    TrialRecording trial;
    trial.spec = spec;
    trial.xypts_path = find_xypts((dir / spec.dir).string());
    trial.tracks = read_xypts(trial.xypts_path, m.video);
    const std::string offsets = offsets_path(trial.xypts_path);
    if (exists_entry(offsets)) trial.frame_offsets = read_offsets(offsets, static_cast<int>(m.video.cameras.size()));
    trial.force = read_force(find_force_file((dir / spec.dir).string()), m.forceplate);
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
    if (t.force.layout == ForceLayout::Resultants &&
        t.force.pretrigger_samples !=
            trigger_sample_from_fraction(m.forceplate.pretrigger_fraction, static_cast<int>(t.force.data.rows())))
      throw Error(fmt::format("write_session: trial '{}' BioWare record has {} pretrigger samples but the manifest's "
                              "pretrigger_fraction {} of {} samples gives {}",
                              t.spec.id, t.force.pretrigger_samples, m.forceplate.pretrigger_fraction,
                              t.force.data.rows(),
                              trigger_sample_from_fraction(m.forceplate.pretrigger_fraction,
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
