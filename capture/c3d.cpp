// The C3D reader; the format as capture/c3d.h summarises it.
#include "capture/c3d.h"

#include <fmt/format.h>

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>

#include "core/error.h"

namespace dropfit::capture {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr std::size_t kBlock = 512;

std::string upper(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return out;
}

// Bytes of the file with the processor's number formats.
class Reader {
 public:
  Reader(std::string_view bytes, std::string name) : bytes_(bytes), name_(std::move(name)) {}

  [[noreturn]] void fail(const std::string& field, const std::string& reason) const {
    throw InputError(name_, 0, 0, field, reason);
  }
  const std::string& name() const { return name_; }
  std::size_t size() const { return bytes_.size(); }
  void set_processor(C3dProcessor p) { processor_ = p; }
  C3dProcessor processor() const { return processor_; }

  void need(std::size_t at, std::size_t n, const std::string& field) const {
    if (at > bytes_.size() || n > bytes_.size() - at)
      fail(field, fmt::format("the file ends at byte {}, {} reaches byte {} (truncated or corrupt file)", bytes_.size(),
                              field, at > bytes_.size() ? at : at + n));
  }
  std::uint8_t u8(std::size_t at, const std::string& field) const {
    need(at, 1, field);
    return static_cast<std::uint8_t>(bytes_[at]);
  }
  std::int8_t i8(std::size_t at, const std::string& field) const {
    return static_cast<std::int8_t>(u8(at, field));
  }
  std::uint16_t u16(std::size_t at, const std::string& field) const {
    need(at, 2, field);
    const auto b0 = static_cast<std::uint8_t>(bytes_[at]), b1 = static_cast<std::uint8_t>(bytes_[at + 1]);
    if (processor_ == C3dProcessor::Mips) return static_cast<std::uint16_t>((b0 << 8) | b1);
    return static_cast<std::uint16_t>((b1 << 8) | b0);
  }
  std::int16_t i16(std::size_t at, const std::string& field) const {
    return static_cast<std::int16_t>(u16(at, field));
  }
  float f32(std::size_t at, const std::string& field) const {
    need(at, 4, field);
    std::uint8_t b[4];
    std::memcpy(b, bytes_.data() + at, 4);
    std::uint32_t u = 0;
    switch (processor_) {
      case C3dProcessor::Intel:
        u = static_cast<std::uint32_t>(b[0]) | (static_cast<std::uint32_t>(b[1]) << 8) |
            (static_cast<std::uint32_t>(b[2]) << 16) | (static_cast<std::uint32_t>(b[3]) << 24);
        return std::bit_cast<float>(u);
      case C3dProcessor::Mips:
        u = static_cast<std::uint32_t>(b[3]) | (static_cast<std::uint32_t>(b[2]) << 8) |
            (static_cast<std::uint32_t>(b[1]) << 16) | (static_cast<std::uint32_t>(b[0]) << 24);
        return std::bit_cast<float>(u);
      case C3dProcessor::Dec: {
        // VAX F-float: the first 16-bit word (little-endian) holds the sign,
        // the exponent and the high mantissa bits. Swapping the words gives
        // an IEEE pattern worth 4 times the value; exponent 0 is zero.
        u = (static_cast<std::uint32_t>(b[0]) << 16) | (static_cast<std::uint32_t>(b[1]) << 24) |
            static_cast<std::uint32_t>(b[2]) | (static_cast<std::uint32_t>(b[3]) << 8);
        if (((u >> 23) & 0xFFu) == 0) return 0.0f;
        return std::bit_cast<float>(u) / 4.0f;
      }
    }
    return 0.0f;
  }

 private:
  std::string_view bytes_;
  std::string name_;
  C3dProcessor processor_ = C3dProcessor::Intel;
};

std::string trim_text(std::string_view s) {
  std::size_t b = 0, e = s.size();
  while (b < e && (s[b] == ' ' || s[b] == '\0')) ++b;
  while (e > b && (s[e - 1] == ' ' || s[e - 1] == '\0')) --e;
  return std::string(s.substr(b, e - b));
}

void read_parameters(const Reader& r, std::size_t start, std::size_t end, C3dFile& out) {
  // Group ids -> names; parameters may precede their group's record.
  struct Pending {
    int group_id;
    C3dParameter p;
  };
  std::vector<std::pair<int, std::string>> groups;
  std::vector<Pending> pending;
  std::size_t at = start + 4;
  for (int record = 0;; ++record) {
    if (at >= end) break;  // ran into the end of the section: no terminator, accept what was read
    const std::string where = fmt::format("parameter record {} at byte {}", record + 1, at);
    const int name_len = std::abs(static_cast<int>(r.i8(at, where)));
    if (name_len == 0) break;
    const int id = r.i8(at + 1, where);
    if (id == 0) r.fail(where, "group id 0 (corrupt parameter section)");
    r.need(at + 2, static_cast<std::size_t>(name_len) + 2, where);
    if (at + 2 + name_len + 2 > end) r.fail(where, "record runs past the end of the parameter section");
    std::string name;
    for (int k = 0; k < name_len; ++k) {
      const char c = static_cast<char>(r.u8(at + 2 + k, where));
      if (!std::isprint(static_cast<unsigned char>(c)))
        r.fail(where, fmt::format("name has a non-printable byte 0x{:02x} (corrupt parameter section)",
                                  static_cast<unsigned>(static_cast<unsigned char>(c))));
      name += c;
    }
    name = upper(name);
    const std::size_t offset_at = at + 2 + name_len;
    const std::uint16_t next = r.u16(offset_at, where + " (" + name + ")");
    const std::size_t body = offset_at + 2;
    const std::string field = id < 0 ? name : fmt::format("{} (group {})", name, id);
    if (id < 0) {
      groups.emplace_back(-id, name);
    } else {
      C3dParameter p;
      p.name = name;
      p.type = r.i8(body, field);
      if (p.type != -1 && p.type != 1 && p.type != 2 && p.type != 4)
        r.fail(field, fmt::format("parameter type {} (expected -1, 1, 2 or 4)", p.type));
      const int n_dims = r.u8(body + 1, field);
      if (n_dims > 7) r.fail(field, fmt::format("{} dimensions (at most 7)", n_dims));
      std::size_t count = 1;
      for (int d = 0; d < n_dims; ++d) {
        const int dim = r.u8(body + 2 + d, field);
        p.dims.push_back(dim);
        count *= static_cast<std::size_t>(dim);  // <= 255^7: no overflow
      }
      const std::size_t data_at = body + 2 + n_dims;
      const std::size_t width = static_cast<std::size_t>(std::abs(p.type));
      // count <= 255^7: bounded by the section before multiplying further.
      if (count > end || count * width > end - std::min(end, data_at))
        r.fail(field, fmt::format("{} values of {} bytes run past the end of the parameter section", count, width));
      if (p.type == -1) {
        const std::size_t len = p.dims.empty() ? 1 : static_cast<std::size_t>(p.dims[0]);
        const std::size_t cols = len == 0 ? 0 : count / len;
        for (std::size_t c = 0; c < cols; ++c) {
          std::string s;
          for (std::size_t k = 0; k < len; ++k) s += static_cast<char>(r.u8(data_at + c * len + k, field));
          p.strings.push_back(trim_text(s));
        }
      } else {
        p.numbers.reserve(count);
        for (std::size_t k = 0; k < count; ++k) {
          const std::size_t a = data_at + k * width;
          double v = 0.0;
          if (p.type == 1)
            v = r.u8(a, field);
          else if (p.type == 2)
            v = r.i16(a, field);
          else
            v = r.f32(a, field);
          p.numbers.push_back(v);
        }
      }
      pending.push_back({id, std::move(p)});
    }
    if (next == 0) break;
    const std::size_t following = offset_at + next;
    if (following <= at) r.fail(field, "offset to the next record points backwards (corrupt parameter section)");
    at = following;
  }
  for (Pending& p : pending) {
    const auto it = std::find_if(groups.begin(), groups.end(), [&](const auto& g) { return g.first == p.group_id; });
    if (it == groups.end()) continue;  // a parameter of no group: not addressable, ignored
    p.p.group = it->second;
    out.parameters.push_back(std::move(p.p));
  }
}

// The data section (the counts in out already checked against the file):
// frame by frame, every point's X Y Z and fourth word, then the analog
// samples (sample-major), into out.points and out.analog_stored.
void read_data_section(const Reader& r, std::size_t data_start, std::size_t frame_bytes, bool analog_unsigned,
                       C3dFile& out) {
  const std::size_t width = out.float_data ? 4 : 2;
  const double scale = std::abs(out.point_scale);
  for (int f = 0; f < out.n_frames; ++f) {
    std::size_t at = data_start + static_cast<std::size_t>(f) * frame_bytes;
    for (int p = 0; p < out.n_points; ++p) {
      double xyz[3];
      double fourth = 0.0;
      if (out.float_data) {
        for (int k = 0; k < 3; ++k) xyz[k] = r.f32(at + 4 * k, "data section");
        fourth = r.f32(at + 12, "data section");
      } else {
        for (int k = 0; k < 3; ++k) xyz[k] = r.i16(at + 2 * k, "data section") * scale;
        fourth = r.i16(at + 6, "data section");
      }
      at += 4 * width;
      // The fourth word as a 16-bit integer: negative = invalid point.
      const double word = std::isfinite(fourth) ? std::trunc(fourth) : -1.0;
      const bool valid = word >= 0.0 && std::isfinite(xyz[0]) && std::isfinite(xyz[1]) && std::isfinite(xyz[2]);
      for (int k = 0; k < 3; ++k) out.points(f, 4 * p + k) = valid ? xyz[k] : kNaN;
      out.points(f, 4 * p + 3) =
          valid ? static_cast<double>(static_cast<long long>(std::min(word, 65535.0)) & 0xFF) * scale : kNaN;
    }
    for (int s = 0; s < out.analog_per_frame; ++s) {
      const Eigen::Index row = static_cast<Eigen::Index>(f) * out.analog_per_frame + s;
      for (int c = 0; c < out.n_analog_channels; ++c) {
        double v = 0.0;
        if (out.float_data)
          v = r.f32(at, "data section");
        else
          v = analog_unsigned ? static_cast<double>(r.u16(at, "data section"))
                              : static_cast<double>(r.i16(at, "data section"));
        if (!std::isfinite(v))
          r.fail("data section", fmt::format("analog channel {} frame {} sample {} is not finite", c + 1,
                                             out.first_frame + f, s + 1));
        out.analog_stored(row, c) = v;
        at += width;
      }
    }
  }
}

int parameter_int(const C3dFile& f, std::string_view group, std::string_view name, int fallback) {
  const C3dParameter* p = f.find(group, name);
  if (!p || p->numbers.empty()) return fallback;
  const double v = p->numbers[0];
  // int16 counts above 32767 are stored as negative numbers.
  if (p->type == 2 && v < 0) return static_cast<int>(v) + 65536;
  if (!std::isfinite(v) || v < 0 || v > 1e9) return fallback;
  return static_cast<int>(v);
}

}  // namespace

const C3dParameter* C3dFile::find(std::string_view group, std::string_view name) const {
  const std::string g = upper(group), n = upper(name);
  for (const C3dParameter& p : parameters)
    if (p.group == g && p.name == n) return &p;
  return nullptr;
}

double C3dFile::analog_rate_hz() const {
  if (const C3dParameter* p = find("ANALOG", "RATE"); p && !p->numbers.empty() && p->numbers[0] > 0.0)
    return p->numbers[0];
  return point_rate_hz * analog_per_frame;
}

C3dFile parse_c3d(std::string_view bytes, const std::string& name) {
  Reader r(bytes, name);
  C3dFile out;
  out.path = name;
  if (bytes.size() > kMaxC3dBytes)
    r.fail("", fmt::format("file of {} bytes, larger than the {} bytes a C3D here may have", bytes.size(),
                           kMaxC3dBytes));
  r.need(0, kBlock, "header");
  const int param_block = r.u8(0, "header byte 1 (parameter block)");
  if (r.u8(1, "header byte 2") != 0x50)
    r.fail("header byte 2", fmt::format("is 0x{:02x}, a C3D file has 0x50 (not a C3D file?)", r.u8(1, "header")));
  if (param_block < 2) r.fail("header byte 1 (parameter block)", fmt::format("{} (must be 2 or more)", param_block));
  const std::size_t param_start = (static_cast<std::size_t>(param_block) - 1) * kBlock;
  r.need(param_start, 4, "parameter section");
  const int proc = r.u8(param_start + 3, "parameter section byte 4 (processor type)");
  if (proc < 84 || proc > 86)
    r.fail("processor type", fmt::format("{} (expected 84 Intel, 85 DEC or 86 MIPS)", proc));
  out.processor = static_cast<C3dProcessor>(proc);
  r.set_processor(out.processor);

  out.n_points = r.u16(2, "header word 2 (points)");
  const int analog_total = r.u16(4, "header word 3 (analog measurements per frame)");
  out.first_frame = r.u16(6, "header word 4 (first frame)");
  const int last_frame = r.u16(8, "header word 5 (last frame)");
  out.point_scale = r.f32(12, "header words 7-8 (scale factor)");
  const int data_block = r.u16(16, "header word 9 (data block)");
  out.analog_per_frame = r.u16(18, "header word 10 (analog samples per frame)");
  out.point_rate_hz = r.f32(20, "header words 11-12 (frame rate)");
  if (!std::isfinite(out.point_scale) || out.point_scale == 0.0)
    r.fail("header words 7-8 (scale factor)", fmt::format("{} (must be finite and not 0)", out.point_scale));
  out.float_data = out.point_scale < 0.0;
  if (!(out.point_rate_hz > 0.0) || !std::isfinite(out.point_rate_hz))
    r.fail("header words 11-12 (frame rate)", fmt::format("{} Hz (must be positive)", out.point_rate_hz));
  if (data_block <= param_block)
    r.fail("header word 9 (data block)",
           fmt::format("{}: the data must start after the parameter section (block {})", data_block, param_block));
  const std::size_t data_start = (static_cast<std::size_t>(data_block) - 1) * kBlock;
  read_parameters(r, param_start, std::min(data_start, bytes.size()), out);

  // Frames: the header's count, or POINT:FRAMES when a long record overflowed the header.
  long long n_frames = static_cast<long long>(last_frame) - out.first_frame + 1;
  const int frames_param = parameter_int(out, "POINT", "FRAMES", -1);
  if (frames_param > n_frames) n_frames = frames_param;
  if (n_frames < 1)
    r.fail("header words 4-5 (first, last frame)",
           fmt::format("first frame {}, last frame {}: no frames", out.first_frame, last_frame));
  if (out.analog_per_frame == 0 && analog_total != 0)
    r.fail("header word 10 (analog samples per frame)", fmt::format("0 with {} analog measurements", analog_total));
  out.n_analog_channels = out.analog_per_frame == 0 ? 0 : analog_total / out.analog_per_frame;
  if (out.analog_per_frame != 0 && analog_total % out.analog_per_frame != 0)
    r.fail("header word 3 (analog measurements per frame)",
           fmt::format("{} is not a multiple of {} samples per frame", analog_total, out.analog_per_frame));
  if (const C3dParameter* used = out.find("ANALOG", "USED"); used && !used->numbers.empty()) {
    const int u = parameter_int(out, "ANALOG", "USED", -1);
    if (u != out.n_analog_channels && !(out.n_analog_channels == 0 && u == 0))
      r.fail("ANALOG:USED", fmt::format("{} channels, but the header has {} measurements per frame at {} per channel",
                                        u, analog_total, out.analog_per_frame));
  }
  if (const C3dParameter* used = out.find("POINT", "USED"); used && !used->numbers.empty()) {
    const int u = parameter_int(out, "POINT", "USED", -1);
    if (u != out.n_points)
      r.fail("POINT:USED", fmt::format("{} points, but the header (word 2) says {}", u, out.n_points));
  }

  const std::size_t width = out.float_data ? 4 : 2;
  const std::size_t frame_values =
      4 * static_cast<std::size_t>(out.n_points) + static_cast<std::size_t>(analog_total);
  const std::size_t frame_bytes = frame_values * width;
  if (data_start > bytes.size())
    r.fail("header word 9 (data block)",
           fmt::format("the data would start at byte {}, past the end of the file ({} bytes)", data_start,
                       bytes.size()));
  const std::size_t available = bytes.size() - data_start;
  if (frame_bytes != 0 && static_cast<std::size_t>(n_frames) > available / frame_bytes)
    r.fail("data section",
           fmt::format("{} frames of {} bytes need {} bytes from byte {}, the file has {} (truncated file?)", n_frames,
                       frame_bytes, static_cast<double>(n_frames) * static_cast<double>(frame_bytes), data_start,
                       available));
  out.n_frames = static_cast<int>(n_frames);

  bool analog_unsigned = false;
  if (const C3dParameter* fmt_p = out.find("ANALOG", "FORMAT"); fmt_p && !fmt_p->strings.empty())
    analog_unsigned = upper(fmt_p->strings[0]) == "UNSIGNED";

  out.points.resize(out.n_frames, 4 * out.n_points);
  out.analog_stored.resize(static_cast<Eigen::Index>(out.n_frames) * out.analog_per_frame, out.n_analog_channels);
  if (frame_bytes == 0) return out;  // no points and no analog channels: nothing to read
  read_data_section(r, data_start, frame_bytes, analog_unsigned, out);
  return out;
}

C3dFile read_c3d(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st)) throw InputError(path, 0, 0, "", "file not found");
  if (!fs::is_regular_file(st)) throw InputError(path, 0, 0, "", "not a regular file");
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec) throw InputError(path, 0, 0, "", fmt::format("cannot read its size: {}", ec.message()));
  if (size > kMaxC3dBytes)
    throw InputError(path, 0, 0, "",
                     fmt::format("file of {} bytes, larger than the {} bytes a C3D here may have", size, kMaxC3dBytes));
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError(path, 0, 0, "", "cannot open");
  std::string bytes(static_cast<std::size_t>(size), '\0');
  in.read(bytes.data(), static_cast<std::streamsize>(size));
  if (static_cast<std::uintmax_t>(in.gcount()) != size) throw InputError(path, 0, 0, "", "cannot read the whole file");
  return parse_c3d(bytes, path);
}

Eigen::MatrixXd c3d_analog_scaled(const C3dFile& file, const std::vector<int>& channels_in) {
  std::vector<int> channels = channels_in;
  if (channels.empty())
    for (int c = 0; c < file.n_analog_channels; ++c) channels.push_back(c);
  const C3dParameter* scale = file.find("ANALOG", "SCALE");
  const C3dParameter* offset = file.find("ANALOG", "OFFSET");
  const C3dParameter* gen = file.find("ANALOG", "GEN_SCALE");
  if (!gen || gen->numbers.empty()) throw InputError(file.path, 0, 0, "ANALOG:GEN_SCALE", "missing");
  const double g = gen->numbers[0];
  if (!std::isfinite(g) || g == 0.0) throw InputError(file.path, 0, 0, "ANALOG:GEN_SCALE", fmt::format("{} (must be finite, not 0)", g));
  bool offset_unsigned = false;
  if (const C3dParameter* fmt_p = file.find("ANALOG", "FORMAT"); fmt_p && !fmt_p->strings.empty())
    offset_unsigned = upper(fmt_p->strings[0]) == "UNSIGNED";
  Eigen::MatrixXd out(file.analog_stored.rows(), static_cast<Eigen::Index>(channels.size()));
  for (std::size_t k = 0; k < channels.size(); ++k) {
    const int c = channels[k];
    if (c < 0 || c >= file.n_analog_channels)
      throw InputError(file.path, 0, 0, "ANALOG:USED",
                       fmt::format("channel {} asked for, the file has {} analog channels", c + 1,
                                   file.n_analog_channels));
    if (!scale || static_cast<int>(scale->numbers.size()) <= c)
      throw InputError(file.path, 0, 0, "ANALOG:SCALE", fmt::format("no scale for analog channel {}", c + 1));
    if (!offset || static_cast<int>(offset->numbers.size()) <= c)
      throw InputError(file.path, 0, 0, "ANALOG:OFFSET", fmt::format("no offset for analog channel {}", c + 1));
    const double s = scale->numbers[c];
    double o = offset->numbers[c];
    if (offset_unsigned && o < 0) o += 65536.0;
    if (!std::isfinite(s))
      throw InputError(file.path, 0, 0, "ANALOG:SCALE", fmt::format("channel {}: {} is not finite", c + 1, s));
    out.col(static_cast<Eigen::Index>(k)) = (file.analog_stored.col(c).array() - o) * (s * g);
    if (!out.col(static_cast<Eigen::Index>(k)).allFinite())
      throw InputError(file.path, 0, 0, "ANALOG:SCALE",
                       fmt::format("channel {}: scale {} x {} overflows to an infinite value", c + 1, s, g));
  }
  return out;
}

}  // namespace dropfit::capture
