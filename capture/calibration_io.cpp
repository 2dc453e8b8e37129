// calibration/frame.csv and calibration/<camera>.csv; see capture/io.h.
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

namespace dropfit::capture {

using namespace detail;

std::vector<CalibrationMarker> read_frame_csv(const std::string& path) {
  const std::vector<Line> lines = read_lines(path);
  if (lines.empty() || blank_line(lines[0].text))
    throw InputError(path, 1, 0, "", "expected the header id,x_m,y_m,z_m,role on line 1");
  const std::vector<Field> header = split_fields(lines[0].text, ',', 5);
  const std::map<std::string, int> col = header_columns(path, lines[0], header, {"id", "x_m", "y_m", "z_m", "role"}, false);
  std::vector<CalibrationMarker> out;
  std::map<std::string, int> seen;
  for (std::size_t i = 1; i < lines.size(); ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) continue;
    const std::vector<Field> f = split_fields(l.text, ',', header.size());
    if (f.size() != header.size()) row_length_error(path, l, f, header, lines[0].number);
    if (out.size() == kMaxCalibrationMarkers)
      throw InputError(path, l.number, 1, "id",
                       fmt::format("more than {} calibration markers: the calibration's leave-one-out checks refit "
                                   "the cameras once per marker and more (the time grows as N^2.5: 1,000 markers take "
                                   "minutes); a calibration structure needs 20 to 100 (a wand's thousands of points "
                                   "belong in [calibration] dlt_coefficients, from easyWand)",
                                   kMaxCalibrationMarkers));
    CalibrationMarker m;
    const Field& id = f[col.at("id")];
    m.id = id.text;
    if (m.id.empty()) throw InputError(path, l.number, id.column, "id", "empty id");
    if (m.id.size() > kMaxNameChars)
      throw InputError(path, l.number, id.column, "id",
                       fmt::format("an id of {} characters, more than {}", m.id.size(), kMaxNameChars));
    if (const auto [it, inserted] = seen.emplace(m.id, l.number); !inserted)
      throw InputError(path, l.number, id.column, "id",
                       fmt::format("duplicate id '{}' (first on line {})", m.id, it->second));
    for (int k = 0; k < 3; ++k) {
      const char* name = k == 0 ? "x_m" : k == 1 ? "y_m" : "z_m";
      m.lab_m[k] = parse_bounded(path, l.number, f[col.at(name)], name, false, kMaxLabCoordinateM,
                                 "a lab position in metres (a frame in millimetres? x_m, y_m and z_m are metres)");
    }
    const Field& role = f[col.at("role")];
    if (role.text == "fit")
      m.role = MarkerRole::Fit;
    else if (role.text == "check")
      m.role = MarkerRole::Check;
    else
      throw InputError(path, l.number, role.column, "role",
                       fmt::format("role '{}' is neither 'fit' nor 'check'", role.text));
    out.push_back(m);
  }
  if (out.empty()) throw InputError(path, 0, 0, "", "no calibration markers after the header");
  return out;
}

CalibrationImage read_camera_csv(const std::string& path, const std::string& camera,
                                 const std::vector<CalibrationMarker>& frame) {
  const std::vector<Line> lines = read_lines(path);
  if (lines.empty() || blank_line(lines[0].text))
    throw InputError(path, 1, 0, "", "expected the header id,u_px,v_px on line 1");
  const std::vector<Field> header = split_fields(lines[0].text, ',', 3);
  const std::map<std::string, int> col = header_columns(path, lines[0], header, {"id", "u_px", "v_px"}, false);
  std::set<std::string> known;
  for (const CalibrationMarker& m : frame) known.insert(m.id);
  CalibrationImage image;
  image.camera = camera;
  std::map<std::string, int> seen;
  for (std::size_t i = 1; i < lines.size(); ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) continue;
    const std::vector<Field> f = split_fields(l.text, ',', header.size());
    if (f.size() != header.size()) row_length_error(path, l, f, header, lines[0].number);
    CameraObservation obs;
    const Field& id = f[col.at("id")];
    obs.id = id.text;
    if (obs.id.empty()) throw InputError(path, l.number, id.column, "id", "empty id");
    if (!known.count(obs.id))
      throw InputError(path, l.number, id.column, "id",
                       fmt::format("marker '{}' is not in calibration/frame.csv", obs.id));
    if (const auto [it, inserted] = seen.emplace(obs.id, l.number); !inserted)
      throw InputError(path, l.number, id.column, "id",
                       fmt::format("duplicate id '{}' (first on line {})", obs.id, it->second));
    obs.image_px.x() = parse_bounded(path, l.number, f[col.at("u_px")], "u_px", false, kMaxPixel, "an image coordinate");
    obs.image_px.y() = parse_bounded(path, l.number, f[col.at("v_px")], "v_px", false, kMaxPixel, "an image coordinate");
    image.observations.push_back(obs);
  }
  return image;
}

void write_frame_csv(const std::string& path, const std::vector<CalibrationMarker>& frame) {
  std::string s = "id,x_m,y_m,z_m,role\n";
  auto out = std::back_inserter(s);
  for (const CalibrationMarker& m : frame)
    fmt::format_to(out, "{},{:.9g},{:.9g},{:.9g},{}\n", csv_field(m.id), m.lab_m.x(), m.lab_m.y(), m.lab_m.z(),
                   m.role == MarkerRole::Fit ? "fit" : "check");
  write_whole(path, s);
}

void write_camera_csv(const std::string& path, const CalibrationImage& image) {
  std::string s = "id,u_px,v_px\n";
  auto out = std::back_inserter(s);
  for (const CameraObservation& o : image.observations)
    fmt::format_to(out, "{},{},{}\n", csv_field(o.id), pixel(o.image_px.x()), pixel(o.image_px.y()));
  write_whole(path, s);
}

DltCoefficients dlt_from_bottom_left(const DltCoefficients& l, double image_height_px) {
  // v_top = H - v_bottom with v_bottom = (L5 X + L6 Y + L7 Z + L8) / D and
  // D = L9 X + L10 Y + L11 Z + 1, so v_top = ((H L9 - L5) X + (H L10 - L6) Y
  // + (H L11 - L7) Z + (H - L8)) / D: the v row changes, u and D do not.
  // The map is its own inverse.
  DltCoefficients out = l;
  const double h = image_height_px;
  out(4) = h * l(8) - l(4);
  out(5) = h * l(9) - l(5);
  out(6) = h * l(10) - l(6);
  out(7) = h - l(7);
  return out;
}

std::vector<DltCoefficients> read_dlt_coefficients(const std::string& path, const VideoSpec& video) {
  const int n_cameras = static_cast<int>(video.cameras.size());
  const bool flip = video.image_origin == ImageOrigin::BottomLeft;
  if (flip && !(video.image_height_px && *video.image_height_px > 0.0))
    throw InputError(path, 0, 0, "video.image_height_px", "a bottom-left image origin needs video.image_height_px");
  const std::vector<Line> lines = read_lines(path);
  std::vector<DltCoefficients> out(static_cast<std::size_t>(n_cameras), DltCoefficients::Zero());
  int row = 0;
  bool first = true;
  for (const Line& l : lines) {
    if (blank_line(l.text)) continue;
    std::vector<Field> f = split_fields(l.text, separator_of(l.text), static_cast<std::size_t>(n_cameras) + 1);
    drop_trailing_empty(f);
    const bool was_first = first;
    first = false;
    // A header line is tolerated: the first line, when its first field is
    // not a number.
    if (was_first && !f[0].text.empty()) {
      const char c = f[0].text[0];
      if (!(std::isdigit(static_cast<unsigned char>(c)) || c == '-' || c == '+' || c == '.')) continue;
    }
    if (row == 11)
      throw InputError(path, l.number, 0, "", "more than 11 rows of coefficients (expected L1..L11, one row each)");
    if (static_cast<int>(f.size()) != n_cameras)
      throw InputError(path, l.number, f.size() > static_cast<std::size_t>(n_cameras) ? f[n_cameras].column : 0,
                       fmt::format("L{}", row + 1),
                       fmt::format("{} fields, expected one column per camera of video.cameras ({})", f.size(),
                                   n_cameras));
    for (int c = 0; c < n_cameras; ++c)
      out[c](row) = parse_number(path, l.number, f[c], fmt::format("L{} of {}", row + 1, video.cameras[c]), false);
    ++row;
  }
  if (row != 11)
    throw InputError(path, 0, 0, "", fmt::format("{} rows of coefficients, expected 11 (L1..L11)", row));
  for (int c = 0; c < n_cameras; ++c) {
    if (out[c].head<3>().isZero() || out[c].segment<3>(4).isZero())
      throw InputError(path, 0, 0, video.cameras[c],
                       fmt::format("camera {} (column {}): L1..L3 or L5..L7 are all zero, not a camera",
                                   video.cameras[c], c + 1));
    if (flip) out[c] = dlt_from_bottom_left(out[c], *video.image_height_px);
  }
  return out;
}

}  // namespace dropfit::capture
