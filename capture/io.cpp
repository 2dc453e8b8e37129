// Readers and writers of the session format; see capture/io.h for the
// conventions and docs/formats.md for the contract.
// The other formats live in capture/*_io.cpp; this file holds the force-plate exports.
#include "capture/io.h"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <limits>
#include <optional>
#include <vector>

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

std::optional<DataTrigger> trigger_sample_from_data(const ForceRecord& record, double threshold_n) {
  const Eigen::Index n = record.data.rows();
  constexpr Eigen::Index kWindow = 50;
  if (n < 2 * kWindow || record.data.cols() < 8) return std::nullopt;
  Eigen::VectorXd fz = record.layout == ForceLayout::EightChannel ? Eigen::VectorXd(record.data.rightCols(4).rowwise().sum())
                                                                  : Eigen::VectorXd(record.data.col(2));
  Eigen::Index peak = -1;
  for (Eigen::Index i = 0; i < n; ++i)
    if (std::isfinite(fz(i)) && (peak < 0 || fz(i) > fz(peak))) peak = i;
  if (peak < kWindow) return std::nullopt;
  // Window spreads before the peak from running sums (NaN samples count as
  // spread: a window holding one is never quiet).
  std::vector<double> s1(static_cast<std::size_t>(peak) + 1, 0.0), s2(s1.size(), 0.0);
  std::vector<int> bad(s1.size(), 0);
  for (Eigen::Index i = 0; i < peak; ++i) {
    const bool ok = std::isfinite(fz(i));
    s1[i + 1] = s1[i] + (ok ? fz(i) : 0.0);
    s2[i + 1] = s2[i] + (ok ? fz(i) * fz(i) : 0.0);
    bad[i + 1] = bad[i] + (ok ? 0 : 1);
  }
  auto spread = [&](Eigen::Index s) {
    if (bad[s + kWindow] - bad[s] > 0) return std::numeric_limits<double>::infinity();
    const double mean = (s1[s + kWindow] - s1[s]) / kWindow;
    return std::sqrt(std::max(0.0, (s2[s + kWindow] - s2[s]) / kWindow - mean * mean));
  };
  auto mean_of = [&](Eigen::Index s) { return (s1[s + kWindow] - s1[s]) / kWindow; };
  // Quiet stretches: windows well below the peak, within twice the least
  // spread (at least 1 N: quantised records).
  double least = std::numeric_limits<double>::infinity();
  for (Eigen::Index s = 0; s + kWindow <= peak; ++s)
    if (mean_of(s) + threshold_n < fz(peak)) least = std::min(least, spread(s));
  if (!std::isfinite(least)) return std::nullopt;
  const double allowed = std::max(2.0 * least, 1.0);
  auto quiet_window = [&](Eigen::Index s) { return mean_of(s) + threshold_n < fz(peak) && spread(s) <= allowed; };
  auto crossing_after = [&](Eigen::Index s) -> std::optional<DataTrigger> {
    std::vector<double> w(fz.data() + s, fz.data() + s + kWindow);
    std::nth_element(w.begin(), w.begin() + kWindow / 2, w.end());
    const double level = w[kWindow / 2];
    for (Eigen::Index i = s + kWindow; i <= peak; ++i)
      if (fz(i) - level > threshold_n) return DataTrigger{static_cast<int>(i), level};
    return std::nullopt;
  };
  // A record that starts quiet: the first crossing after its start, where
  // the acquisition triggered (a drop jump's first landing, not its larger
  // second one).
  if (quiet_window(0)) return crossing_after(0);
  // A record that starts loaded or swaying: the quiet stretch just before
  // the impact.
  Eigen::Index quiet = -1;
  for (Eigen::Index s = 0; s + kWindow <= peak; ++s)
    if (quiet_window(s)) quiet = s;
  return crossing_after(quiet);
}

namespace detail {
void set_trigger(ForceRecord& rec, const ForcePlateSpec& plate, const std::string& path) {
  const int n = static_cast<int>(rec.data.rows());
  if (plate.pretrigger_fraction) {
    rec.pretrigger_samples = std::min(trigger_sample_from_fraction(*plate.pretrigger_fraction, n), n - 1);
    rec.trigger = fmt::format("sample {} from forceplate.pretrigger_fraction = {}", rec.pretrigger_samples,
                              *plate.pretrigger_fraction);
    return;
  }
  const std::optional<DataTrigger> t = trigger_sample_from_data(rec, plate.trigger_threshold_n);
  if (!t)
    throw InputError(path, 0, 0, "Fz",
                     fmt::format("the export carries no trigger and Fz never rises {} N (forceplate."
                                 "trigger_threshold_n) above a quiet level before its peak: no impact to align on "
                                 "(or give forceplate.pretrigger_fraction)",
                                 plate.trigger_threshold_n));
  rec.pretrigger_samples = t->sample;
  rec.trigger = fmt::format("sample {} from the data: Fz {} N above its quiet level {:.1f} N", t->sample,
                            plate.trigger_threshold_n, t->quiet_level_n);
  rec.trigger_from_data = true;
}
}  // namespace detail

int trigger_sample_from_fraction(double pretrigger_fraction, int n_samples) {
  return static_cast<int>(std::lround(pretrigger_fraction * static_cast<double>(n_samples)));
}

ForceRecord read_force(const std::string& path, const ForcePlateSpec& plate) {
  const std::string ext = fs::path(path).extension().string();
  if (iequals(ext, ".c3d") || force_file_kind(path) == ForceFileKind::C3d) return read_force_c3d(path, plate);
  // The header is read first; the data rows are parsed as they are read.
  LineStream stream(path);
  const ForceTextHead head = read_force_text_head(path, stream);
  return head.bioware ? read_bioware(path, head, stream, plate) : read_eight_channel(path, head, stream, plate);
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
