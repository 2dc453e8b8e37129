// Seed files (capture/tracking.h): where each marker is in one frame, in
// one camera's pixels or in the lab.
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "capture/tracking.h"
#include "capture/text_io.h"
#include "core/error.h"

namespace dropfit::capture {

namespace {
std::string trim(const std::string& s) {
  std::size_t b = 0, e = s.size();
  while (b < e && std::isspace(static_cast<unsigned char>(s[b]))) ++b;
  while (e > b && std::isspace(static_cast<unsigned char>(s[e - 1]))) --e;
  return s.substr(b, e - b);
}

std::vector<std::string> split_csv(const std::string& line) {
  std::vector<std::string> out;
  std::string field;
  std::istringstream in(line);
  while (std::getline(in, field, ',')) out.push_back(trim(field));
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}

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
  std::ifstream in(path);
  if (!in) throw InputError(path, 0, 0, "", "cannot open the seed file");
  std::string line;
  int line_no = 0;
  std::vector<int> col;  // index of each of names
  const std::string expected = fmt::format("{}", fmt::join(names, ","));
  const int n_cols = static_cast<int>(names.size());
  std::vector<SeedRow> seeds;
  while (std::getline(in, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    const auto fields = split_csv(t);
    if (col.empty()) {
      col.assign(names.size(), -1);
      for (std::size_t i = 0; i < fields.size(); ++i) {
        const auto it = std::find(names.begin(), names.end(), fields[i]);
        if (it == names.end())
          throw InputError(path, line_no, static_cast<int>(i) + 1, fields[i],
                           "unknown column (expected " + expected + ")");
        if (col[it - names.begin()] >= 0)
          throw InputError(path, line_no, static_cast<int>(i) + 1, fields[i], "repeated column");
        col[it - names.begin()] = static_cast<int>(i);
      }
      for (int k = 0; k < n_cols; ++k)
        if (col[k] < 0) throw InputError(path, line_no, 0, names[k], "missing column (expected " + expected + ")");
      continue;
    }
    if (fields.size() != names.size())
      throw InputError(path, line_no, 0, "", fmt::format("expected {} fields, found {}", names.size(), fields.size()));
    SeedRow s;
    s.line = line_no;
    s.point = fields[col[0]];
    if (std::find(points.begin(), points.end(), s.point) == points.end()) {
      std::string known;
      for (const auto& p : points) known += (known.empty() ? "" : ", ") + p;
      throw InputError(path, line_no, col[0] + 1, "point",
                       fmt::format("unknown point '{}' (not in [video].points: {})", s.point, known));
    }
    for (const SeedRow& other : seeds)
      if (other.point == s.point)
        throw InputError(path, line_no, col[0] + 1, "point",
                         fmt::format("point '{}' already seeded on line {}", s.point, other.line));
    auto number = [&](int k) {
      const std::string& f = fields[col[k]];
      try {
        std::size_t used = 0;
        const double v = std::stod(f, &used);
        if (used != f.size() || !std::isfinite(v)) throw std::invalid_argument(f);
        return v;
      } catch (const std::exception&) {
        throw InputError(path, line_no, col[k] + 1, names[k], fmt::format("'{}' is not a number", f));
      }
    };
    const double frame = number(1);
    if (frame < 0 || frame != std::floor(frame) || frame > 1e9)
      throw InputError(path, line_no, col[1] + 1, "frame", fmt::format("'{}' is not a frame number (0, 1, 2, ...)", fields[col[1]]));
    s.frame = static_cast<int>(frame);
    for (int k = 2; k < n_cols; ++k) s.values.push_back(number(k));
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
