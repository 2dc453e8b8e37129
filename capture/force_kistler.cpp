// The Kistler eight-channel text export (force.txt, first layout of
// docs/formats.md).
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>

#include "capture/force_internal.h"
#include "capture/io.h"
#include "core/error.h"

namespace dropfit::capture::detail {

ForceRecord read_eight_channel(const std::string& path, const ForceTextHead& text, LineStream& stream,
                               const ForcePlateSpec& plate) {
  const std::vector<Line>& lines = text.lines;
  const std::size_t header = text.header;
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
  for (const char* c : kForceEightChannels) wanted.push_back(c);
  const std::map<std::string, int> index = header_columns(path, head, cols, wanted, true);
  std::array<int, 8> channel{};
  for (int c = 0; c < 8; ++c) channel[c] = index.at(kForceEightChannels[c]);

  std::vector<double> t, res;
  std::vector<int> line_of, col_of;
  std::vector<double> values;
  // Room for the rows the header announces (up to 2^18; a header's claim
  // alone never allocates more).
  const auto reserve = static_cast<std::size_t>(std::min<long long>(samples, 1 << 18));
  t.reserve(reserve);
  res.reserve(reserve);
  line_of.reserve(reserve);
  col_of.reserve(reserve);
  values.reserve(8 * reserve);
  DataRows data(path, stream);
  for (Line l; data.next(l);) {
    std::vector<Field> f = split_fields(l.text, '\t');
    drop_trailing_empty(f);
    if (f.size() != cols.size()) row_length_error(path, l, f, cols, head.number);
    t.push_back(parse_number(path, l.number, f[0], cols[0].text, false));
    res.push_back(printed_resolution(f[0].text));
    line_of.push_back(l.number);
    col_of.push_back(f[0].column);
    for (int c = 0; c < 8; ++c) values.push_back(parse_number(path, l.number, f[channel[c]], kForceEightChannels[c], false));
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

}  // namespace dropfit::capture::detail
