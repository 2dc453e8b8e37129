// session.toml: reading (toml++) and writing; see capture/io.h.
#include "capture/io.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>
#include <sstream>
#include <fstream>
#include <string_view>

#include "capture/text_io.h"
#include "core/error.h"
#include <toml++/toml.h>

namespace dropfit::capture {
namespace {

using namespace detail;
namespace fs = std::filesystem;

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
    check_text(raw);
    lines_ = split_semicolon_lines(raw);
    toml::table root;
    try {
      root = toml::parse(lines_.text, file_);
    } catch (const toml::parse_error& e) {
      fail(e.source(), "", std::string(e.description()));
    }
    check_keys(root, "", {"session", "impactor", "mat", "video", "forceplate", "trial", "calibration"});
    Manifest m;
    read_session(root, m);
    read_calibration(root, m);
    read_video(root, m);
    read_impactor(root, m);
    read_mat(root, m);
    read_forceplate(root, m);
    read_trials(root, m);
    return m;
  }

 private:
  // [session]: name and gravity (optional table).
  void read_session(const toml::table& root, Manifest& m) {
    if (const toml::table* t = table(root, "session", false)) {
      check_keys(*t, "session", {"name", "gravity_m_s2", "outside_physical_range"});
      m.name = string(*t, "session", "name", false).value_or("");
      if (t->get("outside_physical_range"))
        m.outside_physical_range = names(*t, "session", "outside_physical_range", false);
      overrides_ = m.outside_physical_range;
      m.gravity_m_s2 = number(*t, "session", "gravity_m_s2", Check::Positive, false).value_or(9.81);
      // Earth's surface gravity is 9.764-9.834 m/s^2 from the equator to the poles.
      plausible(*t, "session", "gravity_m_s2", 9.70, 9.90, "m/s^2 (Earth's surface: 9.76-9.84)");
    }
  }

  // A number the manifest gives must lie within the range a drop-test lab
  // can have (a typo or a unit slip, e.g. grams for kilograms, otherwise
  // flows into every result), unless [session] outside_physical_range names
  // the field. Absent keys are not checked.
  void plausible(const toml::table& t, const std::string& prefix, std::string_view key, double lo, double hi,
                 const std::string& range) const {
    const toml::node* node = t.get(key);
    if (!node || !node->is_number()) return;
    const std::string field = dotted(prefix, key);
    if (std::find(overrides_.begin(), overrides_.end(), field) != overrides_.end()) return;
    const double v = *node->value<double>();
    if (v < lo || v > hi)
      fail(*node, field,
           fmt::format("{} is outside the physical range {}-{} {}; if the value is right, list \"{}\" in "
                       "[session] outside_physical_range",
                       v, lo, hi, range, field));
  }

  // [calibration]: a DLT coefficient file instead of the frame (optional).
  void read_calibration(const toml::table& root, Manifest& m) {
    if (const toml::table* t = table(root, "calibration", false)) {
      check_keys(*t, "calibration", {"dlt_coefficients"});
      m.calibration.dlt_coefficients = string(*t, "calibration", "dlt_coefficients", false).value_or("");
      const toml::node* node = t->get("dlt_coefficients");
      if (node && m.calibration.dlt_coefficients.empty())
        fail(*node, "calibration.dlt_coefficients", "empty file name");
      if (node && fs::path(m.calibration.dlt_coefficients).is_absolute())
        fail(*node, "calibration.dlt_coefficients",
             fmt::format("\"{}\" is absolute; it is relative to the session folder",
                         m.calibration.dlt_coefficients));
    }
  }

  // [video]: cameras, frame rate, points, trigger frame, image origin.
  void read_video(const toml::table& root, Manifest& m) {
    const toml::table& video = *table(root, "video", true);
    check_keys(video, "video",
               {"cameras", "frame_rate_hz", "points", "trigger_frame", "image_origin", "image_height_px"});
    m.video.cameras = names(video, "video", "cameras", true, kMaxCameras);
    for (std::size_t i = 0; i < m.video.cameras.size(); ++i) {
      const std::string& cam = m.video.cameras[i];
      if (cam.find_first_of("/\\") != std::string::npos || cam == "." || cam == "..")
        fail(*video.get("cameras")->as_array()->get(i), fmt::format("video.cameras[{}]", i),
             fmt::format("camera name '{}' names calibration/{}.csv: it may not contain '/' or '\\'", cam, cam));
    }
    m.video.frame_rate_hz = *number(video, "video", "frame_rate_hz", Check::Positive, true);
    plausible(video, "video", "frame_rate_hz", 20.0, 1e6, "Hz");
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
  }

  // [impactor]: mass, footprint and base markers (among video.points).
  void read_impactor(const toml::table& root, Manifest& m) {
    const toml::table& imp = *table(root, "impactor", true);
    check_keys(imp, "impactor", {"mass_kg", "footprint_m", "base_markers", "base_marker_height_m"});
    m.impactor.mass_kg = *number(imp, "impactor", "mass_kg", Check::Positive, true);
    plausible(imp, "impactor", "mass_kg", 1.0, 200.0, "kg");
    plausible(imp, "impactor", "base_marker_height_m", -1.0, 1.0, "m");
    m.impactor.footprint_m = footprint(imp);
    m.impactor.base_markers = markers(imp, "impactor", "base_markers", m.video.points, true);
    m.impactor.base_marker_height_m = number(imp, "impactor", "base_marker_height_m", Check::Finite, false).value_or(0.0);
  }

  // [mat]: size, surface markers and layers.
  void read_mat(const toml::table& root, Manifest& m) {
    const toml::table& mat = *table(root, "mat", true);
    check_keys(mat, "mat", {"length_m", "width_m", "surface_markers", "layers"});
    m.mat.length_m = *number(mat, "mat", "length_m", Check::Positive, true);
    m.mat.width_m = *number(mat, "mat", "width_m", Check::Positive, true);
    plausible(mat, "mat", "length_m", 0.05, 20.0, "m");
    plausible(mat, "mat", "width_m", 0.05, 20.0, "m");
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
      plausible(layer, prefix, "thickness_m", 0.001, 2.0, "m");
      plausible(layer, prefix, "mass_kg", 0.0, 500.0, "kg");
      m.mat.layers.push_back(spec);
    }
  }

  // [forceplate]: rate, trigger, geometry and plate number.
  void read_forceplate(const toml::table& root, Manifest& m) {
    const toml::table& plate = *table(root, "forceplate", true);
    check_keys(plate, "forceplate",
               {"model", "sample_rate_hz", "trigger_threshold_n", "pretrigger_fraction", "a_m", "b_m", "az0_m",
                "mat_top_z_m", "plate", "lowpass_hz", "lowpass_order"});
    m.forceplate.model = string(plate, "forceplate", "model", false).value_or("");
    m.forceplate.sample_rate_hz = *number(plate, "forceplate", "sample_rate_hz", Check::Positive, true);
    m.forceplate.trigger_threshold_n = *number(plate, "forceplate", "trigger_threshold_n", Check::Positive, true);
    m.forceplate.pretrigger_fraction = number(plate, "forceplate", "pretrigger_fraction", Check::Fraction, false);
    m.forceplate.a_m = *number(plate, "forceplate", "a_m", Check::Positive, true);
    m.forceplate.b_m = *number(plate, "forceplate", "b_m", Check::Positive, true);
    m.forceplate.az0_m = *number(plate, "forceplate", "az0_m", Check::Finite, true);
    m.forceplate.mat_top_z_m = *number(plate, "forceplate", "mat_top_z_m", Check::Finite, true);
    m.forceplate.plate = static_cast<int>(integer(plate, "forceplate", "plate", 1, false).value_or(1));
    m.forceplate.lowpass_hz = number(plate, "forceplate", "lowpass_hz", Check::Positive, false).value_or(0.0);
    m.forceplate.lowpass_order =
        static_cast<int>(integer(plate, "forceplate", "lowpass_order", 1, false).value_or(2));
    plausible(plate, "forceplate", "sample_rate_hz", 100.0, 1e6, "Hz");
    plausible(plate, "forceplate", "trigger_threshold_n", 0.1, 5000.0, "N");
    plausible(plate, "forceplate", "a_m", 0.01, 2.0, "m");
    plausible(plate, "forceplate", "b_m", 0.01, 2.0, "m");
    plausible(plate, "forceplate", "az0_m", -0.5, 0.5, "m");
    plausible(plate, "forceplate", "mat_top_z_m", 0.0, 3.0, "m");
    plausible(plate, "forceplate", "lowpass_hz", 1.0, 1e6, "Hz");
    plausible(plate, "forceplate", "lowpass_order", 1.0, 8.0, "");
  }

  // [[trial]]: ids (unique) and folders (relative, one trial each: two
  // trials reading one folder would be one drop counted twice).
  void read_trials(const toml::table& root, Manifest& m) {
    const toml::array& trials = table_array(root, "", "trial");
    std::map<std::string, std::size_t> seen, folders;
    for (std::size_t i = 0; i < trials.size(); ++i) {
      const std::string prefix = fmt::format("trial[{}]", i);
      const toml::table& t = *trials.get(i)->as_table();
      check_keys(t, prefix, {"id", "dir"});
      TrialSpec spec;
      spec.id = *string(t, prefix, "id", true);
      spec.dir = *string(t, prefix, "dir", true);
      if (spec.id.empty()) fail(*t.get("id"), prefix + ".id", "empty trial id");
      if (spec.dir.empty()) fail(*t.get("dir"), prefix + ".dir", "empty trial dir");
      if (const std::string why = trial_id_problem(spec.id); !why.empty()) fail(*t.get("id"), prefix + ".id", why);
      if (const std::string why = trial_dir_problem(spec.dir); !why.empty()) fail(*t.get("dir"), prefix + ".dir", why);
      const auto [it, inserted] = seen.emplace(spec.id, i);
      if (!inserted)
        fail(*t.get("id"), prefix + ".id",
             fmt::format("duplicate trial id \"{}\" (also trial[{}])", spec.id, it->second));
      std::string folder = fs::path(spec.dir).lexically_normal().generic_string();
      while (folder.size() > 1 && folder.back() == '/') folder.pop_back();
      const auto [dir_it, new_dir] = folders.emplace(folder, i);
      if (!new_dir)
        fail(*t.get("dir"), prefix + ".dir",
             fmt::format("trial \"{}\" reads folder \"{}\", as trial[{}] does: each trial is its own recording",
                         spec.id, spec.dir, dir_it->second));
      m.trials.push_back(spec);
    }
  }

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
                                 bool non_empty, std::size_t max_count = kMaxPoints) const {
    const toml::node* node = t.get(key);
    if (!node) missing(t, prefix, key);
    const std::string field = dotted(prefix, key);
    const toml::array* arr = node->as_array();
    if (!arr) fail(*node, field, fmt::format("wrong type: expected an array of strings, found {}", type_name(*node)));
    if (non_empty && arr->empty()) fail(*node, field, "must not be empty");
    if (arr->size() > max_count)
      fail(*node, field, fmt::format("{} names, more than the {} dropfit accepts here", arr->size(), max_count));
    std::vector<std::string> out;
    for (std::size_t i = 0; i < arr->size(); ++i) {
      const toml::node& el = *arr->get(i);
      const std::string el_field = fmt::format("{}[{}]", field, i);
      if (!el.is_string())
        fail(el, el_field, fmt::format("wrong type: expected a string, found {}", type_name(el)));
      const std::string& name = el.as_string()->get();
      if (name.empty()) fail(el, el_field, "empty name");
      if (name.size() > kMaxNameChars)
        fail(el, el_field, fmt::format("a name of {} bytes, more than the {} allowed", name.size(), kMaxNameChars));
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

  // What toml++ must never see: a manifest over 4 MiB, bytes that are not
  // UTF-8, and non-ASCII characters outside strings and comments (TOML
  // allows none there, and toml++ 3.3 reaches undefined behaviour on some of
  // them where the grammar allows whitespace).
  void check_text(std::string_view raw) const {
    constexpr std::size_t kMaxManifestBytes = 4u << 20;
    if (raw.size() > kMaxManifestBytes)
      throw InputError(file_, 0, 0, "",
                       fmt::format("{} bytes, more than the {} bytes a manifest may have", raw.size(),
                                   kMaxManifestBytes));
    if (const auto bad = first_invalid_utf8(raw))
      throw InputError(file_, bad->first, bad->second, "", "not UTF-8 text (an invalid byte sequence starts here)");
    if (raw.substr(0, 3) == "\xEF\xBB\xBF") raw.remove_prefix(3);
    enum class S { Normal, Comment, Basic, Literal, MultiBasic, MultiLiteral };
    S state = S::Normal;
    int line = 1, column = 1;
    for (std::size_t i = 0; i < raw.size(); ++i) {
      const char c = raw[i];
      const auto u = static_cast<unsigned char>(c);
      const bool lead = (u & 0xC0) != 0x80;  // counts one code point
      if (state == S::Normal && u >= 0x80)
        throw InputError(file_, line, column, "",
                         "a non-ASCII character outside a string or comment (TOML allows none there)");
      switch (state) {
        case S::Normal:
          if (c == '#') state = S::Comment;
          else if (raw.substr(i, 3) == "\"\"\"") { state = S::MultiBasic; i += 2; column += 2; }
          else if (raw.substr(i, 3) == "'''") { state = S::MultiLiteral; i += 2; column += 2; }
          else if (c == '"') state = S::Basic;
          else if (c == '\'') state = S::Literal;
          break;
        case S::Comment:
          if (c == '\n') state = S::Normal;
          break;
        case S::Basic:
          if (c == '\\' && i + 1 < raw.size() && raw[i + 1] != '\n') { ++i; ++column; }
          else if (c == '"' || c == '\n') state = S::Normal;  // an unterminated string is toml++'s to report
          break;
        case S::Literal:
          if (c == '\'' || c == '\n') state = S::Normal;
          break;
        case S::MultiBasic:
          if (c == '\\' && i + 1 < raw.size() && raw[i + 1] != '\n') { ++i; ++column; }
          else if (raw.substr(i, 3) == "\"\"\"") { state = S::Normal; i += 2; column += 2; }
          break;
        case S::MultiLiteral:
          if (raw.substr(i, 3) == "'''") { state = S::Normal; i += 2; column += 2; }
          break;
      }
      if (c == '\n') {
        ++line;
        column = 1;
      } else if (lead) {
        ++column;
      }
    }
  }

  std::string file_;
  SplitToml lines_;
  std::vector<std::string> overrides_;  // [session] outside_physical_range
};

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

}  // namespace

Manifest read_manifest(const std::string& path) { return ManifestReader(path).read(); }

void write_manifest(const std::string& path, const Manifest& m) {
  std::string s;
  auto out = std::back_inserter(s);
  fmt::format_to(out, "# dropfit session manifest (docs/formats.md)\n\n");
  fmt::format_to(out, "[session]\nname = {}\ngravity_m_s2 = {}\n", toml_string(m.name), toml_float(m.gravity_m_s2));
  if (!m.outside_physical_range.empty())
    fmt::format_to(out, "outside_physical_range = {}\n", toml_strings(m.outside_physical_range));
  fmt::format_to(out, "\n");
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
                 "\n[forceplate]\nmodel = {}\nsample_rate_hz = {}\ntrigger_threshold_n = {}\n{}"
                 "a_m = {}\nb_m = {}\naz0_m = {}\nmat_top_z_m = {}\n",
                 toml_string(p.model), toml_float(p.sample_rate_hz), toml_float(p.trigger_threshold_n),
                 p.pretrigger_fraction ? "pretrigger_fraction = " + toml_float(*p.pretrigger_fraction) + "\n" : "",
                 toml_float(p.a_m), toml_float(p.b_m), toml_float(p.az0_m), toml_float(p.mat_top_z_m));
  if (p.plate != 1) fmt::format_to(out, "plate = {}\n", p.plate);
  if (p.lowpass_hz > 0.0) fmt::format_to(out, "lowpass_hz = {}\nlowpass_order = {}\n", toml_float(p.lowpass_hz), p.lowpass_order);
  if (!m.calibration.dlt_coefficients.empty())
    fmt::format_to(out, "\n[calibration]\ndlt_coefficients = {}\n", toml_string(m.calibration.dlt_coefficients));
  for (const TrialSpec& t : m.trials)
    fmt::format_to(out, "\n[[trial]]\nid = {}\ndir = {}\n", toml_string(t.id), toml_string(t.dir));
  write_whole(path, s);
}

}  // namespace dropfit::capture
