#pragma once
// Internal to capture/: the text-file plumbing shared by its readers and
// writers (lines, delimited fields, strict numbers, header columns, whole-file
// writes). Not part of the public API (capture/io.h is).
#include <map>
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

bool is_blank(char c);
bool blank_line(std::string_view s);
std::string_view trim(std::string_view s);
// A regular file (symlinks followed); an InputError naming `path` otherwise
// (not found, a folder, a symlink loop, larger than max_file_bytes).
void require_file(const std::string& path);
// Every line of a text file (CR LF handled, UTF-8 BOM skipped).
std::vector<Line> read_lines(const std::string& path);
std::vector<Field> split_fields(std::string_view line, char sep);
// Tab when the line has tabs and no comma, else comma.
char separator_of(std::string_view line);
void drop_trailing_empty(std::vector<Field>& fields);
bool iequals_prefix(std::string_view s, std::string_view prefix);
bool iequals(std::string_view a, std::string_view b);
double parse_number(const std::string& file, int line, const Field& f, const std::string& field, bool nan_ok);
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

void write_whole(const std::string& path, const std::string& content);
std::string csv_field(const std::string& s);
std::string pixel(double v);

}  // namespace dropfit::capture::detail
