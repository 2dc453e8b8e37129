// BioWare text exports as they come (docs/formats.md), and the
// UTF-8 / UTF-16 line reading of the force text files.
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>

#include "capture/force_internal.h"
#include "capture/force_io.h"
#include "capture/io.h"
#include "core/error.h"

namespace dropfit::capture {
namespace detail {
namespace {

void append_utf8(std::string& out, char32_t cp) {
  if (cp < 0x80) {
    out += static_cast<char>(cp);
  } else if (cp < 0x800) {
    out += static_cast<char>(0xC0 | (cp >> 6));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else if (cp < 0x10000) {
    out += static_cast<char>(0xE0 | (cp >> 12));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else {
    out += static_cast<char>(0xF0 | (cp >> 18));
    out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  }
}

// UTF-16 (after its byte-order mark) to UTF-8.
std::string utf16_to_utf8(const std::string& path, std::string_view bytes, bool big_endian) {
  if (bytes.size() % 2 != 0)
    throw InputError(path, 0, 0, "", "UTF-16 file with an odd number of bytes (truncated?)");
  std::string out;
  out.reserve(bytes.size() / 2);
  int line = 1;
  auto unit = [&](std::size_t i) -> char16_t {
    const auto a = static_cast<unsigned char>(bytes[i]), b = static_cast<unsigned char>(bytes[i + 1]);
    return static_cast<char16_t>(big_endian ? (a << 8) | b : (b << 8) | a);
  };
  for (std::size_t i = 0; i < bytes.size(); i += 2) {
    const char16_t u = unit(i);
    char32_t cp = u;
    if (u >= 0xD800 && u <= 0xDBFF) {
      if (i + 3 >= bytes.size()) throw InputError(path, line, 0, "", "UTF-16 file ends inside a surrogate pair");
      const char16_t low = unit(i + 2);
      if (low < 0xDC00 || low > 0xDFFF) throw InputError(path, line, 0, "", "invalid UTF-16 surrogate pair");
      cp = 0x10000 + ((static_cast<char32_t>(u) - 0xD800) << 10) + (low - 0xDC00);
      i += 2;
    } else if (u >= 0xDC00 && u <= 0xDFFF) {
      throw InputError(path, line, 0, "", "invalid UTF-16: a lone low surrogate");
    }
    if (cp == '\n') ++line;
    append_utf8(out, cp);
  }
  return out;
}

// Scale from the unit of a BioWare column (0..7: Fx..Ay) to SI, or nullopt.
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

int resultant_index(std::string_view name) {
  for (int c = 0; c < 8; ++c)
    if (name == kForceResultants[c]) return c;
  return -1;
}

// Where things were found, for the errors of read_bioware.
struct BioWareLines {
  int header_line = 0;
  int rate_line = 0;
  int rate_column = 0;
  std::vector<std::array<int, 8>> columns;  // per plate, field index of Fx..Ay or -1
};

// The values after the first field of a header line ("Rate (Hz):<TAB>1000<TAB>1000").
std::vector<Field> header_values(const Line& l) {
  std::vector<Field> f = split_fields(l.text, '\t');
  std::vector<Field> values;
  for (std::size_t k = 1; k < f.size(); ++k)
    if (!f[k].text.empty()) values.push_back(f[k]);
  return values;
}

// "Samples (#):" of the free header lines: the count and where it stands.
struct SamplesLine {
  std::optional<long long> samples;
  int line = 0, column = 0;
};

// The free header lines before the column header (`header`): version and
// rate into ex (rate's place into where), the sample count returned.
SamplesLine read_bioware_header(const std::string& path, const std::vector<Line>& lines, std::size_t header,
                                BioWareExport& ex, BioWareLines& where) {
  SamplesLine samples;
  bool have_rate = false;
  for (std::size_t i = 0; i < header; ++i) {
    const Line& l = lines[i];
    const std::vector<Field> f = split_fields(l.text, '\t');
    const std::string& key = f[0].text;
    if (iequals_prefix(key, "BioWare Version")) {
      std::string_view v = std::string_view(key).substr(15);
      v = trim(v);
      if (v.size() >= 6 && iequals(v.substr(v.size() - 6), "Export"))
        v = trim(v.substr(0, v.size() - 6));
      ex.version = std::string(v);
    } else if (iequals_prefix(key, "Rate (Hz)")) {
      const std::vector<Field> values = header_values(l);
      if (values.empty()) throw InputError(path, l.number, 0, "Rate (Hz)", "no value after 'Rate (Hz):'");
      for (const Field& v : values) {
        const double r = parse_number(path, l.number, v, "Rate (Hz)", false);
        if (!(r > 0.0)) throw InputError(path, l.number, v.column, "Rate (Hz)", "must be positive");
        if (!have_rate) {
          ex.sample_rate_hz = r;
          where.rate_line = l.number;
          where.rate_column = v.column;
          have_rate = true;
        } else if (std::abs(r - ex.sample_rate_hz) > 1e-9 * ex.sample_rate_hz) {
          throw InputError(path, l.number, v.column, "Rate (Hz)",
                           fmt::format("columns at different rates ({} and {} Hz): not one record", ex.sample_rate_hz,
                                       r));
        }
      }
    } else if (iequals_prefix(key, "Samples")) {  // "Samples (#):" or "Samples:"
      const std::vector<Field> values = header_values(l);
      if (values.empty()) continue;
      samples.samples = parse_integer(path, l.number, values[0], "Samples");
      samples.line = l.number;
      samples.column = values[0].column;
      for (const Field& v : values)
        if (parse_integer(path, l.number, v, "Samples") != *samples.samples)
          throw InputError(path, l.number, v.column, "Samples",
                           fmt::format("columns with different sample counts ({} and {})", *samples.samples, v.text));
    }
  }
  if (!have_rate) throw InputError(path, 0, 0, "Rate (Hz)", "missing header line 'Rate (Hz):<TAB>rate'");
  return samples;
}

// The column header `head` (fields in `cols`): blocks of Fx..Ay, one per
// plate, each column's field index (-1 absent); which are present and the
// plate count into ex.
std::vector<std::array<int, 8>> resultant_blocks(const std::string& path, const Line& head,
                                                 const std::vector<Field>& cols, BioWareExport& ex) {
  std::vector<std::array<int, 8>> blocks;
  std::vector<int> block_start;
  for (std::size_t i = 1; i < cols.size(); ++i) {
    const int c = resultant_index(cols[i].text);
    if (c < 0) continue;  // another column (BioWare can export more): ignored
    if (blocks.empty() || blocks.back()[c] >= 0) {
      blocks.emplace_back();
      blocks.back().fill(-1);
      block_start.push_back(static_cast<int>(i));
    }
    blocks.back()[c] = static_cast<int>(i);
  }
  if (blocks.empty())
    throw InputError(path, head.number, 0, "",
                     fmt::format("no force-plate column after '{}' (expected some of {})", cols[0].text,
                                 fmt::join(kForceResultants, " ")));
  for (int c = 0; c < 8; ++c) ex.present[c] = blocks[0][c] >= 0;
  for (std::size_t b = 1; b < blocks.size(); ++b) {
    for (int c = 0; c < 8; ++c) {
      if ((blocks[b][c] >= 0) != ex.present[c])
        throw InputError(path, head.number, cols[block_start[b]].column, kForceResultants[c],
                         fmt::format("plate {} (from column {}) {} {}, plate 1 {}: the plates' blocks must name the "
                                     "same columns",
                                     b + 1, block_start[b] + 1, ex.present[c] ? "lacks" : "has", kForceResultants[c],
                                     ex.present[c] ? "has it" : "does not"));
    }
  }
  ex.n_plates = static_cast<int>(blocks.size());
  return blocks;
}

// The units line after the column header: per plate and column, the factor to SI.
std::vector<std::array<double, 8>> unit_scales(const std::string& path, const std::vector<Line>& lines,
                                               std::size_t header, const std::vector<std::array<int, 8>>& blocks) {
  if (header + 1 >= lines.size())
    throw InputError(path, lines[header].number + 1, 0, "", "expected a units line after the column header");
  const Line& units_line = lines[header + 1];
  const std::vector<Field> units = split_fields(units_line.text, '\t');
  std::vector<std::array<double, 8>> scale(blocks.size());
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (int c = 0; c < 8; ++c) {
      if (blocks[b][c] < 0) continue;
      if (blocks[b][c] >= static_cast<int>(units.size()))
        throw InputError(path, units_line.number, 0, kForceResultants[c],
                         fmt::format("the units line has no unit for {} (column {})", kForceResultants[c],
                                     blocks[b][c] + 1));
      const Field& u = units[blocks[b][c]];
      const std::optional<double> s = bioware_scale(c, u.text);
      if (!s)
        throw InputError(path, units_line.number, u.column, kForceResultants[c],
                         fmt::format("unit '{}' for {} is not known (expected {})", u.text, kForceResultants[c],
                                     c < 3 ? "N" : c < 6 ? "N.m" : "mm or m"));
      scale[b][c] = *s;
    }
  }
  return scale;
}

BioWareExport parse_bioware(const std::string& path, const ForceTextHead& text, LineStream& stream,
                            BioWareLines& where) {
  BioWareExport ex;
  const std::vector<Line>& lines = text.lines;
  const std::size_t header = text.header;
  const SamplesLine samples = read_bioware_header(path, lines, header, ex, where);

  // Column header: blocks of Fx..Ay, one per plate.
  const Line& head = lines[header];
  where.header_line = head.number;
  std::vector<Field> cols = split_fields(head.text, '\t');
  drop_trailing_empty(cols);
  const std::vector<std::array<int, 8>> blocks = resultant_blocks(path, head, cols, ex);
  where.columns = blocks;
  int last = 0;
  for (const auto& b : blocks)
    for (int i : b) last = std::max(last, i);
  const std::vector<std::array<double, 8>> scale = unit_scales(path, lines, header, blocks);

  // Data.
  std::vector<double> t, res;
  std::vector<int> line_of, col_of;
  std::vector<std::vector<double>> values(blocks.size());
  DataRows data(path, stream);
  for (Line l; data.next(l);) {
    std::vector<Field> f = split_fields(l.text, '\t');
    // Trailing empty fields beyond the header's columns are a trailing tab;
    // empty fields within them are values (an unloaded plate's Ax Ay).
    while (f.size() > cols.size() && f.back().text.empty()) f.pop_back();
    if (static_cast<int>(f.size()) <= last || f.size() > cols.size()) row_length_error(path, l, f, cols, head.number);
    t.push_back(parse_number(path, l.number, f[0], cols[0].text, false));
    res.push_back(printed_resolution(f[0].text));
    line_of.push_back(l.number);
    col_of.push_back(f[0].column);
    for (std::size_t b = 0; b < blocks.size(); ++b)
      for (int c = 0; c < 8; ++c)
        values[b].push_back(blocks[b][c] < 0 ? std::numeric_limits<double>::quiet_NaN()
                                             : scale[b][c] * parse_number(path, l.number, f[blocks[b][c]],
                                                                          kForceResultants[c], c >= 6));
  }
  if (t.empty()) throw InputError(path, head.number, 0, "", "no data rows after the column header and units line");
  const long long rows = static_cast<long long>(t.size());
  if (samples.samples && *samples.samples != rows)
    throw InputError(path, samples.line, samples.column, "Samples",
                     rows < *samples.samples
                         ? fmt::format("the header says {} samples but the record has only {} data rows "
                                       "(truncated record?)",
                                       *samples.samples, rows)
                         : fmt::format("the header says {} samples but the record has {} data rows", *samples.samples,
                                       rows));
  check_uniform_time(path, t, res, line_of, col_of, cols[0].text, ex.sample_rate_hz);
  const auto n = static_cast<Eigen::Index>(rows);
  ex.abs_time_s = Eigen::Map<const Eigen::VectorXd>(t.data(), n);
  for (std::size_t b = 0; b < blocks.size(); ++b)
    ex.plates.push_back(Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 8, Eigen::RowMajor>>(values[b].data(),
                                                                                                    n, 8));
  return ex;
}


}  // namespace

LineStream::LineStream(const std::string& path) : path_(path) {
  namespace fs = std::filesystem;
  require_file(path);
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec) throw InputError(path, 0, 0, "", fmt::format("cannot read its size: {}", ec.message()));
  if (size > kMaxForceTextBytes)
    throw InputError(path, 0, 0, "",
                     fmt::format("file of {} bytes, larger than the {} bytes a force export here may have", size,
                                 kMaxForceTextBytes));
  in_.open(path, std::ios::binary);
  if (!in_) throw InputError(path, 0, 0, "", "cannot open");
  char bom[3] = {};
  in_.read(bom, 3);
  const std::streamsize got = in_.gcount();
  const auto b0 = static_cast<unsigned char>(bom[0]), b1 = static_cast<unsigned char>(bom[1]);
  if (got >= 2 && ((b0 == 0xFF && b1 == 0xFE) || (b0 == 0xFE && b1 == 0xFF))) {
    // UTF-16: converted whole (the conversion checks every sequence).
    in_.clear();
    in_.seekg(2);
    const std::string bytes((std::istreambuf_iterator<char>(in_)), std::istreambuf_iterator<char>());
    if (static_cast<std::uintmax_t>(bytes.size()) + 2 != size)
      throw InputError(path, 0, 0, "", "cannot read the whole file");
    decoded_ = utf16_to_utf8(path, bytes, b0 == 0xFE);
    utf16_ = true;
    in_.close();
    return;
  }
  // UTF-8: a byte-order mark is skipped, anything else read from the start.
  const bool utf8_bom = got == 3 && std::string_view(bom, 3) == "\xEF\xBB\xBF";
  in_.clear();
  in_.seekg(utf8_bom ? 3 : 0);
}

bool LineStream::next(Line& line) {
  if (utf16_) {
    if (at_ >= decoded_.size()) return false;
    std::size_t end = decoded_.find('\n', at_);
    if (end == std::string::npos) end = decoded_.size();
    line.text.assign(decoded_, at_, end - at_);
    at_ = end + 1;
  } else if (!std::getline(in_, line.text)) {
    if (in_.bad()) throw InputError(path_, number_ + 1, 0, "", "read error");
    return false;
  }
  if (!line.text.empty() && line.text.back() == '\r') line.text.pop_back();
  line.number = ++number_;
  if (const std::size_t nul = line.text.find('\0'); nul != std::string::npos)
    throw InputError(path_, number_, static_cast<int>(nul) + 1, "",
                     "NUL byte in a text file (UTF-16 without a byte-order mark?)");
  return true;
}

std::vector<Line> read_text_lines(const std::string& path) {
  LineStream stream(path);
  std::vector<Line> lines;
  for (Line l; stream.next(l);) lines.push_back(std::move(l));
  return lines;
}

bool DataRows::next(Line& line) {
  while (rows_.next(line)) {
    if (blank_line(line.text)) {
      if (blank_line_ == 0) blank_line_ = line.number;
      continue;
    }
    if (blank_line_ != 0) throw InputError(path_, blank_line_, 0, "", "blank line inside the data");
    return true;
  }
  return false;
}

ForceTextHead read_force_text_head(const std::string& path, LineStream& stream) {
  // A column header further down than this is no force export's.
  constexpr std::size_t kMaxHeadLines = 1000;
  ForceTextHead head;
  for (Line l; head.lines.size() < kMaxHeadLines && stream.next(l);) {
    const std::vector<Field> f = split_fields(l.text, '\t');
    const std::string first = f.empty() ? std::string() : f[0].text;
    head.lines.push_back(std::move(l));
    const bool eight = iequals(first, "Time(s)") || iequals(first, "Time (s)");
    head.bioware = iequals_prefix(first, "abs time");
    if (eight || head.bioware) {
      head.header = head.lines.size() - 1;
      if (head.bioware && stream.next(l)) head.lines.push_back(std::move(l));  // the units line
      return head;
    }
  }
  throw InputError(path, 0, 0, "",
                   fmt::format("no column header{}: expected a line beginning 'Time(s)' (Kistler eight-channel) or "
                               "'abs time' (BioWare)",
                               head.lines.size() >= kMaxHeadLines ? fmt::format(" in the first {} lines", kMaxHeadLines)
                                                                  : std::string()));
}

ForceRecord read_bioware(const std::string& path, const ForceTextHead& head, LineStream& rows,
                         const ForcePlateSpec& plate) {
  BioWareLines where;
  BioWareExport ex = parse_bioware(path, head, rows, where);
  if (!ex.present[2])
    throw InputError(path, where.header_line, 0, "Fz",
                     "no Fz column: this export cannot give the ground reaction force (export Fz from BioWare)");
  if (plate.plate < 1 || plate.plate > ex.n_plates)
    throw InputError(path, where.header_line, 0, "forceplate.plate",
                     fmt::format("the manifest picks plate {}, the export has {} plate{}", plate.plate, ex.n_plates,
                                 ex.n_plates == 1 ? "" : "s"));
  if (std::abs(ex.sample_rate_hz - plate.sample_rate_hz) > 1e-6 * plate.sample_rate_hz)
    throw InputError(path, where.rate_line, where.rate_column, "Rate (Hz)",
                     fmt::format("sample rate {} Hz disagrees with the manifest's forceplate.sample_rate_hz = {} Hz",
                                 ex.sample_rate_hz, plate.sample_rate_hz));
  ForceRecord rec;
  rec.layout = ForceLayout::Resultants;
  rec.sample_rate_hz = ex.sample_rate_hz;
  rec.data = std::move(ex.plates[plate.plate - 1]);
  set_trigger(rec, plate, path);
  rec.t_s = ex.abs_time_s.array() - ex.abs_time_s[rec.pretrigger_samples];
  return rec;
}

}  // namespace detail

BioWareExport read_bioware_export(const std::string& path) {
  detail::LineStream stream(path);
  const detail::ForceTextHead head = detail::read_force_text_head(path, stream);
  if (!head.bioware)
    throw InputError(path, head.lines[head.header].number, 0, "",
                     "a Kistler eight-channel export ('Time(s)' column header), not a BioWare one ('abs time')");
  detail::BioWareLines where;
  return detail::parse_bioware(path, head, stream, where);
}

}  // namespace dropfit::capture
