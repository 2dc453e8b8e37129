// Shared text-file plumbing of the capture readers and writers (see
// capture/text_io.h).
#include "capture/text_io.h"

#include <fmt/format.h>
// libfccp's error types copy file names with strncpy, which GCC flags after
// inlining; the truncation is intended (they keep 255 characters).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wstringop-truncation"
#include <libfccp/csv.h>
#pragma GCC diagnostic pop

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <limits>
#include <optional>

#include "core/atomic_file.h"
#include "core/error.h"

namespace dropfit::capture::detail {

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---------------------------------------------------------------------------
// Lines and fields
// ---------------------------------------------------------------------------

// A field of a delimited line: its text (unquoted, blanks around it removed)
// and the 1-based character column where it starts.


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
  if (ec == std::errc::too_many_symbolic_link_levels)
    throw InputError(path, 0, 0, "", "symbolic link loop: the path never reaches a file");
  if (!fs::exists(st)) {
    std::error_code ec2;
    if (fs::is_symlink(fs::symlink_status(path, ec2)))
      throw InputError(path, 0, 0, "", "broken symbolic link: its target does not exist");
    if (ec && ec != std::errc::no_such_file_or_directory)
      throw InputError(path, 0, 0, "", fmt::format("cannot reach the file: {}", ec.message()));
    throw InputError(path, 0, 0, "", "file not found");
  }
  if (fs::is_directory(st)) throw InputError(path, 0, 0, "", "is a folder, expected a file");
  if (!fs::is_regular_file(st)) throw InputError(path, 0, 0, "", "not a regular file");
  const std::uintmax_t size = fs::file_size(path, ec);
  if (!ec && size > kMaxFileBytes)
    throw InputError(path, 0, 0, "",
                     fmt::format("{} bytes, more than the {} bytes any session file may have", size, kMaxFileBytes));
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
std::vector<Field> split_fields(std::string_view line, char sep, std::size_t max_fields) {
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
    if (max_fields > 0 && out.size() == max_fields) {
      // More fields than the caller can use: the rest is one last field, so
      // that a line of millions of separators costs no more than this.
      out.push_back(Field{std::string(line.substr(i, std::min<std::size_t>(line.size() - i, 64))),
                          static_cast<int>(i) + 1});
      break;
    }
  }
  return out;
}

std::optional<std::pair<int, int>> first_invalid_utf8(std::string_view text) {
  int line = 1, column = 1;
  std::size_t i = 0;
  while (i < text.size()) {
    const auto c = static_cast<unsigned char>(text[i]);
    std::size_t n = 0;
    std::uint32_t cp = 0;
    if (c < 0x80) {
      n = 1;
      cp = c;
    } else if ((c & 0xE0) == 0xC0) {
      n = 2;
      cp = c & 0x1F;
    } else if ((c & 0xF0) == 0xE0) {
      n = 3;
      cp = c & 0x0F;
    } else if ((c & 0xF8) == 0xF0) {
      n = 4;
      cp = c & 0x07;
    } else {
      return std::make_pair(line, column);
    }
    if (i + n > text.size()) return std::make_pair(line, column);
    for (std::size_t k = 1; k < n; ++k) {
      const auto cc = static_cast<unsigned char>(text[i + k]);
      if ((cc & 0xC0) != 0x80) return std::make_pair(line, column);
      cp = (cp << 6) | (cc & 0x3F);
    }
    // Overlong forms, surrogates and code points beyond U+10FFFF.
    if ((n == 2 && cp < 0x80) || (n == 3 && cp < 0x800) || (n == 4 && cp < 0x10000) ||
        (cp >= 0xD800 && cp <= 0xDFFF) || cp > 0x10FFFF)
      return std::make_pair(line, column);
    if (c == '\n') {
      ++line;
      column = 1;
    } else {
      ++column;
    }
    i += n;
  }
  return std::nullopt;
}

char separator_of(std::string_view line) {
  return line.find('\t') != std::string_view::npos && line.find(',') == std::string_view::npos ? '\t' : ',';
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

double parse_bounded(const std::string& file, int line, const Field& f, const std::string& field, bool nan_ok,
                     double limit, const char* what) {
  const double v = parse_number(file, line, f, field, nan_ok);
  if (std::abs(v) > limit)
    throw InputError(file, line, f.column, field,
                     fmt::format("'{}' is beyond +-{:g}, out of range for {}", f.text, limit, what));
  return v;
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

// Writes `content` whole or not at all (core/atomic_file.h: temporary file
// beside `path`, fsync, rename), into a folder that must exist already (the
// writers make no folders). Errors name `path`.
void write_whole(const std::string& path, const std::string& content) {
  const fs::path parent = fs::path(path).parent_path();
  if (!parent.empty() && !fs::is_directory(parent))
    throw Error(fmt::format("cannot write {}: no folder {}", path, parent.string()));
  try {
    write_file_atomic(path, content);
  } catch (const Error& e) {
    throw Error(fmt::format("cannot write {}: {}", path, e.what()));
  }
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

}  // namespace dropfit::capture::detail
