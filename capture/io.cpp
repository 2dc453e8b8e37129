// Readers and writers of the session format; see capture/io.h for the
// conventions and shared/spec/session-format.md for the contract.
#include "capture/io.h"

#include <fmt/format.h>
// libfccp's error types copy file names with strncpy, which GCC flags after
// inlining; the truncation is intended (they keep 255 characters).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wstringop-truncation"
#include <libfccp/csv.h>
#pragma GCC diagnostic pop
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <regex>
#include <set>
#include <sstream>
#include <string_view>
#include <toml++/toml.h>

#include "capture/force_internal.h"
#include "capture/force_io.h"
#include "core/error.h"

namespace dropfit::capture {
namespace {

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---------------------------------------------------------------------------
// Lines and fields
// ---------------------------------------------------------------------------

// A field of a delimited line: its text (unquoted, blanks around it removed)
// and the 1-based character column where it starts.
struct Field {
  std::string text;
  int column = 1;
};

struct Line {
  int number = 0;  // 1-based
  std::string text;
};

bool is_blank(char c) { return c == ' ' || c == '\t'; }

bool blank_line(std::string_view s) {
  return std::all_of(s.begin(), s.end(), [](char c) { return is_blank(c); });
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_blank(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_blank(s.back())) s.remove_suffix(1);
  return s;
}

void require_file(const std::string& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st)) throw InputError(path, 0, 0, "", "file not found");
  if (fs::is_directory(st)) throw InputError(path, 0, 0, "", "is a folder, expected a file");
}

// Every line of a text file (CR LF handled, UTF-8 BOM skipped), read with
// libfccp's io::LineReader; its errors become InputError.
std::vector<Line> read_lines(const std::string& path) {
  require_file(path);
  std::vector<Line> lines;
  try {
    io::LineReader reader(path);
    while (const char* text = reader.next_line()) {
      lines.push_back({static_cast<int>(reader.get_file_line()), text});
    }
  } catch (const io::error::can_not_open_file& e) {
    throw InputError(path, 0, 0, "",
                     e.errno_value != 0 ? fmt::format("cannot open: {}", std::strerror(e.errno_value))
                                        : std::string("cannot open"));
  } catch (const io::error::line_length_limit_exceeded& e) {
    throw InputError(path, e.file_line, 0, "", "line longer than 16 MiB");
  } catch (const io::error::base& e) {
    throw InputError(path, 0, 0, "", e.what());
  }
  return lines;
}

// Splits one line at `sep`. A field may be enclosed in double quotes ("" is
// a quote inside); blanks around a field are dropped (tabs only when they
// are not the separator).
std::vector<Field> split_fields(std::string_view line, char sep) {
  std::vector<Field> out;
  auto blank = [sep](char c) { return c == ' ' || (c == '\t' && sep != '\t'); };
  std::size_t i = 0;
  while (true) {
    Field f;
    std::size_t j = i;
    while (j < line.size() && blank(line[j]) && line[j] != sep) ++j;
    if (j < line.size() && line[j] == '"') {
      f.column = static_cast<int>(j) + 1;
      ++j;
      while (j < line.size()) {
        if (line[j] == '"') {
          if (j + 1 < line.size() && line[j + 1] == '"') {
            f.text += '"';
            j += 2;
            continue;
          }
          ++j;
          break;
        }
        f.text += line[j++];
      }
      // Anything but blanks between the closing quote and the separator is
      // kept, so that it fails the field's own check.
      const std::size_t end = std::min(line.find(sep, j), line.size());
      const std::string_view rest = trim(line.substr(j, end - j));
      f.text += rest;
      j = end;
    } else {
      const std::size_t end = std::min(line.find(sep, j), line.size());
      f.column = static_cast<int>(j < end ? j : i) + 1;
      std::string_view text = line.substr(j, end - j);
      while (!text.empty() && blank(text.back())) text.remove_suffix(1);
      f.text = std::string(text);
      j = end;
    }
    out.push_back(std::move(f));
    if (j >= line.size()) break;
    i = j + 1;
  }
  return out;
}

// Trailing empty fields (a trailing separator) are dropped.
void drop_trailing_empty(std::vector<Field>& fields) {
  while (fields.size() > 1 && fields.back().text.empty()) fields.pop_back();
}

bool iequals_prefix(std::string_view s, std::string_view prefix) {
  if (s.size() < prefix.size()) return false;
  for (std::size_t i = 0; i < prefix.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(s[i])) != std::tolower(static_cast<unsigned char>(prefix[i])))
      return false;
  }
  return true;
}

bool iequals(std::string_view a, std::string_view b) { return a.size() == b.size() && iequals_prefix(a, b); }

// Strict number: the whole field must be a number (a leading '+' allowed).
// Empty or NaN: NaN when nan_ok, else an error. Infinite: always an error.
double parse_number(const std::string& file, int line, const Field& f, const std::string& field, bool nan_ok) {
  const std::string& s = f.text;
  if (s.empty()) {
    if (nan_ok) return kNaN;
    throw InputError(file, line, f.column, field, "empty field, expected a number");
  }
  const char* begin = s.data();
  const char* end = s.data() + s.size();
  if (*begin == '+' && begin + 1 < end && *(begin + 1) != '-' && *(begin + 1) != '+') ++begin;
  double value = 0.0;
  const auto [ptr, ec] = std::from_chars(begin, end, value);
  if (ec == std::errc::result_out_of_range)
    throw InputError(file, line, f.column, field, fmt::format("'{}' is out of the range of a double", s));
  if (ec != std::errc() || ptr != end)
    throw InputError(file, line, f.column, field, fmt::format("'{}' is not a number", s));
  if (std::isnan(value)) {
    if (nan_ok) return kNaN;
    throw InputError(file, line, f.column, field, "NaN is not allowed here");
  }
  if (std::isinf(value)) throw InputError(file, line, f.column, field, fmt::format("'{}' is not finite", s));
  return value;
}

long long parse_integer(const std::string& file, int line, const Field& f, const std::string& field) {
  const std::string& s = f.text;
  if (s.empty()) throw InputError(file, line, f.column, field, "empty field, expected an integer");
  const char* begin = s.data();
  const char* end = s.data() + s.size();
  if (*begin == '+' && begin + 1 < end) ++begin;
  long long value = 0;
  const auto [ptr, ec] = std::from_chars(begin, end, value);
  if (ec != std::errc() || ptr != end)
    throw InputError(file, line, f.column, field, fmt::format("'{}' is not an integer", s));
  return value;
}

// Resolution of a printed decimal number: 10^-(digits after the point); 0
// (taken as exact) when written in exponent form or without a point, which
// exporters that trim trailing zeros do for whole values.
double printed_resolution(std::string_view s) {
  if (s.find_first_of("eE") != std::string_view::npos) return 0.0;
  const std::size_t dot = s.find('.');
  if (dot == std::string_view::npos) return 0.0;
  const std::size_t digits = s.size() - dot - 1;
  return std::pow(10.0, -static_cast<double>(digits));
}

// A data row whose field count differs from the header's: names the first
// missing column, or the first extra field.
[[noreturn]] void row_length_error(const std::string& file, const Line& line, const std::vector<Field>& fields,
                                   const std::vector<Field>& header, int header_line) {
  const std::string reason = fmt::format("{} fields, the column header (line {}) has {}", fields.size(), header_line,
                                         header.size());
  if (fields.size() < header.size())
    throw InputError(file, line.number, static_cast<int>(line.text.size()) + 1, header[fields.size()].text,
                     reason + fmt::format(": '{}' is missing", header[fields.size()].text));
  throw InputError(file, line.number, fields[header.size()].column, "", reason);
}

// Column name -> field index, checking for duplicates, unknown (unless
// allowed) and missing columns.
std::map<std::string, int> header_columns(const std::string& file, const Line& line,
                                          const std::vector<Field>& fields,
                                          const std::vector<std::string>& required, bool allow_unknown) {
  std::map<std::string, int> index;
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const Field& f = fields[i];
    const bool known = std::find(required.begin(), required.end(), f.text) != required.end();
    if (!known) {
      if (allow_unknown) continue;
      throw InputError(file, line.number, f.column, f.text,
                       fmt::format("unknown column '{}' (expected {})", f.text, fmt::join(required, ",")));
    }
    if (!index.emplace(f.text, static_cast<int>(i)).second)
      throw InputError(file, line.number, f.column, f.text, fmt::format("duplicate column '{}'", f.text));
  }
  for (const std::string& name : required) {
    if (!index.count(name))
      throw InputError(file, line.number, 0, name,
                       fmt::format("missing column '{}' (expected {})", name, fmt::join(required, ",")));
  }
  return index;
}

// Rounding slack of the difference of two printed times with resolutions
// ra and rb: none when the period is a whole number of the coarser
// resolution (the rounding error is then the same on every sample of a
// uniform grid), else up to half of each.
double rounding_slack(double period, double ra, double rb) {
  const double r = std::max(ra, rb);
  if (r == 0.0) return 0.0;
  const double q = period / r;
  if (q >= 1.0 - 1e-9 && std::abs(q - std::round(q)) < 1e-6 * q) return 0.0;
  return 0.5 * (ra + rb);
}

// Time column checks shared by both force layouts: every step 1 / rate
// within a quarter sample, and no sample further than half a sample from
// the uniform grid through the first (both plus the printing's rounding).
void check_uniform_time(const std::string& file, const std::vector<double>& t, const std::vector<double>& resolution,
                        const std::vector<int>& lines, const std::vector<int>& columns, const std::string& field,
                        double rate_hz) {
  const double period = 1.0 / rate_hz;
  const double eps = 1e-6 * period;
  for (std::size_t i = 1; i < t.size(); ++i) {
    const double step = t[i] - t[i - 1];
    if (std::abs(step - period) > 0.25 * period + rounding_slack(period, resolution[i], resolution[i - 1]) + eps)
      throw InputError(file, lines[i], columns[i], field,
                       fmt::format("time step {:.6g} s from the previous row, expected {:.6g} s at {} Hz "
                                   "(non-uniform time steps or missing samples)",
                                   step, period, rate_hz));
    const double drift = t[i] - t[0] - static_cast<double>(i) * period;
    if (std::abs(drift) > 0.5 * period + rounding_slack(period, resolution[i], resolution[0]) + eps)
      throw InputError(file, lines[i], columns[i], field,
                       fmt::format("time {:.6g} s is {:.3g} samples off the uniform {} Hz grid from the first row "
                                   "(non-uniform time steps or missing samples)",
                                   t[i], drift / period, rate_hz));
  }
}

// ---------------------------------------------------------------------------
// session.toml
// ---------------------------------------------------------------------------

// Manifests written like the spec's own example put several key/values on
// one line separated by ';' (`name = "carpet";  thickness_m = 0.005`), which
// TOML does not allow. ';' is never valid TOML outside a string or a
// comment, so splitting such a line into one line per key/value changes the
// meaning of no valid file. A line is split only when that is unambiguous:
// it starts outside any multi-line string or array, every ';' on it is
// outside strings, comments and brackets, and every piece is `key = ...`
// (the last may be blank or a comment: a trailing ';'). Anything else is
// left as it is, for toml++ to report at its own position.
//
// `origins` maps each line of the rewritten text back to the file: its
// line, and the code points of the original line before the piece (toml++
// counts columns in code points), so every error names the file's own line
// and column.
struct TomlLineOrigin {
  int line = 0;           // 1-based line of the file
  int column_offset = 0;  // added to a rewritten column
};

struct SplitToml {
  std::string text;
  std::vector<TomlLineOrigin> origins;  // [rewritten line - 1]

  // The file's (line, column) of a rewritten position; column 0 stays 0.
  std::pair<int, int> original(int line, int column) const {
    if (line <= 0 || origins.empty()) return {line, column};
    if (line > static_cast<int>(origins.size()))  // past the last line (an error at the end of the file)
      return {origins.back().line + (line - static_cast<int>(origins.size())), column};
    const TomlLineOrigin& o = origins[static_cast<std::size_t>(line - 1)];
    return {o.line, column > 0 ? column + o.column_offset : 0};
  }
};

int code_points(std::string_view s) {
  return static_cast<int>(
      std::count_if(s.begin(), s.end(), [](char c) { return (static_cast<unsigned char>(c) & 0xC0) != 0x80; }));
}

bool bare_key_char(char c) {
  return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-';
}

// `key = ...` with a bare, quoted or dotted key.
bool starts_with_key_value(std::string_view s) {
  std::size_t i = 0;
  auto skip_blanks = [&] {
    while (i < s.size() && is_blank(s[i])) ++i;
  };
  skip_blanks();
  while (true) {
    if (i >= s.size()) return false;
    if (s[i] == '"') {
      for (++i; i < s.size() && s[i] != '"'; ++i)
        if (s[i] == '\\') ++i;
      if (i >= s.size()) return false;
      ++i;
    } else if (s[i] == '\'') {
      const std::size_t close = s.find('\'', i + 1);
      if (close == std::string_view::npos) return false;
      i = close + 1;
    } else {
      const std::size_t start = i;
      while (i < s.size() && bare_key_char(s[i])) ++i;
      if (i == start) return false;
    }
    skip_blanks();
    if (i < s.size() && s[i] == '.') {
      ++i;
      skip_blanks();
      continue;
    }
    return i < s.size() && s[i] == '=';
  }
}

bool blank_or_comment(std::string_view s) {
  s = trim(s);
  return s.empty() || s.front() == '#';
}

SplitToml split_semicolon_lines(std::string_view text) {
  enum class State { Normal, MultiBasic, MultiLiteral };
  State state = State::Normal;
  int depth = 0;  // open '[' and '{' outside strings and comments
  SplitToml out;
  out.text.reserve(text.size() + 64);
  std::size_t pos = 0;
  for (int number = 1;; ++number) {
    const std::size_t nl = text.find('\n', pos);
    const bool last_line = nl == std::string_view::npos;
    std::string_view line = text.substr(pos, (last_line ? text.size() : nl) - pos);
    std::string_view eol = last_line ? "" : "\n";
    if (!line.empty() && line.back() == '\r') {
      line.remove_suffix(1);
      eol = last_line ? "\r" : "\r\n";
    }
    pos = last_line ? text.size() : nl + 1;

    const bool starts_top = state == State::Normal && depth == 0;
    std::vector<std::size_t> semis;
    for (std::size_t i = 0; i < line.size();) {
      const char c = line[i];
      if (state != State::Normal) {
        const char quote = state == State::MultiBasic ? '"' : '\'';
        if (state == State::MultiBasic && c == '\\') {
          i += 2;
        } else if (c == quote) {
          std::size_t run = 0;
          while (i + run < line.size() && line[i + run] == quote) ++run;
          if (run >= 3) state = State::Normal;
          i += run;
        } else {
          ++i;
        }
        continue;
      }
      if (c == '#') break;
      if (c == '"' || c == '\'') {
        if (line.substr(i, 3) == (c == '"' ? std::string_view("\"\"\"") : std::string_view("'''"))) {
          state = c == '"' ? State::MultiBasic : State::MultiLiteral;
          i += 3;
          continue;
        }
        for (++i; i < line.size() && line[i] != c; ++i)
          if (c == '"' && line[i] == '\\') ++i;
        ++i;
        continue;
      }
      if (c == '[' || c == '{') ++depth;
      if ((c == ']' || c == '}') && depth > 0) --depth;
      if (c == ';' && depth == 0) semis.push_back(i);
      ++i;
    }

    bool split = starts_top && !semis.empty();
    std::vector<std::size_t> starts;
    if (split) {
      starts.push_back(0);
      for (const std::size_t s : semis) starts.push_back(s + 1);
      for (std::size_t k = 0; k < starts.size() && split; ++k) {
        const std::size_t stop = k + 1 < starts.size() ? semis[k] : line.size();
        std::string_view piece = line.substr(starts[k], stop - starts[k]);
        if (number == 1 && k == 0 && piece.substr(0, 3) == "\xEF\xBB\xBF") piece.remove_prefix(3);  // UTF-8 BOM
        split = starts_with_key_value(piece) || (k > 0 && k + 1 == starts.size() && blank_or_comment(piece));
      }
    }
    if (split) {
      for (std::size_t k = 0; k < starts.size(); ++k) {
        const std::size_t stop = k + 1 < starts.size() ? semis[k] : line.size();
        out.text += line.substr(starts[k], stop - starts[k]);
        out.text += k + 1 < starts.size() ? std::string_view("\n") : eol;
        out.origins.push_back({number, code_points(line.substr(0, starts[k]))});
      }
    } else {
      out.text += line;
      out.text += eol;
      out.origins.push_back({number, 0});
    }
    if (last_line) break;
  }
  return out;
}

enum class Check { Positive, NonNegative, Finite, Fraction };

std::string type_name(const toml::node& node) {
  switch (node.type()) {
    case toml::node_type::table: return "a table";
    case toml::node_type::array: return "an array";
    case toml::node_type::string: return "a string";
    case toml::node_type::integer: return "an integer";
    case toml::node_type::floating_point: return "a float";
    case toml::node_type::boolean: return "a boolean";
    case toml::node_type::date: return "a date";
    case toml::node_type::time: return "a time";
    case toml::node_type::date_time: return "a date-time";
    default: return "nothing";
  }
}

class ManifestReader {
 public:
  explicit ManifestReader(std::string file) : file_(std::move(file)) {}

  Manifest read() {
    require_file(file_);
    std::string raw;
    {
      std::ifstream in(file_, std::ios::binary);
      if (!in) throw InputError(file_, 0, 0, "", "cannot open");
      std::ostringstream text;
      text << in.rdbuf();
      if (in.bad()) throw InputError(file_, 0, 0, "", "cannot read");
      raw = text.str();
    }
    lines_ = split_semicolon_lines(raw);
    toml::table root;
    try {
      root = toml::parse(lines_.text, file_);
    } catch (const toml::parse_error& e) {
      fail(e.source(), "", std::string(e.description()));
    }
    check_keys(root, "", {"session", "impactor", "mat", "video", "forceplate", "trial"});
    Manifest m;

    if (const toml::table* t = table(root, "session", false)) {
      check_keys(*t, "session", {"name", "gravity_m_s2"});
      m.name = string(*t, "session", "name", false).value_or("");
      m.gravity_m_s2 = number(*t, "session", "gravity_m_s2", Check::Positive, false).value_or(9.81);
    }

    const toml::table& video = *table(root, "video", true);
    check_keys(video, "video",
               {"cameras", "frame_rate_hz", "points", "trigger_frame", "image_origin", "image_height_px"});
    m.video.cameras = names(video, "video", "cameras", true);
    for (std::size_t i = 0; i < m.video.cameras.size(); ++i) {
      const std::string& cam = m.video.cameras[i];
      if (cam.find_first_of("/\\") != std::string::npos || cam == "." || cam == "..")
        fail(*video.get("cameras")->as_array()->get(i), fmt::format("video.cameras[{}]", i),
             fmt::format("camera name '{}' names calibration/{}.csv: it may not contain '/' or '\\'", cam, cam));
    }
    m.video.frame_rate_hz = *number(video, "video", "frame_rate_hz", Check::Positive, true);
    m.video.points = names(video, "video", "points", true);
    m.video.trigger_frame = static_cast<int>(*integer(video, "video", "trigger_frame", 0, true));
    const std::optional<std::string> origin = string(video, "video", "image_origin", false);
    m.video.image_height_px = number(video, "video", "image_height_px", Check::Positive, false);
    if (origin) {
      if (*origin == "top-left") {
        m.video.image_origin = ImageOrigin::TopLeft;
      } else if (*origin == "bottom-left") {
        m.video.image_origin = ImageOrigin::BottomLeft;
        if (!m.video.image_height_px)
          fail(*video.get("image_origin"), "video.image_height_px",
               "image_origin = \"bottom-left\" needs video.image_height_px");
      } else {
        fail(*video.get("image_origin"), "video.image_origin",
             fmt::format("\"{}\" is not an image origin (expected \"top-left\" or \"bottom-left\")", *origin));
      }
    }

    const toml::table& imp = *table(root, "impactor", true);
    check_keys(imp, "impactor", {"mass_kg", "footprint_m", "base_markers", "base_marker_height_m"});
    m.impactor.mass_kg = *number(imp, "impactor", "mass_kg", Check::Positive, true);
    m.impactor.footprint_m = footprint(imp);
    m.impactor.base_markers = markers(imp, "impactor", "base_markers", m.video.points, true);
    m.impactor.base_marker_height_m = number(imp, "impactor", "base_marker_height_m", Check::Finite, false).value_or(0.0);

    const toml::table& mat = *table(root, "mat", true);
    check_keys(mat, "mat", {"length_m", "width_m", "surface_markers", "layers"});
    m.mat.length_m = *number(mat, "mat", "length_m", Check::Positive, true);
    m.mat.width_m = *number(mat, "mat", "width_m", Check::Positive, true);
    m.mat.surface_markers = markers(mat, "mat", "surface_markers", m.video.points, false);
    const toml::array& layers = table_array(mat, "mat", "layers");
    for (std::size_t i = 0; i < layers.size(); ++i) {
      const std::string prefix = fmt::format("mat.layers[{}]", i);
      const toml::table& layer = *layers.get(i)->as_table();
      check_keys(layer, prefix, {"name", "thickness_m", "mass_kg"});
      LayerSpec spec;
      spec.name = *string(layer, prefix, "name", true);
      spec.thickness_m = *number(layer, prefix, "thickness_m", Check::Positive, true);
      spec.mass_kg = *number(layer, prefix, "mass_kg", Check::NonNegative, true);
      m.mat.layers.push_back(spec);
    }

    const toml::table& plate = *table(root, "forceplate", true);
    check_keys(plate, "forceplate",
               {"model", "sample_rate_hz", "trigger_threshold_n", "pretrigger_fraction", "a_m", "b_m", "az0_m",
                "mat_top_z_m", "plate"});
    m.forceplate.model = string(plate, "forceplate", "model", false).value_or("");
    m.forceplate.sample_rate_hz = *number(plate, "forceplate", "sample_rate_hz", Check::Positive, true);
    m.forceplate.trigger_threshold_n = *number(plate, "forceplate", "trigger_threshold_n", Check::Positive, true);
    m.forceplate.pretrigger_fraction = *number(plate, "forceplate", "pretrigger_fraction", Check::Fraction, true);
    m.forceplate.a_m = *number(plate, "forceplate", "a_m", Check::Positive, true);
    m.forceplate.b_m = *number(plate, "forceplate", "b_m", Check::Positive, true);
    m.forceplate.az0_m = *number(plate, "forceplate", "az0_m", Check::Finite, true);
    m.forceplate.mat_top_z_m = *number(plate, "forceplate", "mat_top_z_m", Check::Finite, true);
    m.forceplate.plate = static_cast<int>(integer(plate, "forceplate", "plate", 1, false).value_or(1));

    const toml::array& trials = table_array(root, "", "trial");
    std::map<std::string, std::size_t> seen;
    for (std::size_t i = 0; i < trials.size(); ++i) {
      const std::string prefix = fmt::format("trial[{}]", i);
      const toml::table& t = *trials.get(i)->as_table();
      check_keys(t, prefix, {"id", "dir"});
      TrialSpec spec;
      spec.id = *string(t, prefix, "id", true);
      spec.dir = *string(t, prefix, "dir", true);
      if (spec.id.empty()) fail(*t.get("id"), prefix + ".id", "empty trial id");
      if (spec.dir.empty()) fail(*t.get("dir"), prefix + ".dir", "empty trial dir");
      if (fs::path(spec.dir).is_absolute())
        fail(*t.get("dir"), prefix + ".dir",
             fmt::format("\"{}\" is absolute; trial dirs are relative to the session folder", spec.dir));
      const auto [it, inserted] = seen.emplace(spec.id, i);
      if (!inserted)
        fail(*t.get("id"), prefix + ".id",
             fmt::format("duplicate trial id \"{}\" (also trial[{}])", spec.id, it->second));
      m.trials.push_back(spec);
    }
    return m;
  }

 private:
  // Every position goes through lines_, so that it names the file's own
  // line and column where a ';'-separated line was split.
  [[noreturn]] void fail(const toml::source_region& where, const std::string& field, const std::string& reason) const {
    const auto [line, column] =
        lines_.original(static_cast<int>(where.begin.line), static_cast<int>(where.begin.column));
    throw InputError(file_, line, column, field, reason);
  }
  [[noreturn]] void fail(const toml::node& node, const std::string& field, const std::string& reason) const {
    fail(node.source(), field, reason);
  }
  static std::string dotted(const std::string& prefix, std::string_view key) {
    return prefix.empty() ? std::string(key) : prefix + "." + std::string(key);
  }

  void check_keys(const toml::table& t, const std::string& prefix, std::initializer_list<std::string_view> allowed) const {
    for (auto&& [key, value] : t) {
      if (std::find(allowed.begin(), allowed.end(), key.str()) == allowed.end()) {
        fail(key.source(), dotted(prefix, key.str()),
             fmt::format("unknown key '{}' (allowed here: {})", dotted(prefix, key.str()), fmt::join(allowed, ", ")));
      }
    }
  }

  // A missing key: line of the enclosing table's header (0 at the top level).
  [[noreturn]] void missing(const toml::table& t, const std::string& prefix, std::string_view key) const {
    const std::string field = dotted(prefix, key);
    if (prefix.empty()) throw InputError(file_, 0, 0, field, fmt::format("missing required key '{}'", field));
    fail(t.source(), field, fmt::format("missing required key '{}'", field));
  }

  const toml::table* table(const toml::table& root, std::string_view key, bool required) const {
    const toml::node* node = root.get(key);
    if (!node) {
      if (required) throw InputError(file_, 0, 0, std::string(key), fmt::format("missing required table [{}]", key));
      return nullptr;
    }
    if (!node->is_table())
      fail(*node, std::string(key), fmt::format("wrong type: expected a table, found {}", type_name(*node)));
    return node->as_table();
  }

  const toml::array& table_array(const toml::table& t, const std::string& prefix, std::string_view key) const {
    const std::string field = dotted(prefix, key);
    const toml::node* node = t.get(key);
    if (!node) missing(t, prefix, key);
    const toml::array* arr = node->as_array();
    if (!arr || !arr->is_array_of_tables() || arr->empty())
      fail(*node, field,
           fmt::format("wrong type: expected one or more [[{}]] tables, found {}", field,
                       arr && arr->empty() ? "an empty array" : type_name(*node)));
    return *arr;
  }

  std::optional<double> number(const toml::table& t, const std::string& prefix, std::string_view key, Check check,
                               bool required) const {
    const toml::node* node = t.get(key);
    if (!node) {
      if (required) missing(t, prefix, key);
      return std::nullopt;
    }
    return checked_number(*node, dotted(prefix, key), check);
  }

  double checked_number(const toml::node& node, const std::string& field, Check check) const {
    if (!node.is_number())
      fail(node, field, fmt::format("wrong type: expected a number, found {}", type_name(node)));
    const double v = *node.value<double>();
    if (!std::isfinite(v)) fail(node, field, "not a finite number");
    switch (check) {
      case Check::Positive:
        if (!(v > 0.0)) fail(node, field, fmt::format("must be positive, is {}", v));
        break;
      case Check::NonNegative:
        if (v < 0.0) fail(node, field, fmt::format("must not be negative, is {}", v));
        break;
      case Check::Fraction:
        if (v < 0.0 || v >= 1.0) fail(node, field, fmt::format("must be in [0, 1), is {}", v));
        break;
      case Check::Finite: break;
    }
    return v;
  }

  std::optional<long long> integer(const toml::table& t, const std::string& prefix, std::string_view key,
                                   long long min, bool required) const {
    const toml::node* node = t.get(key);
    if (!node) {
      if (required) missing(t, prefix, key);
      return std::nullopt;
    }
    const std::string field = dotted(prefix, key);
    if (!node->is_integer())
      fail(*node, field, fmt::format("wrong type: expected an integer, found {}", type_name(*node)));
    const long long v = node->as_integer()->get();
    if (v < min || v > std::numeric_limits<int>::max())
      fail(*node, field, fmt::format("must be an integer >= {}, is {}", min, v));
    return v;
  }

  std::optional<std::string> string(const toml::table& t, const std::string& prefix, std::string_view key,
                                    bool required) const {
    const toml::node* node = t.get(key);
    if (!node) {
      if (required) missing(t, prefix, key);
      return std::nullopt;
    }
    if (!node->is_string())
      fail(*node, dotted(prefix, key), fmt::format("wrong type: expected a string, found {}", type_name(*node)));
    return node->as_string()->get();
  }

  // A list of unique non-empty names (non-empty list when `non_empty`).
  std::vector<std::string> names(const toml::table& t, const std::string& prefix, std::string_view key,
                                 bool non_empty) const {
    const toml::node* node = t.get(key);
    if (!node) missing(t, prefix, key);
    const std::string field = dotted(prefix, key);
    const toml::array* arr = node->as_array();
    if (!arr) fail(*node, field, fmt::format("wrong type: expected an array of strings, found {}", type_name(*node)));
    if (non_empty && arr->empty()) fail(*node, field, "must not be empty");
    std::vector<std::string> out;
    for (std::size_t i = 0; i < arr->size(); ++i) {
      const toml::node& el = *arr->get(i);
      const std::string el_field = fmt::format("{}[{}]", field, i);
      if (!el.is_string())
        fail(el, el_field, fmt::format("wrong type: expected a string, found {}", type_name(el)));
      const std::string& name = el.as_string()->get();
      if (name.empty()) fail(el, el_field, "empty name");
      if (std::find(out.begin(), out.end(), name) != out.end())
        fail(el, el_field, fmt::format("duplicate name \"{}\"", name));
      out.push_back(name);
    }
    return out;
  }

  std::vector<std::string> markers(const toml::table& t, const std::string& prefix, std::string_view key,
                                   const std::vector<std::string>& points, bool non_empty) const {
    std::vector<std::string> out = names(t, prefix, key, non_empty);
    const toml::array& arr = *t.get(key)->as_array();
    for (std::size_t i = 0; i < out.size(); ++i) {
      if (std::find(points.begin(), points.end(), out[i]) == points.end())
        fail(*arr.get(i), fmt::format("{}[{}]", dotted(prefix, key), i),
             fmt::format("\"{}\" is not one of video.points", out[i]));
    }
    return out;
  }

  Eigen::Vector2d footprint(const toml::table& imp) const {
    const toml::node* node = imp.get("footprint_m");
    if (!node) missing(imp, "impactor", "footprint_m");
    const toml::array* arr = node->as_array();
    if (!arr || arr->size() != 2)
      fail(*node, "impactor.footprint_m",
           fmt::format("wrong type: expected an array of two numbers [length, width], found {}",
                       arr ? fmt::format("{} elements", arr->size()) : type_name(*node)));
    return {checked_number(*arr->get(0), "impactor.footprint_m[0]", Check::Positive),
            checked_number(*arr->get(1), "impactor.footprint_m[1]", Check::Positive)};
  }

  std::string file_;
  SplitToml lines_;
};

// ---------------------------------------------------------------------------
// Writing
// ---------------------------------------------------------------------------

// Writes `content` to a temporary file beside `path`, then renames it over
// `path`, so that a reader never sees a partial file.
void write_whole(const std::string& path, const std::string& content) {
  static std::atomic<unsigned> counter{0};
  const fs::path target(path);
  fs::path temp = target;
  temp += fmt::format(".tmp{}-{}", static_cast<long>(::getpid()), counter++);
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(fmt::format("cannot write {}: cannot create {}", path, temp.string()));
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    out.close();
    if (!out) {
      std::error_code ec;
      fs::remove(temp, ec);
      throw Error(fmt::format("cannot write {}: write failed", path));
    }
  }
  std::error_code ec;
  fs::rename(temp, target, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(temp, ignored);
    throw Error(fmt::format("cannot write {}: {}", path, ec.message()));
  }
}

// Shortest text that reads back to the same double, always with a decimal
// point or exponent (a TOML float).
std::string toml_float(double v) {
  std::string s = fmt::format("{}", v);
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";  // 'n': nan, inf
  return s;
}

std::string toml_string(std::string_view s) {
  std::string out = "\"";
  for (const char c : s) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\t': out += "\\t"; break;
      case '\r': out += "\\r"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f)
          out += fmt::format("\\u{:04X}", static_cast<unsigned>(static_cast<unsigned char>(c)));
        else
          out += c;
    }
  }
  return out + "\"";
}

std::string toml_strings(const std::vector<std::string>& v) {
  std::vector<std::string> quoted;
  for (const std::string& s : v) quoted.push_back(toml_string(s));
  return fmt::format("[{}]", fmt::join(quoted, ", "));
}

std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\t\r\n") == std::string::npos && trim(s) == s) return s;
  std::string out = "\"";
  for (const char c : s) {
    if (c == '"') out += '"';
    out += c;
  }
  return out + "\"";
}

std::string pixel(double v) { return std::isnan(v) ? std::string("NaN") : fmt::format("{:.6f}", v); }

std::string xypts_column(XyptsLayout layout, int point, const std::string& name, int camera, int axis) {
  switch (layout) {
    case XyptsLayout::Dltdv83: return fmt::format("pt{}_cam{}_{}", point + 1, camera + 1, axis == 0 ? "X" : "Y");
    case XyptsLayout::Dltdv84: return fmt::format("{}_cam{}_{}", name, camera + 1, axis == 0 ? "U" : "V");
    case XyptsLayout::Argus: return fmt::format("{}_cam_{}_{}", name, camera + 1, axis == 0 ? "x" : "y");
  }
  return {};
}

constexpr std::array<const char*, 8> kEightChannels = {"Fx12", "Fx34", "Fy14", "Fy23", "Fz1", "Fz2", "Fz3", "Fz4"};
constexpr std::array<const char*, 8> kResultants = {"Fx", "Fy", "Fz", "Mx", "My", "Mz", "Ax", "Ay"};

// force.txt and force.c3d: capture/force_kistler.cpp, force_bioware.cpp, force_c3d.cpp.

}  // namespace

// ---------------------------------------------------------------------------
// Readers
// ---------------------------------------------------------------------------

Manifest read_manifest(const std::string& path) { return ManifestReader(path).read(); }

std::vector<CalibrationMarker> read_frame_csv(const std::string& path) {
  const std::vector<Line> lines = read_lines(path);
  if (lines.empty() || blank_line(lines[0].text))
    throw InputError(path, 1, 0, "", "expected the header id,x_m,y_m,z_m,role on line 1");
  const std::vector<Field> header = split_fields(lines[0].text, ',');
  const std::map<std::string, int> col = header_columns(path, lines[0], header, {"id", "x_m", "y_m", "z_m", "role"}, false);
  std::vector<CalibrationMarker> out;
  std::map<std::string, int> seen;
  for (std::size_t i = 1; i < lines.size(); ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) continue;
    const std::vector<Field> f = split_fields(l.text, ',');
    if (f.size() != header.size()) row_length_error(path, l, f, header, lines[0].number);
    CalibrationMarker m;
    const Field& id = f[col.at("id")];
    m.id = id.text;
    if (m.id.empty()) throw InputError(path, l.number, id.column, "id", "empty id");
    if (const auto [it, inserted] = seen.emplace(m.id, l.number); !inserted)
      throw InputError(path, l.number, id.column, "id",
                       fmt::format("duplicate id '{}' (first on line {})", m.id, it->second));
    for (int k = 0; k < 3; ++k) {
      const char* name = k == 0 ? "x_m" : k == 1 ? "y_m" : "z_m";
      m.lab_m[k] = parse_number(path, l.number, f[col.at(name)], name, false);
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
  const std::vector<Field> header = split_fields(lines[0].text, ',');
  const std::map<std::string, int> col = header_columns(path, lines[0], header, {"id", "u_px", "v_px"}, false);
  std::set<std::string> known;
  for (const CalibrationMarker& m : frame) known.insert(m.id);
  CalibrationImage image;
  image.camera = camera;
  std::map<std::string, int> seen;
  for (std::size_t i = 1; i < lines.size(); ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) continue;
    const std::vector<Field> f = split_fields(l.text, ',');
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
    obs.image_px.x() = parse_number(path, l.number, f[col.at("u_px")], "u_px", false);
    obs.image_px.y() = parse_number(path, l.number, f[col.at("v_px")], "v_px", false);
    image.observations.push_back(obs);
  }
  return image;
}

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

int trigger_sample_from_fraction(double pretrigger_fraction, int n_samples) {
  return static_cast<int>(std::lround(pretrigger_fraction * static_cast<double>(n_samples)));
}

ForceRecord read_force(const std::string& path, const ForcePlateSpec& plate) {
  const std::string ext = fs::path(path).extension().string();
  if (iequals(ext, ".c3d")) return read_force_c3d(path, plate);
  const std::vector<detail::Line> lines = detail::read_text_lines(path);
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const std::vector<detail::Field> f = detail::split_fields(lines[i].text, '\t');
    const std::string& first = f[0].text;
    if (iequals(first, "Time(s)") || iequals(first, "Time (s)")) return detail::read_eight_channel(path, lines, i, plate);
    if (iequals_prefix(first, "abs time")) return detail::read_bioware(path, lines, i, plate);
  }
  throw InputError(path, 0, 0, "",
                   "no column header: expected a line beginning 'Time(s)' (Kistler eight-channel) or 'abs time' "
                   "(BioWare)");
}

Session read_session(const std::string& root) {
  const fs::path dir(root);
  Session s;
  s.root = root;
  s.manifest = read_manifest((dir / "session.toml").string());
  s.frame = read_frame_csv((dir / "calibration" / "frame.csv").string());
  for (const std::string& camera : s.manifest.video.cameras)
    s.images.push_back(read_camera_csv((dir / "calibration" / (camera + ".csv")).string(), camera, s.frame));
  for (const TrialSpec& spec : s.manifest.trials) {
    TrialData trial;
    trial.spec = spec;
    trial.tracks = read_xypts((dir / spec.dir / "xypts.csv").string(), s.manifest.video);
    trial.force = read_force(find_force_file((dir / spec.dir).string()), s.manifest.forceplate);
    s.trials.push_back(std::move(trial));
  }
  return s;
}

// ---------------------------------------------------------------------------
// Writers
// ---------------------------------------------------------------------------

void write_manifest(const std::string& path, const Manifest& m) {
  std::string s;
  auto out = std::back_inserter(s);
  fmt::format_to(out, "# dropfit session manifest (shared/spec/session-format.md)\n\n");
  fmt::format_to(out, "[session]\nname = {}\ngravity_m_s2 = {}\n\n", toml_string(m.name), toml_float(m.gravity_m_s2));
  fmt::format_to(out, "[impactor]\nmass_kg = {}\nfootprint_m = [{}, {}]\nbase_markers = {}\nbase_marker_height_m = {}\n\n",
                 toml_float(m.impactor.mass_kg), toml_float(m.impactor.footprint_m.x()),
                 toml_float(m.impactor.footprint_m.y()), toml_strings(m.impactor.base_markers),
                 toml_float(m.impactor.base_marker_height_m));
  fmt::format_to(out, "[mat]\nlength_m = {}\nwidth_m = {}\nsurface_markers = {}\n\n", toml_float(m.mat.length_m),
                 toml_float(m.mat.width_m), toml_strings(m.mat.surface_markers));
  for (const LayerSpec& layer : m.mat.layers)
    fmt::format_to(out, "[[mat.layers]]\nname = {}\nthickness_m = {}\nmass_kg = {}\n\n", toml_string(layer.name),
                   toml_float(layer.thickness_m), toml_float(layer.mass_kg));
  fmt::format_to(out, "[video]\ncameras = {}\nframe_rate_hz = {}\npoints = {}\ntrigger_frame = {}\nimage_origin = {}\n",
                 toml_strings(m.video.cameras), toml_float(m.video.frame_rate_hz), toml_strings(m.video.points),
                 m.video.trigger_frame,
                 m.video.image_origin == ImageOrigin::BottomLeft ? "\"bottom-left\"" : "\"top-left\"");
  if (m.video.image_height_px) fmt::format_to(out, "image_height_px = {}\n", toml_float(*m.video.image_height_px));
  const ForcePlateSpec& p = m.forceplate;
  fmt::format_to(out,
                 "\n[forceplate]\nmodel = {}\nsample_rate_hz = {}\ntrigger_threshold_n = {}\npretrigger_fraction = {}\n"
                 "a_m = {}\nb_m = {}\naz0_m = {}\nmat_top_z_m = {}\n",
                 toml_string(p.model), toml_float(p.sample_rate_hz), toml_float(p.trigger_threshold_n),
                 toml_float(p.pretrigger_fraction), toml_float(p.a_m), toml_float(p.b_m), toml_float(p.az0_m),
                 toml_float(p.mat_top_z_m));
  if (p.plate != 1) fmt::format_to(out, "plate = {}\n", p.plate);
  for (const TrialSpec& t : m.trials)
    fmt::format_to(out, "\n[[trial]]\nid = {}\ndir = {}\n", toml_string(t.id), toml_string(t.dir));
  write_whole(path, s);
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

void write_force(const std::string& path, const ForceRecord& record, const std::string& device) {
  const Eigen::Index n = record.data.rows();
  if (record.data.cols() != 8 || record.t_s.size() != n || n == 0)
    throw Error(fmt::format("write_force {}: expected n x 8 data and n times (n > 0), got {} x {} and {}", path, n,
                            record.data.cols(), record.t_s.size()));
  if (!(record.sample_rate_hz > 0.0)) throw Error(fmt::format("write_force {}: sample rate must be positive", path));
  std::string s;
  auto out = std::back_inserter(s);
  if (record.layout == ForceLayout::EightChannel) {
    if (record.pretrigger_samples < 0 || record.pretrigger_samples >= n)
      throw Error(fmt::format("write_force {}: pretrigger_samples {} outside the record", path, record.pretrigger_samples));
    if (std::abs(record.t_s(record.pretrigger_samples)) > 0.5 / record.sample_rate_hz)
      throw Error(fmt::format("write_force {}: t_s at the trigger sample ({}) must be 0", path,
                              record.pretrigger_samples));
    fmt::format_to(out, "Device\t{}\nSample rate\t{}\nSamples\t{}\nPretrigger samples\t{}\n",
                   device.empty() ? "unknown" : device, record.sample_rate_hz, n, record.pretrigger_samples);
    if (!record.trigger.empty()) fmt::format_to(out, "Trigger\t{}\n", record.trigger);
    fmt::format_to(out, "\nTime(s)\t{}\n", fmt::join(kEightChannels, "\t"));
    for (Eigen::Index i = 0; i < n; ++i) {
      fmt::format_to(out, "{:.6f}", record.t_s(i));
      for (int c = 0; c < 8; ++c) fmt::format_to(out, "\t{:.6f}", record.data(i, c));
      s += '\n';
    }
  } else {
    fmt::format_to(out, "BioWare export{}\nRate (Hz):\t{}\nSamples:\t{}\n\n", device.empty() ? "" : " " + device,
                   record.sample_rate_hz, n);
    fmt::format_to(out, "abs time (s)\t{}\ns\tN\tN\tN\tN.m\tN.m\tN.m\tmm\tmm\n", fmt::join(kResultants, "\t"));
    for (Eigen::Index i = 0; i < n; ++i) {
      fmt::format_to(out, "{:.6f}", record.t_s(i) - record.t_s(0));
      for (int c = 0; c < 8; ++c) {
        const double v = c >= 6 ? 1e3 * record.data(i, c) : record.data(i, c);
        if (std::isnan(v))
          s += "\tNaN";
        else
          fmt::format_to(out, "\t{:.6f}", v);
      }
      s += '\n';
    }
  }
  write_whole(path, s);
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
    const TrialData& t = session.trials[i];
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
  for (const TrialData& t : session.trials) {
    const fs::path trial_dir = dir / t.spec.dir;
    fs::create_directories(trial_dir, ec);
    if (ec) throw Error(fmt::format("write_session: cannot create {}: {}", trial_dir.string(), ec.message()));
    write_xypts((trial_dir / "xypts.csv").string(), t.tracks, layout, m.video.image_origin,
                flip ? *m.video.image_height_px : 0.0);
    write_force((trial_dir / "force.txt").string(), t.force, m.forceplate.model);
  }
}

}  // namespace dropfit::capture
