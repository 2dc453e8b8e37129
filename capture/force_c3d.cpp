// Force plates and markers from C3D files (capture/force_io.h).
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <limits>
#include <optional>

#include "capture/force_internal.h"
#include "capture/force_io.h"
#include "capture/io.h"
#include "core/error.h"

namespace dropfit::capture {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

[[noreturn]] void fail(const C3dFile& f, const std::string& field, const std::string& reason) {
  throw InputError(f.path, 0, 0, field, reason);
}

const C3dParameter& need(const C3dFile& f, const char* group, const char* name) {
  const C3dParameter* p = f.find(group, name);
  if (!p) fail(f, fmt::format("{}:{}", group, name), "missing parameter");
  return *p;
}

// Metres per unit of POINT:UNITS (mm when absent).
double point_unit_m(const C3dFile& f) {
  const C3dParameter* p = f.find("POINT", "UNITS");
  if (!p || p->strings.empty() || p->strings[0].empty()) return 1e-3;
  const std::string u = lower(p->strings[0]);
  if (u == "mm") return 1e-3;
  if (u == "cm") return 1e-2;
  if (u == "m") return 1.0;
  fail(f, "POINT:UNITS", fmt::format("unit '{}' is not known (expected mm, cm or m)", p->strings[0]));
}

// SI per unit of an analog channel's ANALOG:UNITS: forces N or kN, moments
// N.m or N.mm. A force channel without units is taken as N (the raw
// Kistler channels); a moment channel must say which.
double analog_unit_si(const C3dFile& f, int channel, bool moment) {
  const C3dParameter* p = f.find("ANALOG", "UNITS");
  std::string u;
  if (p && channel < static_cast<int>(p->strings.size())) u = p->strings[channel];
  std::string compact;
  for (char c : lower(u))
    if (c != ' ' && c != '.' && c != '*' && c != '-') compact += c;
  if (!moment) {
    if (compact.empty() || compact == "n") return 1.0;
    if (compact == "kn") return 1e3;
  } else {
    if (compact == "nm") return 1.0;
    if (compact == "nmm") return 1e-3;
    if (compact.empty())
      fail(f, "ANALOG:UNITS",
           fmt::format("analog channel {} (a moment) has no unit: N.m or N.mm cannot be told apart", channel + 1));
  }
  fail(f, "ANALOG:UNITS",
       fmt::format("unit '{}' of analog channel {} is not known for a {} (expected {})", u, channel + 1,
                   moment ? "moment" : "force", moment ? "N.m or N.mm" : "N or kN"));
}

}  // namespace

ForceRecord force_record_from_c3d(const C3dFile& f, const ForcePlateSpec& spec) {
  const C3dParameter& used_p = need(f, "FORCE_PLATFORM", "USED");
  if (used_p.numbers.empty()) fail(f, "FORCE_PLATFORM:USED", "has no value");
  const double used_v = used_p.numbers[0];
  if (!(used_v >= 1.0) || used_v > 255.0 || used_v != std::floor(used_v))
    fail(f, "FORCE_PLATFORM:USED", fmt::format("{}: the file has no force plate", used_v));
  const int used = static_cast<int>(used_v);
  if (spec.plate < 1 || spec.plate > used)
    fail(f, "FORCE_PLATFORM:USED",
         fmt::format("the manifest's forceplate.plate = {}, the file has {} plate{}", spec.plate, used,
                     used == 1 ? "" : "s"));
  const int k = spec.plate - 1;
  const C3dParameter& type_p = need(f, "FORCE_PLATFORM", "TYPE");
  if (static_cast<int>(type_p.numbers.size()) <= k)
    fail(f, "FORCE_PLATFORM:TYPE", fmt::format("no type for plate {}", spec.plate));
  const double type = type_p.numbers[k];
  if (type != 2.0 && type != 3.0)
    fail(f, "FORCE_PLATFORM:TYPE",
         fmt::format("plate {} is of type {}; only types 2 (six resultants) and 3 (eight Kistler channels) are read",
                     spec.plate, type));
  const int n_ch = type == 3.0 ? 8 : 6;
  const C3dParameter& chan_p = need(f, "FORCE_PLATFORM", "CHANNEL");
  const int rows = chan_p.dims.empty() ? 1 : chan_p.dims[0];
  if (rows < n_ch || static_cast<int>(chan_p.numbers.size()) < rows * (k + 1))
    fail(f, "FORCE_PLATFORM:CHANNEL",
         fmt::format("plate {} of type {} needs {} channels, the parameter has {} per plate ({} values)", spec.plate,
                     type, n_ch, rows, chan_p.numbers.size()));
  std::vector<int> channels;
  for (int c = 0; c < n_ch; ++c) {
    const double ch = chan_p.numbers[static_cast<std::size_t>(k) * rows + c];
    if (ch < 1.0 || ch > f.n_analog_channels || ch != std::floor(ch))
      fail(f, "FORCE_PLATFORM:CHANNEL",
           fmt::format("plate {} channel {} is analog channel {}, the file has {} analog channels", spec.plate, c + 1,
                       ch, f.n_analog_channels));
    channels.push_back(static_cast<int>(ch) - 1);
  }
  const C3dParameter& origin_p = need(f, "FORCE_PLATFORM", "ORIGIN");
  if (static_cast<int>(origin_p.numbers.size()) < 3 * (k + 1))
    fail(f, "FORCE_PLATFORM:ORIGIN", fmt::format("no origin for plate {}", spec.plate));
  const double unit = point_unit_m(f);
  Eigen::Vector3d origin;
  for (int i = 0; i < 3; ++i) {
    origin[i] = unit * origin_p.numbers[static_cast<std::size_t>(3 * k + i)];
    if (!std::isfinite(origin[i])) fail(f, "FORCE_PLATFORM:ORIGIN", fmt::format("plate {}: not finite", spec.plate));
  }

  const double rate = f.analog_rate_hz();
  if (!(rate > 0.0) || !std::isfinite(rate)) fail(f, "ANALOG:RATE", fmt::format("{} Hz (must be positive)", rate));
  if (std::abs(rate - spec.sample_rate_hz) > 1e-6 * spec.sample_rate_hz)
    fail(f, "ANALOG:RATE",
         fmt::format("analog rate {} Hz disagrees with the manifest's forceplate.sample_rate_hz = {} Hz", rate,
                     spec.sample_rate_hz));
  Eigen::MatrixXd data = c3d_analog_scaled(f, channels);
  const Eigen::Index n = data.rows();
  if (n < 2) fail(f, "data section", fmt::format("{} analog samples: not a force record", n));

  ForceRecord rec;
  rec.sample_rate_hz = rate;
  const auto set_times = [&] {
    detail::set_trigger(rec, spec, f.path);
    rec.t_s = (Eigen::VectorXd::LinSpaced(n, 0.0, static_cast<double>(n - 1)).array() - rec.pretrigger_samples) / rate;
  };
  if (type == 3.0) {
    for (int c = 0; c < 8; ++c) data.col(c) *= analog_unit_si(f, channels[c], false);
    rec.layout = ForceLayout::EightChannel;
    rec.data = std::move(data);
    const double a = std::abs(origin[0]), b = std::abs(origin[1]), az0 = -std::abs(origin[2]);
    if (a == 0.0 || b == 0.0)
      fail(f, "FORCE_PLATFORM:ORIGIN", fmt::format("plate {}: a = {} m, b = {} m (sensor offsets must not be 0)",
                                                   spec.plate, a, b));
    rec.plate_geometry_m = Eigen::Vector3d(a, b, az0);
  } else {
    for (int c = 0; c < 6; ++c) data.col(c) *= analog_unit_si(f, channels[c], c >= 3);
    // ORIGIN is the vector from the transducer origin to the centre of the
    // top surface (C3D guide), so the transducer is at -ORIGIN from the centre.
    const double ox = -origin[0], oy = -origin[1];
    rec.layout = ForceLayout::Resultants;
    rec.data.resize(n, 8);
    rec.data.leftCols(3) = data.leftCols(3);
    // Moments about the point (0, 0, oz) under the plate centre.
    rec.data.col(3) = data.col(3) + oy * data.col(2);
    rec.data.col(4) = data.col(4) - ox * data.col(2);
    rec.data.col(5) = data.col(5) + ox * data.col(1) - oy * data.col(0);
    rec.data.rightCols(2).setConstant(kNaN);
    rec.plate_geometry_m = Eigen::Vector3d(kNaN, kNaN, -std::abs(origin[2]));
  }
  set_times();
  return rec;
}

ForceRecord read_force_c3d(const std::string& path, const ForcePlateSpec& plate) {
  return force_record_from_c3d(read_c3d(path), plate);
}

MarkerTrajectories markers_from_c3d(const C3dFile& f, const std::vector<std::string>& points) {
  const C3dParameter* labels = f.find("POINT", "LABELS");
  if (!labels) fail(f, "POINT:LABELS", "missing parameter: the points cannot be named");
  const double unit = point_unit_m(f);
  MarkerTrajectories out;
  out.points = points;
  out.frame_rate_hz = f.point_rate_hz;
  out.first_frame = f.first_frame;
  out.xyz_m.resize(f.n_frames, 3 * static_cast<Eigen::Index>(points.size()));
  const int n_labels = std::min(static_cast<int>(labels->strings.size()), f.n_points);
  for (std::size_t p = 0; p < points.size(); ++p) {
    int found = -1;
    for (int i = 0; i < n_labels; ++i) {
      if (lower(labels->strings[i]) != lower(points[p])) continue;
      if (found >= 0)
        fail(f, "POINT:LABELS", fmt::format("point '{}' is labelled twice (points {} and {})", points[p], found + 1,
                                            i + 1));
      found = i;
    }
    if (found < 0)
      fail(f, "POINT:LABELS", fmt::format("point '{}' is not among the file's {} labelled points", points[p], n_labels));
    for (int k = 0; k < 3; ++k)
      out.xyz_m.col(static_cast<Eigen::Index>(3 * p + k)) = unit * f.points.col(4 * found + k);
  }
  return out;
}

MarkerTrajectories read_markers_c3d(const std::string& path, const std::vector<std::string>& points) {
  return markers_from_c3d(read_c3d(path), points);
}

}  // namespace dropfit::capture
