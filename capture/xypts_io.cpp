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
#include <regex>

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

}  // namespace

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

  static const std::regex dltdv83(R"(^pt([0-9]+)_cam([0-9]+)_([XY])$)");
  static const std::regex dltdv84(R"(^(.+)_cam([0-9]+)_([UV])$)");
  static const std::regex argus(R"(^(.+)_cam_([0-9]+)_([xy])$)");
  const char* layout_names[] = {"DLTdv 8.3 (ptK_camN_X)", "DLTdv 8.4 (NAME_camN_U)", "Argus (NAME_cam_N_x)"};

  const Line& head = lines[0];
  const std::vector<Field> header = split_fields(head.text, ',');
  std::vector<int> target(header.size(), -1);  // column of uv_px for each file column
  std::vector<int> source(width, -1);           // file column for each column of uv_px
  int layout = -1;
  for (std::size_t j = 0; j < header.size(); ++j) {
    const Field& f = header[j];
    std::smatch m;
    int this_layout = -1;
    int point = -1;
    std::string point_name;
    std::string camera_text;
    std::string axis_text;
    if (std::regex_match(f.text, m, dltdv83)) {
      this_layout = 0;
      point_name = m[1].str();
      camera_text = m[2].str();
      axis_text = m[3].str();
    } else if (std::regex_match(f.text, m, argus)) {
      this_layout = 2;
      point_name = m[1].str();
      camera_text = m[2].str();
      axis_text = m[3].str();
    } else if (std::regex_match(f.text, m, dltdv84)) {
      this_layout = 1;
      point_name = m[1].str();
      camera_text = m[2].str();
      axis_text = m[3].str();
    } else {
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("column '{}' is not an xypts column (ptK_camN_X, NAME_camN_U or NAME_cam_N_x)",
                                   f.text));
    }
    if (layout < 0) layout = this_layout;
    if (layout != this_layout)
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("column '{}' is in the {} layout but the first column is in the {} layout", f.text,
                                   layout_names[this_layout], layout_names[layout]));
    if (this_layout == 0) {
      const long long k = std::atoll(point_name.c_str());
      if (point_name.size() > 9 || k < 1 || k > n_points)
        throw InputError(path, head.number, f.column, f.text,
                         fmt::format("point pt{} is not in the manifest, whose video.points lists {} points",
                                     point_name, n_points));
      point = static_cast<int>(k - 1);
    } else {
      const auto it = std::find(video.points.begin(), video.points.end(), point_name);
      if (it == video.points.end())
        throw InputError(path, head.number, f.column, f.text,
                         fmt::format("point '{}' is not in the manifest's video.points", point_name));
      point = static_cast<int>(it - video.points.begin());
    }
    const long long cam = camera_text.size() > 9 ? 0 : std::atoll(camera_text.c_str());
    if (cam < 1 || cam > n_cameras)
      throw InputError(path, head.number, f.column, f.text,
                       fmt::format("camera {} is not in the manifest, whose video.cameras lists {} cameras",
                                   camera_text, n_cameras));
    const int axis = (axis_text == "X" || axis_text == "U" || axis_text == "x") ? 0 : 1;
    const int c = tracks.column(point, static_cast<int>(cam - 1)) + axis;
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
    const std::vector<Field> f = split_fields(l.text, ',');
    if (f.size() != header.size()) row_length_error(path, l, f, header, lines[0].number);
    // A point or point/camera pair absent from the file was never digitised:
    // its columns stay NaN.
    std::fill(row.begin(), row.end(), kNaN);
    for (std::size_t j = 0; j < f.size(); ++j) {
      double v = parse_number(path, l.number, f[j], header[j].text, true);
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
