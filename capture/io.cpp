// Readers and writers of the session format; see capture/io.h for the
// conventions and shared/spec/session-format.md for the contract.
// The other formats live in capture/*_io.cpp; this file holds the force-plate exports.
#include "capture/io.h"

#include <fmt/format.h>

#include <array>
#include <cmath>
#include <filesystem>

#include "capture/force_internal.h"
#include "capture/force_io.h"
#include "capture/text_io.h"
#include "core/error.h"

namespace dropfit::capture {
namespace {

using namespace detail;
namespace fs = std::filesystem;

constexpr std::array<const char*, 8> kEightChannels = {"Fx12", "Fx34", "Fy14", "Fy23", "Fz1", "Fz2", "Fz3", "Fz4"};
constexpr std::array<const char*, 8> kResultants = {"Fx", "Fy", "Fz", "Mx", "My", "Mz", "Ax", "Ay"};

// force.txt and force.c3d: capture/force_kistler.cpp, force_bioware.cpp, force_c3d.cpp.

}  // namespace

int trigger_sample_from_fraction(double pretrigger_fraction, int n_samples) {
  return static_cast<int>(std::lround(pretrigger_fraction * static_cast<double>(n_samples)));
}

ForceRecord read_force(const std::string& path, const ForcePlateSpec& plate) {
  const std::string ext = fs::path(path).extension().string();
  if (iequals(ext, ".c3d")) return read_force_c3d(path, plate);
  const std::vector<Line> lines = read_text_lines(path);
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
