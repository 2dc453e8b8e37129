// trials/T/xypts.csv in the layouts of DLTdv and Argus; see capture/io.h.
#include "capture/io.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <set>
#include <string_view>

#include "capture/text_io.h"
#include "core/error.h"
#include <limits>

namespace dropfit::capture {
namespace {

using namespace detail;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string xypts_column(XyptsLayout layout, int point, const std::string& name, int camera, int axis) {
  switch (layout) {
    case XyptsLayout::Dltdv83: return fmt::format("pt{}_cam{}_{}", point + 1, camera + 1, axis == 0 ? "X" : "Y");
    case XyptsLayout::Dltdv84: return fmt::format("{}_cam{}_{}", name, camera + 1, axis == 0 ? "U" : "V");
    case XyptsLayout::Argus: return fmt::format("{}_cam_{}_{}", name, camera + 1, axis == 0 ? "x" : "y");
  }
  return {};
}


// K of a default point name "ptK" (K digits only), nullopt otherwise; K
// with more than 9 digits reads as 0 (out of range).
std::optional<long long> default_point_number(std::string_view name) {
  if (name.size() < 3 || name.substr(0, 2) != "pt") return std::nullopt;
  const std::string_view k = name.substr(2);
  if (!std::all_of(k.begin(), k.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); }))
    return std::nullopt;
  return k.size() > 9 ? 0 : std::stoll(std::string(k));
}


// A name as quoted in a message: at most 80 characters.
std::string shorten(std::string_view s) {
  return s.size() <= 80 ? std::string(s) : fmt::format("{}... ({} characters)", s.substr(0, 60), s.size());
}

}  // namespace

namespace detail {
std::optional<ColumnName> parse_column_name(std::string_view s) {
  if (s.size() < 2 || s[s.size() - 2] != '_') return std::nullopt;
  ColumnName out;
  const char a = s.back();
  bool argus = false;
  switch (a) {
    case 'X': out.layout = 0; out.axis = 0; break;
    case 'Y': out.layout = 0; out.axis = 1; break;
    case 'U': out.layout = 1; out.axis = 0; break;
    case 'V': out.layout = 1; out.axis = 1; break;
    case 'x': out.layout = 2; out.axis = 0; argus = true; break;
    case 'y': out.layout = 2; out.axis = 1; argus = true; break;
    default: return std::nullopt;
  }
  std::string_view rest = s.substr(0, s.size() - 2);
  std::size_t digits = 0;
  while (digits < rest.size() && std::isdigit(static_cast<unsigned char>(rest[rest.size() - 1 - digits]))) ++digits;
  if (digits == 0) return std::nullopt;
  out.camera_text = std::string(rest.substr(rest.size() - digits));
  rest.remove_suffix(digits);
  const std::string_view marker = argus ? "_cam_" : "_cam";
  if (rest.size() <= marker.size() || rest.substr(rest.size() - marker.size()) != marker) return std::nullopt;
  rest.remove_suffix(marker.size());
  out.point = std::string(rest);
  out.camera = digits > 9 ? 0 : std::stoll(out.camera_text);
  return out;
}

}  // namespace detail

MarkerTracks2D read_xypts(const std::string& path, const VideoSpec& video) {
  if (video.image_origin == ImageOrigin::BottomLeft && !(video.image_height_px && *video.image_height_px > 0.0))
    throw InputError(path, 0, 0, "video.image_height_px", "a bottom-left image origin needs video.image_height_px");
  const std::vector<Line> lines = read_lines(path);
  if (lines.empty() || blank_line(lines[0].text))
    throw InputError(path, 1, 0, "", "expected the xypts column header on line 1");

  MarkerTracks2D tracks;
  tracks.points = video.points;
  tracks.cameras = video.cameras;
  const int n_points = tracks.n_points();
  const int n_cameras = tracks.n_cameras();
  const int width = 2 * n_points * n_cameras;

  const char* layout_names[] = {"DLTdv 8.3 (ptK_camN_X)", "DLTdv 8.4 (NAME_camN_U)", "Argus (NAME_cam_N_x)"};

  const Line& head = lines[0];
  const char sep = separator_of(head.text);
  // Each manifest point/camera/axis has one column at most.
  const std::vector<Field> header = split_fields(head.text, sep, static_cast<std::size_t>(width));
  if (header.size() > static_cast<std::size_t>(width))
    throw InputError(path, head.number, header[width].column, "",
                     fmt::format("more than {} columns, the most {} points and {} cameras can have", width, n_points,
                                 n_cameras));
  std::vector<int> target(header.size(), -1);  // column of uv_px for each file column
  std::vector<int> source(width, -1);           // file column for each column of uv_px
  int layout = -1;
  for (std::size_t j = 0; j < header.size(); ++j) {
    const Field& f = header[j];
    if (f.text.size() > kMaxNameChars + 16)
      throw InputError(path, head.number, f.column, shorten(f.text),
                       fmt::format("a column name of {} characters, more than any point name allows ({})",
                                   f.text.size(), kMaxNameChars));
    const std::optional<ColumnName> name = parse_column_name(f.text);
    if (!name)
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("column '{}' is not an xypts column (ptK_camN_X, NAME_camN_U or NAME_cam_N_x)",
                                   shorten(f.text)));
    if (layout < 0) layout = name->layout;
    if (layout != name->layout)
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("column '{}' is in the {} layout but the first column is in the {} layout", f.text,
                                   layout_names[name->layout], layout_names[layout]));
    // A manifest name first; else DLTdv's and Argus's default names ptK,
    // meaning video.points[K-1] (the only meaning in the 8.3 layout).
    int point = -1;
    if (name->layout != 0) {
      const auto it = std::find(video.points.begin(), video.points.end(), name->point);
      if (it != video.points.end()) point = static_cast<int>(it - video.points.begin());
    }
    if (point < 0) {
      const std::optional<long long> k = default_point_number(name->point);
      if (!k) {
        if (name->layout == 0)
          throw InputError(path, head.number, f.column, f.text,
                           fmt::format("column '{}' is not an xypts column (ptK_camN_X, NAME_camN_U or NAME_cam_N_x)",
                                       shorten(f.text)));
        throw InputError(path, head.number, f.column, f.text,
                         fmt::format("point '{}' is not in the manifest's video.points", shorten(name->point)));
      }
      if (*k < 1 || *k > n_points)
        throw InputError(path, head.number, f.column, f.text,
                         fmt::format("point {} is not in the manifest, whose video.points lists {} points",
                                     shorten(name->point), n_points));
      point = static_cast<int>(*k - 1);
    }
    const long long cam = name->camera;
    if (cam < 1 || cam > n_cameras)
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("camera {} is not in the manifest, whose video.cameras lists {} cameras",
                                   shorten(name->camera_text), n_cameras));
    const int c = tracks.column(point, static_cast<int>(cam - 1)) + name->axis;
    if (source[c] >= 0)
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("column '{}' duplicates column {} ('{}')", f.text, source[c] + 1,
                                   header[source[c]].text));
    source[c] = static_cast<int>(j);
    target[j] = c;
  }
  for (int c = 0; c < width; c += 2) {
    if ((source[c] >= 0) != (source[c + 1] >= 0)) {
      const int present = source[c] >= 0 ? source[c] : source[c + 1];
      const Field& f = header[present];
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("column '{}' has no partner {} column", f.text, source[c] >= 0 ? "v" : "u"));
    }
  }

  const bool flip = video.image_origin == ImageOrigin::BottomLeft;
  const double height = flip ? *video.image_height_px : 0.0;
  std::vector<double> values;
  std::size_t end = lines.size();
  while (end > 1 && blank_line(lines[end - 1].text)) --end;
  std::vector<double> row(width);
  for (std::size_t i = 1; i < end; ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) throw InputError(path, l.number, 0, "", "blank line inside the data (each row is a frame)");
    const std::vector<Field> f = split_fields(l.text, sep, header.size());
    if (f.size() != header.size()) row_length_error(path, l, f, header, lines[0].number);
    // A point or point/camera pair absent from the file was never digitised:
    // its columns stay NaN.
    std::fill(row.begin(), row.end(), kNaN);
    for (std::size_t j = 0; j < f.size(); ++j) {
      double v = parse_bounded(path, l.number, f[j], header[j].text, true, kMaxPixel, "an image coordinate");
      if (flip && (target[j] % 2) == 1) v = height - v;
      row[target[j]] = v;
    }
    values.insert(values.end(), row.begin(), row.end());
  }
  const Eigen::Index n_frames = width > 0 ? static_cast<Eigen::Index>(values.size() / width) : 0;
  if (n_frames == 0) throw InputError(path, 0, 0, "", "no data rows after the header");
  if (video.trigger_frame >= n_frames)
    throw InputError(path, 0, 0, "video.trigger_frame",
                     fmt::format("trigger_frame {} is beyond the file's {} rows", video.trigger_frame, n_frames));
  tracks.uv_px = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>(
      values.data(), n_frames, width);
  return tracks;
}

void write_xypts(const std::string& path, const MarkerTracks2D& tracks, XyptsLayout layout, ImageOrigin origin,
                 double image_height_px) {
  const bool flip = origin == ImageOrigin::BottomLeft;
  if (flip && !(image_height_px > 0.0))
    throw Error(fmt::format("write_xypts {}: a bottom-left origin needs image_height_px > 0", path));
  const int width = 2 * tracks.n_points() * tracks.n_cameras();
  if (tracks.uv_px.cols() != width)
    throw Error(fmt::format("write_xypts {}: uv_px has {} columns, expected {} for {} points and {} cameras", path,
                            tracks.uv_px.cols(), width, tracks.n_points(), tracks.n_cameras()));
  std::vector<std::string> names;
  for (int p = 0; p < tracks.n_points(); ++p)
    for (int c = 0; c < tracks.n_cameras(); ++c)
      for (int axis = 0; axis < 2; ++axis) names.push_back(csv_field(xypts_column(layout, p, tracks.points[p], c, axis)));
  std::string s = fmt::format("{}\n", fmt::join(names, ","));
  s.reserve(s.size() + static_cast<std::size_t>(tracks.n_frames()) * width * 12);
  for (int f = 0; f < tracks.n_frames(); ++f) {
    for (int c = 0; c < width; ++c) {
      double v = tracks.uv_px(f, c);
      if (flip && c % 2 == 1) v = image_height_px - v;
      if (c > 0) s += ',';
      s += pixel(v);
    }
    s += '\n';
  }
  write_whole(path, s);
}

}  // namespace dropfit::capture

namespace dropfit::capture {

std::string find_xypts(const std::string& trial_dir) {
  namespace fs = std::filesystem;
  const fs::path dir(trial_dir);
  const fs::path plain = dir / "xypts.csv";
  std::error_code ec;
  if (fs::exists(fs::symlink_status(plain, ec))) return plain.string();
  std::vector<std::string> found;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    constexpr std::string_view suffix = "xypts.csv";
    if (name.size() > suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0)
      found.push_back(it->path().string());
  }
  std::sort(found.begin(), found.end());
  if (found.size() > 1)
    throw InputError(plain.string(), 0, 0, "",
                     fmt::format("file not found, and more than one marker table ends in xypts.csv beside it: {} and "
                                 "{}; keep one (or name it xypts.csv)",
                                 found[0], found[1]));
  return found.empty() ? plain.string() : found[0];
}

std::string offsets_path(const std::string& xypts_path) {
  std::string p = xypts_path;
  p.replace(p.size() - std::string_view("xypts.csv").size(), std::string::npos, "offsets.csv");
  return p;
}

FrameOffsets read_offsets(const std::string& path, int n_cameras) {
  const std::vector<Line> lines = read_lines(path);
  std::vector<std::vector<Field>> rows;
  std::vector<int> row_lines;
  bool header_seen = false;
  for (const Line& l : lines) {
    if (blank_line(l.text)) continue;
    std::vector<Field> f = split_fields(l.text, separator_of(l.text), static_cast<std::size_t>(n_cameras) + 1);
    drop_trailing_empty(f);
    // A header line (DLTdv: cam1_offset,cam2_offset; or any words) is skipped.
    const bool words = !f.empty() && !f[0].text.empty() && !std::isdigit(static_cast<unsigned char>(f[0].text[0])) &&
                       f[0].text[0] != '-' && f[0].text[0] != '+' && f[0].text[0] != '.';
    if (rows.empty() && !header_seen && words) {
      header_seen = true;
      continue;
    }
    rows.push_back(std::move(f));
    row_lines.push_back(l.number);
  }
  // DLTdv writes whole frames as %.6f ("-3.000000"); a fraction of a frame
  // cannot name the video frame a row came from.
  auto frames_of = [&](const Field& f, int line, const std::string& field) {
    const double v = parse_number(path, line, f, field, false);
    if (std::abs(v) > 1e6)
      throw InputError(path, line, f.column, field, fmt::format("frame offset {} is beyond +-1000000 frames", f.text));
    if (std::abs(v - std::round(v)) > 1e-6)
      throw InputError(path, line, f.column, field,
                       fmt::format("'{}' is not a whole number of frames (a frame offset names a video frame)", f.text));
    return static_cast<int>(std::lround(v));
  };
  if (rows.empty()) throw InputError(path, 0, 0, "", "no offsets: expected one row per camera or per frame");
  FrameOffsets out;
  if (n_cameras > 1 && static_cast<int>(rows.size()) == n_cameras &&
      std::all_of(rows.begin(), rows.end(), [](const auto& r) { return r.size() == 1; })) {
    // One row per camera: constant offsets.
    out.frames.resize(1, n_cameras);
    for (int c = 0; c < n_cameras; ++c) out.frames(0, c) = frames_of(rows[c][0], row_lines[c], fmt::format("cam{}", c + 1));
    return out;
  }
  // DLTdv 7 and 8: one column per camera (cam1_offset, ...), one row per
  // frame; the offsets may change along the trial.
  out.frames.resize(static_cast<Eigen::Index>(rows.size()), n_cameras);
  out.per_frame = true;
  for (std::size_t r = 0; r < rows.size(); ++r) {
    if (static_cast<int>(rows[r].size()) != n_cameras)
      throw InputError(path, row_lines[r], 0, "",
                       fmt::format("{} fields, expected one offset per camera ({} cameras in video.cameras)",
                                   rows[r].size(), n_cameras));
    for (int c = 0; c < n_cameras; ++c)
      out.frames(static_cast<Eigen::Index>(r), c) = frames_of(rows[r][c], row_lines[r], fmt::format("cam{}", c + 1));
  }
  return out;
}

}  // namespace dropfit::capture
