#pragma once
// Internal to capture/: the text-file plumbing shared by its readers and
// writers (lines, delimited fields, strict numbers, header columns, whole-file
// writes). Not part of the public API (capture/io.h is).
#include <cstdint>
#include <map>
#include <optional>
#include <utility>
#include <string>
#include <string_view>
#include <vector>

namespace dropfit::capture::detail {

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

// Limits of every reader (bounded readers). A session file larger
// than kMaxFileBytes is refused before it is read; names (points, cameras,
// column names) are at most kMaxNameChars characters; a manifest lists at
// most kMaxPoints points and kMaxCameras cameras (triangulation works
// without allocation up to 16 cameras).
inline constexpr std::uintmax_t kMaxFileBytes = 2ull << 30;  // 2 GiB
inline constexpr std::size_t kMaxNameChars = 256;
inline constexpr std::size_t kMaxPoints = 1000;
inline constexpr std::size_t kMaxCameras = 16;
// Most markers in calibration/frame.csv (the calibration's cross-validation
// refits grow faster than N^2 with them).
inline constexpr std::size_t kMaxCalibrationMarkers = 500;

bool is_blank(char c);
bool blank_line(std::string_view s);
std::string_view trim(std::string_view s);
// A regular file (symlinks followed); an InputError naming `path` otherwise
// (not found, a folder, a symlink loop, larger than max_file_bytes).
void require_file(const std::string& path);
// Every line of a text file (CR LF handled, UTF-8 BOM skipped).
std::vector<Line> read_lines(const std::string& path);
// Splits a delimited line (double quotes, "" inside; blanks around fields
// dropped). With max_fields > 0, at most max_fields + 1 fields: the rest of
// a longer line becomes one last field (its first 64 characters).
std::vector<Field> split_fields(std::string_view line, char sep, std::size_t max_fields = 0);
// Tab when the line has tabs and no comma, else comma.
char separator_of(std::string_view line);
// 1-based line and column (in code points) of the first byte that does not
// start a valid UTF-8 sequence (overlong forms, surrogates and values above
// U+10FFFF are invalid); nullopt when the whole text is valid.
std::optional<std::pair<int, int>> first_invalid_utf8(std::string_view text);
void drop_trailing_empty(std::vector<Field>& fields);
bool iequals_prefix(std::string_view s, std::string_view prefix);
bool iequals(std::string_view a, std::string_view b);
double parse_number(const std::string& file, int line, const Field& f, const std::string& field, bool nan_ok);
// parse_number, then |value| <= limit (NaN passes when nan_ok): a value
// beyond it is refused naming `what` ("a lab position in metres") so that
// numbers like 1e308 fail where they are written, not later as a degenerate
// geometry.
double parse_bounded(const std::string& file, int line, const Field& f, const std::string& field, bool nan_ok,
                     double limit, const char* what);
// Largest magnitudes accepted: lab coordinates (m) and image coordinates (px).
// A drop test's calibration structure spans a metre or so about the plate,
// a sports hall's wand volume tens of metres: a coordinate beyond 100 m is a
// frame written in millimetres (a 0.4 m structure reads 400).
inline constexpr double kMaxLabCoordinateM = 100.0;
inline constexpr double kMaxPixel = 1e6;
long long parse_integer(const std::string& file, int line, const Field& f, const std::string& field);
double printed_resolution(std::string_view s);
[[noreturn]] void row_length_error(const std::string& file, const Line& line, const std::vector<Field>& fields,
                                   const std::vector<Field>& header, int header_line);
std::map<std::string, int> header_columns(const std::string& file, const Line& line,
                                          const std::vector<Field>& fields,
                                          const std::vector<std::string>& required, bool allow_unknown);
double rounding_slack(double period, double ra, double rb);
void check_uniform_time(const std::string& file, const std::vector<double>& t, const std::vector<double>& resolution,
                        const std::vector<int>& lines, const std::vector<int>& columns, const std::string& field,
                        double rate_hz);

// One xypts column name taken apart, without regular expressions (a
// backtracking regex on a long header field overflowed the stack):
//   NAME_camN_X / _Y   layout 0 (DLTdv 8.3; NAME is ptK there)
//   NAME_camN_U / _V   layout 1 (DLTdv 8.4 and later)
//   NAME_cam_N_x / _y  layout 2 (Argus)
// N is one or more digits; NAME is non-empty. nullopt when none fits.
struct ColumnName {
  int layout = 0;
  std::string point;
  std::string camera_text;
  long long camera = 0;  // 0 when camera_text has more than 9 digits
  int axis = 0;          // 0 u, 1 v
};

std::optional<ColumnName> parse_column_name(std::string_view s);

void write_whole(const std::string& path, const std::string& content);
std::string csv_field(const std::string& s);
std::string pixel(double v);

}  // namespace dropfit::capture::detail
