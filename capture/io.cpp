// Readers and writers of the session format; see capture/io.h for the
// conventions and shared/spec/session-format.md for the contract.
// The other formats live in capture/*_io.cpp; this file holds the force-plate exports.
#include "capture/io.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <string_view>

#include "capture/text_io.h"
#include "core/error.h"

namespace dropfit::capture {
namespace {

using namespace detail;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

constexpr std::array<const char*, 8> kEightChannels = {"Fx12", "Fx34", "Fy14", "Fy23", "Fz1", "Fz2", "Fz3", "Fz4"};
constexpr std::array<const char*, 8> kResultants = {"Fx", "Fy", "Fz", "Mx", "My", "Mz", "Ax", "Ay"};

// ---------------------------------------------------------------------------
// force.txt
// ---------------------------------------------------------------------------

ForceRecord read_eight_channel(const std::string& path, const std::vector<Line>& lines, std::size_t header,
                               const ForcePlateSpec& plate) {
  ForceRecord rec;
  rec.layout = ForceLayout::EightChannel;
  struct Entry {
    Field value;
    int line;
  };
  std::map<std::string, Entry> keys;
  for (std::size_t i = 0; i < header; ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) continue;
    const std::vector<Field> f = split_fields(l.text, '\t');
    if (f.size() < 2)
      throw InputError(path, l.number, 1, f.empty() ? "" : f[0].text,
                       "expected a 'key<TAB>value' header line before the column header");
    if (!keys.emplace(f[0].text, Entry{f[1], l.number}).second)
      throw InputError(path, l.number, f[0].column, f[0].text, fmt::format("duplicate header key '{}'", f[0].text));
  }
  auto need = [&](const char* key) -> const Entry& {
    const auto it = keys.find(key);
    if (it == keys.end())
      throw InputError(path, 0, 0, key, fmt::format("missing header line '{}<TAB>value'", key));
    return it->second;
  };
  const Entry& rate = need("Sample rate");
  rec.sample_rate_hz = parse_number(path, rate.line, rate.value, "Sample rate", false);
  if (!(rec.sample_rate_hz > 0.0))
    throw InputError(path, rate.line, rate.value.column, "Sample rate", "must be positive");
  if (std::abs(rec.sample_rate_hz - plate.sample_rate_hz) > 1e-6 * plate.sample_rate_hz)
    throw InputError(path, rate.line, rate.value.column, "Sample rate",
                     fmt::format("sample rate {} Hz disagrees with the manifest's forceplate.sample_rate_hz = {} Hz",
                                 rec.sample_rate_hz, plate.sample_rate_hz));
  const Entry& samples_entry = need("Samples");
  const long long samples = parse_integer(path, samples_entry.line, samples_entry.value, "Samples");
  if (samples < 1 || samples > std::numeric_limits<int>::max())
    throw InputError(path, samples_entry.line, samples_entry.value.column, "Samples", "must be a positive integer");
  const Entry& pre = need("Pretrigger samples");
  const long long pretrigger = parse_integer(path, pre.line, pre.value, "Pretrigger samples");
  if (pretrigger < 0 || pretrigger >= samples)
    throw InputError(path, pre.line, pre.value.column, "Pretrigger samples",
                     fmt::format("{} is not a sample of a {}-sample record", pretrigger, samples));
  rec.pretrigger_samples = static_cast<int>(pretrigger);
  if (const auto it = keys.find("Trigger"); it != keys.end()) rec.trigger = it->second.value.text;

  const Line& head = lines[header];
  std::vector<Field> cols = split_fields(head.text, '\t');
  drop_trailing_empty(cols);
  std::vector<std::string> wanted = {cols[0].text};
  for (const char* c : kEightChannels) wanted.push_back(c);
  const std::map<std::string, int> index = header_columns(path, head, cols, wanted, true);
  std::array<int, 8> channel{};
  for (int c = 0; c < 8; ++c) channel[c] = index.at(kEightChannels[c]);

  std::vector<double> t, res;
  std::vector<int> line_of, col_of;
  std::vector<double> values;
  std::size_t end = lines.size();
  while (end > header + 1 && blank_line(lines[end - 1].text)) --end;
  for (std::size_t i = header + 1; i < end; ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) throw InputError(path, l.number, 0, "", "blank line inside the data");
    std::vector<Field> f = split_fields(l.text, '\t');
    drop_trailing_empty(f);
    if (f.size() != cols.size()) row_length_error(path, l, f, cols, head.number);
    t.push_back(parse_number(path, l.number, f[0], cols[0].text, false));
    res.push_back(printed_resolution(f[0].text));
    line_of.push_back(l.number);
    col_of.push_back(f[0].column);
    for (int c = 0; c < 8; ++c) values.push_back(parse_number(path, l.number, f[channel[c]], kEightChannels[c], false));
  }
  const long long rows = static_cast<long long>(t.size());
  if (rows != samples)
    throw InputError(path, samples_entry.line, samples_entry.value.column, "Samples",
                     rows < samples ? fmt::format("the header says {} samples but the record has only {} data rows "
                                                  "(truncated record?)",
                                                  samples, rows)
                                    : fmt::format("the header says {} samples but the record has {} data rows", samples,
                                                  rows));
  check_uniform_time(path, t, res, line_of, col_of, cols[0].text, rec.sample_rate_hz);
  const double t0 = t[rec.pretrigger_samples];
  if (std::abs(t0) > 0.5 / rec.sample_rate_hz + 0.5 * res[rec.pretrigger_samples])
    throw InputError(path, line_of[rec.pretrigger_samples], col_of[rec.pretrigger_samples], cols[0].text,
                     fmt::format("the trigger sample (row {} after {} pretrigger samples) is at {} s, expected 0",
                                 rec.pretrigger_samples + 1, rec.pretrigger_samples, t0));
  rec.t_s = Eigen::Map<const Eigen::VectorXd>(t.data(), static_cast<Eigen::Index>(t.size()));
  rec.data = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 8, Eigen::RowMajor>>(values.data(),
                                                                                        static_cast<Eigen::Index>(rows), 8);
  return rec;
}

// Scale from the unit of a BioWare column to SI, or nullopt if not known.
std::optional<double> bioware_scale(int column, std::string_view unit) {
  if (column < 3) {  // forces
    if (unit == "N") return 1.0;
  } else if (column < 6) {  // moments
    for (std::string_view u : {"N.m", "Nm", "N m", "N*m", "N-m", "N·m"})
      if (unit == u) return 1.0;
  } else {  // centre of pressure
    if (unit == "mm") return 1e-3;
    if (unit == "m") return 1.0;
  }
  return std::nullopt;
}

ForceRecord read_bioware(const std::string& path, const std::vector<Line>& lines, std::size_t header,
                         const ForcePlateSpec& plate) {
  ForceRecord rec;
  rec.layout = ForceLayout::Resultants;
  bool have_rate = false;
  for (std::size_t i = 0; i < header; ++i) {
    const std::vector<Field> f = split_fields(lines[i].text, '\t');
    if (!iequals_prefix(f[0].text, "Rate (Hz)")) continue;
    const Field* value = nullptr;
    for (std::size_t k = 1; k < f.size() && !value; ++k)
      if (!f[k].text.empty()) value = &f[k];
    if (!value) throw InputError(path, lines[i].number, 0, "Rate (Hz)", "no value after 'Rate (Hz):'");
    rec.sample_rate_hz = parse_number(path, lines[i].number, *value, "Rate (Hz)", false);
    if (std::abs(rec.sample_rate_hz - plate.sample_rate_hz) > 1e-6 * plate.sample_rate_hz)
      throw InputError(path, lines[i].number, value->column, "Rate (Hz)",
                       fmt::format("sample rate {} Hz disagrees with the manifest's forceplate.sample_rate_hz = {} Hz",
                                   rec.sample_rate_hz, plate.sample_rate_hz));
    have_rate = true;
    break;
  }
  if (!have_rate) throw InputError(path, 0, 0, "Rate (Hz)", "missing header line 'Rate (Hz):<TAB>rate'");

  const Line& head = lines[header];
  std::vector<Field> cols = split_fields(head.text, '\t');
  drop_trailing_empty(cols);
  std::vector<std::string> wanted = {cols[0].text};
  for (const char* c : kResultants) wanted.push_back(c);
  const std::map<std::string, int> index = header_columns(path, head, cols, wanted, true);
  std::array<int, 8> column{};
  int last = 0;
  for (int c = 0; c < 8; ++c) {
    column[c] = index.at(kResultants[c]);
    last = std::max(last, column[c]);
  }

  if (header + 1 >= lines.size())
    throw InputError(path, head.number + 1, 0, "", "expected a units line after the column header");
  const Line& units_line = lines[header + 1];
  const std::vector<Field> units = split_fields(units_line.text, '\t');
  std::array<double, 8> scale{};
  for (int c = 0; c < 8; ++c) {
    if (column[c] >= static_cast<int>(units.size()))
      throw InputError(path, units_line.number, 0, kResultants[c],
                       fmt::format("the units line has no unit for {}", kResultants[c]));
    const Field& u = units[column[c]];
    const std::optional<double> s = bioware_scale(c, u.text);
    if (!s)
      throw InputError(path, units_line.number, u.column, kResultants[c],
                       fmt::format("unit '{}' for {} is not known (expected {})", u.text, kResultants[c],
                                   c < 3 ? "N" : c < 6 ? "N.m" : "mm or m"));
    scale[c] = *s;
  }

  std::vector<double> t, res;
  std::vector<int> line_of, col_of;
  std::vector<double> values;
  std::size_t end = lines.size();
  while (end > header + 2 && blank_line(lines[end - 1].text)) --end;
  for (std::size_t i = header + 2; i < end; ++i) {
    const Line& l = lines[i];
    if (blank_line(l.text)) throw InputError(path, l.number, 0, "", "blank line inside the data");
    std::vector<Field> f = split_fields(l.text, '\t');
    drop_trailing_empty(f);
    if (static_cast<int>(f.size()) <= last || f.size() > cols.size()) row_length_error(path, l, f, cols, head.number);
    t.push_back(parse_number(path, l.number, f[0], cols[0].text, false));
    res.push_back(printed_resolution(f[0].text));
    line_of.push_back(l.number);
    col_of.push_back(f[0].column);
    for (int c = 0; c < 8; ++c)
      values.push_back(scale[c] * parse_number(path, l.number, f[column[c]], kResultants[c], c >= 6));
  }
  if (t.empty()) throw InputError(path, head.number, 0, "", "no data rows after the column header and units line");
  check_uniform_time(path, t, res, line_of, col_of, cols[0].text, rec.sample_rate_hz);
  const int n = static_cast<int>(t.size());
  rec.pretrigger_samples = std::min(trigger_sample_from_fraction(plate.pretrigger_fraction, n), n - 1);
  const double t_trigger = t[rec.pretrigger_samples];
  rec.t_s = Eigen::Map<const Eigen::VectorXd>(t.data(), n).array() - t_trigger;
  rec.data = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 8, Eigen::RowMajor>>(values.data(), n, 8);
  return rec;
}

}  // namespace

int trigger_sample_from_fraction(double pretrigger_fraction, int n_samples) {
  return static_cast<int>(std::lround(pretrigger_fraction * static_cast<double>(n_samples)));
}

ForceRecord read_force(const std::string& path, const ForcePlateSpec& plate) {
  const std::vector<Line> lines = read_lines(path);
  for (std::size_t i = 0; i < lines.size(); ++i) {
    const std::vector<Field> f = split_fields(lines[i].text, '\t');
    const std::string& first = f[0].text;
    if (iequals(first, "Time(s)") || iequals(first, "Time (s)")) return read_eight_channel(path, lines, i, plate);
    if (iequals_prefix(first, "abs time")) return read_bioware(path, lines, i, plate);
  }
  throw InputError(path, 0, 0, "",
                   "no column header: expected a line beginning 'Time(s)' (Kistler eight-channel) or 'abs time' "
                   "(BioWare)");
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

}  // namespace dropfit::capture
