// Seed files (capture/tracking.h): where each marker is in one frame, in
// one camera's pixels or in the lab.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "capture/tracking.h"
#include "capture/text_io.h"
#include "core/error.h"

namespace dropfit::capture {

namespace {

struct SeedRow {
  std::string point;
  int frame = 0;
  std::vector<double> values;  // the columns after point and frame
  int line = 0;
};

// A seed file with the columns `names` (point, frame, then numbers), in any
// order; blank and '#' lines skipped.
std::vector<SeedRow> read_seed_rows(const std::string& path, const std::vector<std::string>& points,
                                    const std::vector<std::string>& names) {
  const std::vector<detail::Line> lines = detail::read_lines(path);
  const std::string expected = fmt::format("{}", fmt::join(names, ","));
  std::vector<int> col;  // index of each of names
  std::vector<SeedRow> seeds;
  for (const detail::Line& line : lines) {
    const std::string_view t = detail::trim(line.text);
    if (t.empty() || t[0] == '#') continue;
    const std::vector<detail::Field> fields = detail::split_fields(line.text, ',');
    if (col.empty()) {
      const std::map<std::string, int> index = detail::header_columns(path, line, fields, names, false);
      for (const std::string& name : names) col.push_back(index.at(name));
      continue;
    }
    if (fields.size() != names.size())
      throw InputError(path, line.number, 0, "", fmt::format("expected {} fields, found {}", names.size(), fields.size()));
    SeedRow s;
    s.line = line.number;
    const detail::Field& point = fields[col[0]];
    s.point = point.text;
    if (std::find(points.begin(), points.end(), s.point) == points.end())
      throw InputError(path, line.number, point.column, "point",
                       fmt::format("unknown point '{}' (not in [video].points: {})", s.point, fmt::join(points, ", ")));
    for (const SeedRow& other : seeds)
      if (other.point == s.point)
        throw InputError(path, line.number, point.column, "point",
                         fmt::format("point '{}' already seeded on line {}", s.point, other.line));
    const double frame = detail::parse_number(path, line.number, fields[col[1]], "frame", false);
    if (frame < 0 || frame != std::floor(frame) || frame > 1e9)
      throw InputError(path, line.number, fields[col[1]].column, "frame",
                       fmt::format("'{}' is not a frame number (0, 1, 2, ...)", fields[col[1]].text));
    s.frame = static_cast<int>(frame);
    for (std::size_t k = 2; k < names.size(); ++k)
      s.values.push_back(detail::parse_number(path, line.number, fields[col[k]], names[k], false));
    seeds.push_back(s);
  }
  if (col.empty()) throw InputError(path, 0, 0, "", "empty seed file (expected the header " + expected + ")");
  if (seeds.empty()) throw InputError(path, 0, 0, "", "no seeds in the file");
  return seeds;
}

}  // namespace

std::vector<Seed> read_seed_csv(const std::string& path, const std::vector<std::string>& points) {
  std::vector<Seed> seeds;
  for (const SeedRow& r : read_seed_rows(path, points, {"point", "frame", "u_px", "v_px"}))
    seeds.push_back({r.point, r.frame, {r.values[0], r.values[1]}, path, r.line});
  return seeds;
}

std::vector<LabSeed> read_lab_seed_csv(const std::string& path, const std::vector<std::string>& points) {
  std::vector<LabSeed> seeds;
  for (const SeedRow& r : read_seed_rows(path, points, {"point", "frame", "x_m", "y_m", "z_m"}))
    seeds.push_back({r.point, r.frame, {r.values[0], r.values[1], r.values[2]}, r.line});
  return seeds;
}

void write_seed_csv(const std::string& path, const std::vector<Seed>& seeds) {
  std::string text = "point,frame,u_px,v_px\n";
  for (const Seed& s : seeds) text += fmt::format("{},{},{:.3f},{:.3f}\n", s.point, s.frame, s.uv_px.x(), s.uv_px.y());
  try {
    detail::write_whole(path, text);
  } catch (const Error& e) {
    throw InputError(path, 0, 0, "", std::string("cannot write the seed file: ") + e.what());
  }
}

}  // namespace dropfit::capture
