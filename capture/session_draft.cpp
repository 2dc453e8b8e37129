// A session.toml draft from a lab's folder; see capture/session_draft.h.
#include "capture/session_draft.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <map>
#include <functional>
#include <optional>
#include <set>
#include <sstream>
#include <string_view>

#include "capture/c3d.h"
#include "capture/force_io.h"
#include "capture/force_internal.h"
#include "capture/io.h"
#include "capture/text_io.h"
#include "core/error.h"
#include <toml++/toml.h>

namespace dropfit::capture {
namespace {

using namespace detail;
namespace fs = std::filesystem;

std::string toml_quoted(const std::string& s) {
  std::ostringstream out;
  out << toml::value<std::string>(s);
  return out.str();
}

std::string toml_list(const std::vector<std::string>& v) {
  std::vector<std::string> q;
  for (const auto& s : v) q.push_back(toml_quoted(s));
  return fmt::format("[{}]", fmt::join(q, ", "));
}

bool ends_with_ci(std::string_view s, std::string_view suffix) {
  return s.size() >= suffix.size() && iequals(s.substr(s.size() - suffix.size()), suffix);
}

std::string relative_to(const fs::path& p, const fs::path& root) { return p.lexically_relative(root).generic_string(); }

// What the marker tables' headers say: points in order of first appearance
// (a DLTdv 8.3 table's ptK as "ptK"), the number of cameras, the layout.
struct TableHeader {
  std::vector<std::string> points;
  int cameras = 0;
  int layout = -1;
  int rows = 0;
};

TableHeader read_table_header(const std::string& path) {
  const std::vector<Line> lines = read_lines(path);
  if (lines.empty()) throw InputError(path, 1, 0, "", "empty marker table: expected the xypts column header");
  TableHeader h;
  const std::vector<Field> fields = split_fields(lines[0].text, separator_of(lines[0].text));
  for (const Field& f : fields) {
    const std::optional<ColumnName> name = parse_column_name(f.text);
    if (!name)
      throw InputError(path, lines[0].number, f.column, f.text,
                       fmt::format("column '{}' is not an xypts column (ptK_camN_X, NAME_camN_U or NAME_cam_N_x)",
                                   f.text.substr(0, 80)));
    if (h.layout < 0) h.layout = name->layout;
    if (std::find(h.points.begin(), h.points.end(), name->point) == h.points.end()) h.points.push_back(name->point);
    h.cameras = static_cast<int>(std::max<long long>(h.cameras, name->camera));
  }
  for (std::size_t i = 1; i < lines.size(); ++i) h.rows += !blank_line(lines[i].text);
  // DLTdv 8.3 numbers its points: pt1, pt2, ... in order.
  if (h.layout == 0) {
    std::sort(h.points.begin(), h.points.end(), [](const std::string& a, const std::string& b) {
      return a.size() != b.size() ? a.size() < b.size() : a < b;
    });
  }
  return h;
}

// The plate as a force export describes it.
struct PlateFacts {
  std::string kind;  // "Kistler eight-channel text", "BioWare text", "C3D"
  double rate_hz = 0.0;
  int plates = 1;
  std::optional<double> trigger_n;            // a Kistler text's "Trigger  Fz > 25 N"
  std::optional<std::array<double, 3>> geometry_m;  // a C3D's a, b, az0
  std::string device;
};

PlateFacts read_plate_facts(const std::string& path) {
  PlateFacts p;
  switch (force_file_kind(path)) {
    case ForceFileKind::BioWareText: {
      const BioWareExport ex = read_bioware_export(path);
      p.kind = ex.version.empty() ? "BioWare text" : "BioWare " + ex.version + " text";
      p.rate_hz = ex.sample_rate_hz;
      p.plates = ex.n_plates;
      for (const Line& l : read_text_lines(path)) {
        if (iequals_prefix(l.text, "Device:")) {
          const std::vector<Field> f = split_fields(l.text, '\t');
          if (f.size() > 1) p.device = f[1].text;
        }
        if (iequals_prefix(l.text, "abs time")) break;
      }
      break;
    }
    case ForceFileKind::KistlerText: {
      p.kind = "Kistler eight-channel text";
      for (const Line& l : read_text_lines(path)) {
        const std::vector<Field> f = split_fields(l.text, '\t');
        if (f.size() < 2) continue;
        if (iequals(f[0].text, "Sample rate")) p.rate_hz = parse_number(path, l.number, f[1], "Sample rate", false);
        if (iequals(f[0].text, "Device")) p.device = f[1].text;
        if (iequals(f[0].text, "Trigger")) {
          // "Fz > 25 N": the number after '>'.
          const std::size_t gt = f[1].text.find('>');
          if (gt != std::string::npos) {
            try {
              p.trigger_n = std::stod(f[1].text.substr(gt + 1));
            } catch (const std::exception&) {
            }
          }
        }
        if (iequals(f[0].text, "Time(s)") || iequals(f[0].text, "Time (s)")) break;
      }
      break;
    }
    case ForceFileKind::C3d: {
      const C3dFile f = read_c3d(path);
      p.kind = "C3D";
      p.rate_hz = f.analog_rate_hz();
      if (const C3dParameter* used = f.find("FORCE_PLATFORM", "USED"); used && !used->numbers.empty())
        p.plates = static_cast<int>(used->numbers[0]);
      const C3dParameter* type = f.find("FORCE_PLATFORM", "TYPE");
      const C3dParameter* origin = f.find("FORCE_PLATFORM", "ORIGIN");
      if (type && !type->numbers.empty() && type->numbers[0] == 3.0 && origin && origin->numbers.size() >= 3) {
        const C3dParameter* units = f.find("POINT", "UNITS");
        const double unit = units && !units->strings.empty() && iequals(units->strings[0], "m") ? 1.0 : 1e-3;
        p.geometry_m = std::array<double, 3>{std::abs(origin->numbers[0]) * unit, std::abs(origin->numbers[1]) * unit,
                                             -std::abs(origin->numbers[2]) * unit};
      }
      break;
    }
    case ForceFileKind::None: break;
  }
  return p;
}

// The folders under `root` (itself included, hidden ones and links
// skipped, four levels at most) holding a marker table or markers.c3d, and
// the DLT coefficient files found anywhere there.
void scan(const fs::path& root, std::vector<fs::path>& trial_dirs, std::vector<fs::path>& coefficient_files) {
  std::error_code ec;
  std::set<fs::path> trials;
  for (auto it = fs::recursive_directory_iterator(root, fs::directory_options::skip_permission_denied, ec);
       !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!name.empty() && name[0] == '.') {
      if (it->is_directory(ec)) it.disable_recursion_pending();
      continue;
    }
    if (it->is_symlink(ec)) continue;
    if (it->is_directory(ec)) {
      if (it.depth() >= 3) it.disable_recursion_pending();
      continue;
    }
    if (ends_with_ci(name, "xypts.csv") || iequals(name, "markers.c3d")) trials.insert(it->path().parent_path());
    if (ends_with_ci(name, "dltcoefs.csv") || ends_with_ci(name, "dlt-coefs.csv") || iequals(name, "dlt_coefs.csv") ||
        iequals(name, "dlt_coefficients.csv"))
      coefficient_files.push_back(it->path());
  }
  trial_dirs.assign(trials.begin(), trials.end());
  std::sort(coefficient_files.begin(), coefficient_files.end());
}

// A trial id from its folder name: the name itself when it is a usable id
// and not taken, else trialN.
std::string trial_id(const fs::path& dir, const fs::path& root, std::set<std::string>& taken, std::size_t index) {
  std::string id = dir == root ? "trial1" : dir.filename().string();
  if (!trial_id_problem(id).empty() || taken.count(id)) id = fmt::format("trial{}", index + 1);
  while (taken.count(id)) id += "_";
  taken.insert(id);
  return id;
}

// What the trial folders hold: the first marker table's header (the others
// checked against it), the first force export's facts, and each trial's
// [[trial]] lines; `d` gets the trials, what was found and what to check.
struct ScannedTrials {
  std::optional<TableHeader> header;
  std::string header_file;
  std::vector<std::string> trial_lines;
  std::optional<PlateFacts> plate;
  std::string plate_file;
  bool any_offsets = false, any_3d = false;
};

ScannedTrials scan_trial_folders(const fs::path& root, const std::vector<fs::path>& trial_dirs, SessionDraft& d) {
  ScannedTrials s;
  std::set<std::string> ids;
  for (std::size_t i = 0; i < trial_dirs.size(); ++i) {
    const fs::path& dir = trial_dirs[i];
    const std::string rel = dir == root ? "." : relative_to(dir, root);
    d.trials.push_back(rel);
    const std::string table = find_xypts(dir.string());
    if (fs::exists(table)) {
      const TableHeader h = read_table_header(table);
      s.any_offsets = s.any_offsets || fs::exists(offsets_path(table));
      d.found.push_back(fmt::format("{}: marker table {} ({} rows, {} points, {} cameras){}", rel,
                                    fs::path(table).filename().string(), h.rows, h.points.size(), h.cameras,
                                    fs::exists(offsets_path(table)) ? " with DLTdv offsets" : ""));
      if (!s.header) {
        s.header = h;
        s.header_file = table;
      } else if (h.points != s.header->points || h.cameras != s.header->cameras) {
        d.check.push_back(fmt::format("video.points ({} names other points or cameras than {})", table, s.header_file));
      }
    } else {
      s.any_3d = true;
      d.found.push_back(fmt::format("{}: 3-D markers (markers.c3d)", rel));
    }
    const std::string force = find_force_file(dir.string());
    if (fs::exists(force)) {
      const PlateFacts p = read_plate_facts(force);
      d.found.push_back(fmt::format("{}: force export {} ({}, {} Hz{})", rel, fs::path(force).filename().string(),
                                    p.kind, p.rate_hz, p.plates > 1 ? fmt::format(", {} plates", p.plates) : ""));
      if (!s.plate) {
        s.plate = p;
        s.plate_file = force;
      }
    } else {
      d.found.push_back(fmt::format("{}: no force export", rel));
    }
    s.trial_lines.push_back(
        fmt::format("\n[[trial]]\nid = {}\ndir = {}\n", toml_quoted(trial_id(dir, root, ids, i)), toml_quoted(rel)));
  }
  return s;
}

// The [forceplate] table from the first force export's facts.
std::string forceplate_toml(const PlateFacts& plate, const std::string& plate_file, const fs::path& root,
                            SessionDraft& d, const std::function<std::string(const std::string&, const std::string&)>& fill) {
  std::string t;
  t += fmt::format("\n[forceplate]\nmodel = {}\nsample_rate_hz = {}  # from {}\n", toml_quoted(plate.device),
                   plate.rate_hz, relative_to(plate_file, root));
  if (plate.trigger_n) {
    t += fmt::format("trigger_threshold_n = {}  # from the export's Trigger line\n", *plate.trigger_n);
  } else {
    t += "trigger_threshold_n = 25.0  # CHECK: the acquisition's trigger level on Fz (N); the trigger sample of an "
         "export without one is found where Fz crosses it\n";
    d.check.push_back("forceplate.trigger_threshold_n");
  }
  if (plate.geometry_m) {
    t += fmt::format("a_m = {}\nb_m = {}\naz0_m = {}  # from the C3D's FORCE_PLATFORM:ORIGIN\n", (*plate.geometry_m)[0],
                     (*plate.geometry_m)[1], (*plate.geometry_m)[2]);
  } else {
    t += fmt::format("a_m = {}\nb_m = {}\naz0_m = {}\n", fill("forceplate.a_m", "sensor offset a from the plate's certificate, m"),
                     fill("forceplate.b_m", "sensor offset b from the plate's certificate, m"),
                     fill("forceplate.az0_m", "top-surface offset az0 from the certificate, m (negative)"));
  }
  t += fmt::format("mat_top_z_m = {}\n", fill("forceplate.mat_top_z_m", "height of the mat's undeformed top, m"));
  if (plate.plates > 1) {
    t += fmt::format("plate = 1  # CHECK: the export holds {} plates\n", plate.plates);
    d.check.push_back("forceplate.plate");
  }
  return t;
}

}  // namespace

SessionDraft draft_session(const std::string& folder) {
  const fs::path root = fs::path(folder).lexically_normal();
  std::error_code ec;
  if (!fs::is_directory(root, ec)) throw InputError(folder, 0, 0, "", "not a folder");
  std::vector<fs::path> trial_dirs, coefficient_files;
  scan(root, trial_dirs, coefficient_files);
  if (trial_dirs.empty())
    throw InputError(folder, 0, 0, "",
                     "no trial found: no marker table (*xypts.csv, as DLTdv and Argus write it) and no markers.c3d in "
                     "this folder or its sub-folders (one folder per trial)");
  SessionDraft d;
  auto fill = [&](const std::string& key, const std::string& what) {
    d.fill_in.push_back(key);
    return toml_quoted("FILL IN: " + what);
  };

  ScannedTrials scanned = scan_trial_folders(root, trial_dirs, d);
  const std::optional<TableHeader>& header = scanned.header;
  const std::optional<PlateFacts>& plate = scanned.plate;
  if (!plate)
    throw InputError(folder, 0, 0, "",
                     "no force export in any trial folder (a Kistler or BioWare text export, or a C3D with analog "
                     "channels): a session needs the plate's record");

  std::string t = fmt::format(
      "# dropfit session manifest, drafted by `dropfit init` from {}.\n"
      "# Values that read \"FILL IN: ...\" must be filled in (dropfit refuses them, naming the line);\n"
      "# lines marked CHECK were taken from a convention, not from the files. docs/formats.md lists every key.\n",
      root.filename().string().empty() ? folder : root.filename().string());
  t += fmt::format("\n[session]\nname = {}\ngravity_m_s2 = 9.81\n", toml_quoted(root.filename().string()));

  std::vector<std::string> points = header ? header->points : std::vector<std::string>{};
  std::vector<std::string> base, surface;
  for (const auto& p : points) {
    if (iequals_prefix(p, "imp")) base.push_back(p);
    if (iequals_prefix(p, "mat")) surface.push_back(p);
  }
  t += fmt::format("\n[impactor]\nmass_kg = {}\nfootprint_m = {}\n", fill("impactor.mass_kg", "the drop mass in kg"),
                   fill("impactor.footprint_m", "[length, width] of the flat contact face in m"));
  if (base.empty()) {
    t += fmt::format("base_markers = {}\n", fill("impactor.base_markers", "names from video.points on the impactor"));
  } else {
    t += fmt::format("base_markers = {}  # CHECK: the points named imp*\n", toml_list(base));
    d.check.push_back("impactor.base_markers");
  }
  t += fmt::format("base_marker_height_m = {}\n",
                   fill("impactor.base_marker_height_m", "height of those markers above the contact face in m"));
  t += fmt::format("\n[mat]\nlength_m = {}\nwidth_m = {}\nsurface_markers = {}{}\n",
                   fill("mat.length_m", "m"), fill("mat.width_m", "m"), toml_list(surface),
                   surface.empty() ? "  # CHECK: no point is named mat*" : "  # CHECK: the points named mat*");
  d.check.push_back("mat.surface_markers");
  t += fmt::format("[[mat.layers]]  # one table per layer, top to bottom\nname = {}\nthickness_m = {}\nmass_kg = {}\n",
                   fill("mat.layers[0].name", "the top layer's name"), fill("mat.layers[0].thickness_m", "m"),
                   fill("mat.layers[0].mass_kg", "kg"));

  std::vector<std::string> cameras;
  for (int c = 1; c <= (header ? header->cameras : 0); ++c) cameras.push_back(fmt::format("cam{}", c));
  if (cameras.empty()) cameras = {"cam1", "cam2"};
  t += fmt::format("\n[video]\ncameras = {}\nframe_rate_hz = {}\npoints = {}\ntrigger_frame = {}\n",
                   toml_list(cameras), fill("video.frame_rate_hz", "the cameras' frame rate in Hz"),
                   toml_list(points),
                   fill("video.trigger_frame",
                        fmt::format("0-based row of the marker tables recorded at the plate's trigger{}",
                                    header ? fmt::format(" (the tables have {} rows)", header->rows) : "")));
  if (header && header->layout == 0) {
    t += fmt::format("image_origin = \"bottom-left\"  # CHECK: DLTdv before 8.4 (ptK_camN_X columns) and Argus write "
                     "bottom-left; DLTdv 8.4 and later top-left\nimage_height_px = {}\n",
                     fill("video.image_height_px", "the images' height in pixels (bottom-left origin)"));
    d.check.push_back("video.image_origin");
  } else if (header && header->layout == 2) {
    t += fmt::format("image_origin = \"bottom-left\"  # CHECK: Argus writes bottom-left\nimage_height_px = {}\n",
                     fill("video.image_height_px", "the images' height in pixels"));
    d.check.push_back("video.image_origin");
  } else {
    t += "image_origin = \"top-left\"  # DLTdv 8.4 and later\n";
  }

  t += forceplate_toml(*plate, scanned.plate_file, root, d, fill);

  // Calibration: given coefficients, else a frame, else none (3-D markers only).
  const bool frame = fs::exists(root / "calibration" / "frame.csv");
  if (!coefficient_files.empty()) {
    t += fmt::format("\n[calibration]\ndlt_coefficients = {}{}\n", toml_quoted(relative_to(coefficient_files[0], root)),
                     coefficient_files.size() > 1 ? "  # CHECK: more than one coefficient file was found" : "");
    d.found.push_back(fmt::format("DLT coefficients {}", relative_to(coefficient_files[0], root)));
    if (coefficient_files.size() > 1) d.check.push_back("calibration.dlt_coefficients");
  } else if (frame) {
    d.found.push_back("calibration frame calibration/frame.csv");
  } else if (header) {
    t += fmt::format("\n[calibration]\ndlt_coefficients = {}\n",
                     fill("calibration.dlt_coefficients",
                          "the DLT coefficient file (easyWand *_dltCoefs.csv), or give calibration/frame.csv"));
  }
  if (scanned.any_offsets) d.found.push_back("DLTdv offsets: rows are used as DLTdv aligned them");
  if (scanned.any_3d && header) d.check.push_back("trials mix marker tables and markers.c3d");
  for (const auto& l : scanned.trial_lines) t += l;
  d.toml = std::move(t);
  return d;
}

}  // namespace dropfit::capture
