// Force plate numbers. Methods:
//
// Zero offset: the plate is zeroed with the mat resting on it, so Fz is
// about zero before contact; what remains (amplifier drift, a re-zero done
// slightly off) is the trimmed mean of each resultant over the quiet part,
// the pre-trigger samples ending quiet_guard_s before the declared trigger
// sample (and, on a second pass, before the found contact onset): median,
// then the mean of the samples within 3.5 robust SDs (1.4826 MAD) of it, so
// that a spike or the first few newtons of a slow rise do not move it. The
// noise SD is the SD of those Fz samples.
//
// Trigger: the first sample whose zeroed Fz reaches the threshold, with the
// crossing instant interpolated linearly between it and the sample before.
//
// Contact onset: the rise of a mat's ground force starts well below the
// trigger level. j = the last sample before the crossing within
// onset_band_sd noise SDs of zero; the samples after it up to the first one
// at 10 % of the peak (at least twice the threshold; at most 60 samples) are
// the initial rise. Onset t0 is found by extrapolating that rise to zero
// with a power law: least squares of F = c max(t - t0, 0)^p over the rise
// and as many in-band samples before it (at least 10; the model must leave
// them near zero), for p in {1, 1.25, 1.5, 1.75, 2, 2.5, 3} (a damped
// contact rises linearly, Hertz-like contact as t^1.5, a contact through a
// layer's mass as t^2 or t^3) and t0 on a grid refined to about 1/200 of the
// searched span. A linear extrapolation alone would put a convex rise's
// onset late by about half the time the force takes to leave the noise band.
//
// Peak: the largest zeroed Fz, refined by the parabola through it and its
// neighbours. End of contact: the first sample after the peak back within
// the noise band, the instant interpolated at the band's edge.
//
// Saturation: a channel at or beyond the amplifier range (when given), or a
// channel that holds its extreme value flat, within its noise, for several
// samples after arriving at it and before leaving it steeply (a smooth peak
// turns gradually; a clipped one does not; check_flat_tops).
//
// Channel consistency (eight-channel records): the four vertical sensors
// hold a rigid plate, whose deflections lie in one plane, so for equal
// sensors the twist Fz1 - Fz2 + Fz3 - Fz4 is zero wherever the load stands
// and each sensor's share of Fz is the one the centre of pressure implies,
// (1 +- ax / a +- ay / b) / 4. A dead or stuck sensor (share 0), a sign
// reversal (negative share), or a shear column exchanged with a vertical one
// gives a twist of a third of Fz or more; a few per cent of sensor mismatch
// gives a few per cent. A vertical drop has shear of a few per cent of Fz
// (the impactor's tilt), so a shear channel carrying a vertical load shows
// too. Either beyond its bound (12 % twist, 25 % shear) rejects the record,
// naming the suspect channels.
#include "core/median.h"
#include "forceplate/forceplate.h"

#include <fmt/format.h>

#include <Eigen/QR>
#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <vector>

#include "core/error.h"
#include "core/validate.h"

namespace dropfit::forceplate {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Consistency bounds of an eight-channel record under a drop's load
// (ProcessOptions::check_channels).
constexpr double kMaxTwistFraction = 0.12;
constexpr double kMaxShearFraction = 0.25;


struct RobustLevel {
  double mean = 0.0;
  double sd = 0.0;
};

// Trimmed mean and SD: samples within 3.5 robust SDs of the median.
RobustLevel robust_level(const Eigen::VectorXd& x) {
  std::vector<double> v(x.data(), x.data() + x.size());
  const double med = median(v);
  std::vector<double> dev(v.size());
  for (std::size_t i = 0; i < v.size(); ++i) dev[i] = std::abs(v[i] - med);
  const double sigma = 1.4826 * median(dev);
  double sum = 0.0, sum2 = 0.0;
  int n = 0;
  for (double value : v) {
    if (std::abs(value - med) <= 3.5 * sigma) {
      sum += value;
      sum2 += value * value;
      ++n;
    }
  }
  if (n < 2 || sigma == 0.0) {
    // Quantised or constant: the plain mean and SD of all samples.
    const double mean = x.mean();
    const double sd = x.size() > 1 ? std::sqrt((x.array() - mean).square().sum() / (x.size() - 1)) : 0.0;
    return {mean, sd};
  }
  const double mean = sum / n;
  const double var = std::max(0.0, (sum2 - n * mean * mean) / (n - 1));
  return {mean, std::sqrt(var)};
}

std::string channel_name(const Resultants& raw, Eigen::Index c) {
  return c < static_cast<Eigen::Index>(raw.channel_names.size()) ? raw.channel_names[c] : fmt::format("{}", c + 1);
}

void check_no_nan(const Eigen::MatrixXd& data, int columns, const std::vector<std::string>& names) {
  for (int c = 0; c < columns; ++c) {
    for (Eigen::Index i = 0; i < data.rows(); ++i) {
      if (!std::isfinite(data(i, c))) {
        throw Error(fmt::format("force record: channel {} is missing a value (NaN) at sample {}", names[c], i));
      }
    }
  }
}

// Throws when a channel reaches the amplifier range given in the options.
void check_range(const Resultants& raw, const ProcessOptions& options) {
  if (!(options.saturation_n > 0.0)) return;
  const Eigen::MatrixXd& x = raw.channels_n;
  for (Eigen::Index c = 0; c < x.cols(); ++c) {
    Eigen::Index at = 0;
    const double extreme = x.col(c).cwiseAbs().maxCoeff(&at);
    if (extreme >= options.saturation_n) {
      throw Error(fmt::format("force record: channel {} saturated ({:.1f} N at sample {}, range {:.1f} N)",
                              channel_name(raw, c), extreme, at, options.saturation_n));
    }
  }
}

// Throws when a channel has a flat top (see the file comment). Each
// channel's zero and noise SD come from the quiet samples [0, quiet_end).
// The top is the run of consecutive samples within 8 noise SDs of the
// channel's extreme (a clipped amplifier adds its ADC noise after the clip,
// so the clipped samples scatter by a few SDs about one value). A smooth
// peak stays within that band for R samples only because it turns there:
// a parabola that does enters and leaves it at about 4 band / R per sample.
// A clipped channel arrives at and leaves its rail at the signal's own
// slope, several times that; so R >= saturation_flat_samples with both
// shoulders at least 3 times the parabola's slope (and 1 % of the extreme
// per sample, for noiseless rails) is a flat top.
// A clipped amplifier stops following the load; the plate's other loaded
// channels do not. Over the flat run [first, end) of channel c, the sum of
// the other channels loaded in the same sense (beyond 20 noise SDs) must
// move by more than three times the flat channel's own relative band: a
// load that plateaus (a mat's force holding at its peak) flattens every
// channel alike, and is no saturation. With no other loaded channel (a
// resultant-only record) the shape alone decides.
bool load_keeps_moving(const Eigen::MatrixXd& x, Eigen::Index c, Eigen::Index first, Eigen::Index end, int quiet_end,
                       double relative_band) {
  Eigen::VectorXd load = Eigen::VectorXd::Zero(end - first);
  int others = 0;
  for (Eigen::Index k = 0; k < x.cols(); ++k) {
    if (k == c) continue;
    const RobustLevel zero = robust_level(x.col(k).head(quiet_end));
    Eigen::VectorXd y = x.col(k).array() - zero.mean;
    if (-y.minCoeff() > y.maxCoeff()) y = -y;
    if (y.maxCoeff() <= 20.0 * zero.sd || y.segment(first, end - first).minCoeff() <= 20.0 * zero.sd) continue;
    load += y.segment(first, end - first);
    ++others;
  }
  if (others == 0) return true;
  const double top = load.maxCoeff();
  return top > 0.0 && (top - load.minCoeff()) / top > 3.0 * relative_band;
}

void check_flat_tops(const Resultants& raw, int quiet_end, const ProcessOptions& options) {
  const int flat = options.saturation_flat_samples;
  if (flat <= 1) return;
  const Eigen::MatrixXd& x = raw.channels_n;
  const Eigen::Index n = x.rows();
  // The vertical channels carry the mat's force: a clipped one is a wrong
  // force. A shear channel's flat stretch is as often the foot or impactor
  // holding still on the mat (friction), so the shape is judged on Fz only
  // where the record names its channels.
  bool named_vertical = false;
  for (const auto& name : raw.channel_names) named_vertical = named_vertical || name.rfind("Fz", 0) == 0;
  for (Eigen::Index c = 0; c < x.cols(); ++c) {
    if (named_vertical && channel_name(raw, c).rfind("Fz", 0) != 0) continue;
    const RobustLevel zero = robust_level(x.col(c).head(quiet_end));
    Eigen::VectorXd y = x.col(c).array() - zero.mean;
    if (-y.minCoeff() > y.maxCoeff()) y = -y;  // the sign the channel is loaded in
    Eigen::Index at = 0;
    const double extreme = y.maxCoeff(&at);
    if (extreme <= std::max(options.trigger_threshold_n, 20.0 * zero.sd)) continue;
    const double band = std::max(8.0 * zero.sd, 1e-6 * extreme);
    Eigen::Index first = at, end = at + 1;  // the run about the extreme: [first, end)
    while (first > 0 && y[first - 1] >= extreme - band) --first;
    while (end < n && y[end] >= extreme - band) ++end;
    const Eigen::Index run = end - first;
    if (run < flat) continue;
    const double smooth = 4.0 * band / static_cast<double>(run) * (1.0 + 3.0 / static_cast<double>(run));
    const double steep = std::max(3.0 * smooth, 0.01 * extreme);
    const double in = first >= 3 ? (y[first] - y[first - 3]) / 3.0 : kNaN;
    const double out = end + 2 < n ? (y[end - 1] - y[end + 2]) / 3.0 : kNaN;
    const bool steep_in = std::isfinite(in) && in >= steep;
    const bool steep_out = !std::isfinite(out) || out >= steep;
    if (steep_in && steep_out && !load_keeps_moving(x, c, first, end, quiet_end, band / extreme)) continue;
    if (steep_in && steep_out) {
      throw Error(fmt::format(
          "force record: channel {} saturated (flat at {:.1f} N for samples {}-{}, {} samples within {:.1f} N, "
          "arriving at {:.0f} N and leaving at {:.0f} N per sample): the clipped part is not the mat's force",
          channel_name(raw, c), x(at, c), first, end - 1, run, band, in, std::isfinite(out) ? out : 0.0));
    }
  }
}

struct Onset {
  double t0_s = 0.0;
  int last_in_band = 0;
};

// Power-law extrapolation of the initial rise to zero (file comment).
Onset find_onset(const Eigen::VectorXd& t, const Eigen::VectorXd& fz, int crossing, double band_n,
                 double upper_n) {
  const int n = static_cast<int>(fz.size());
  int j = crossing - 1;
  while (j >= 0 && fz[j] > band_n) --j;
  if (j < 0) {
    throw Error("force record: Fz is above zero from the start of the record to the trigger (no quiet part)");
  }
  const int first_above = j + 1;
  int last = first_above;
  while (last + 1 < n && fz[last] < upper_n && last - first_above < 60) ++last;
  // As many in-band samples before the rise as in it (at least 10): a slow
  // rise spends many samples inside the noise band.
  const int first = std::max(0, first_above - std::max(10, last - first_above + 1));
  const double dt = (t[n - 1] - t[0]) / (n - 1);

  // Work in samples from t[first_above] for conditioning.
  std::vector<double> u, f;
  double sff = 0.0;
  for (int k = first; k <= last; ++k) {
    u.push_back((t[k] - t[first_above]) / dt);
    f.push_back(fz[k]);
    sff += fz[k] * fz[k];
  }
  auto rss_at = [&](double u0, double p) {
    double sfg = 0.0, sgg = 0.0;
    for (std::size_t k = 0; k < u.size(); ++k) {
      const double d = u[k] - u0;
      if (d <= 0.0) continue;
      const double g = p == 1.0 ? d : std::pow(d, p);
      sfg += f[k] * g;
      sgg += g * g;
    }
    if (sgg <= 0.0 || sfg <= 0.0) return std::numeric_limits<double>::infinity();
    return sff - sfg * sfg / sgg;
  };
  const double lo = u.front();
  const double hi = 0.0;  // the first above-band sample is already in contact
  const double coarse = (hi - lo) / 100.0;
  double best_rss = std::numeric_limits<double>::infinity();
  double best_u0 = (t[j] - t[first_above]) / dt;
  for (double p : {1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0}) {
    double u_best = lo, r_best = std::numeric_limits<double>::infinity();
    for (int k = 0; k < 100; ++k) {
      const double u0 = lo + k * coarse;
      const double r = rss_at(u0, p);
      if (r < r_best) r_best = r, u_best = u0;
    }
    const double from = std::max(lo, u_best - coarse), to = std::min(hi, u_best + coarse);
    for (int k = 0; k <= 40; ++k) {
      const double u0 = std::min(from + k * (to - from) / 40.0, hi - 1e-6);
      const double r = rss_at(u0, p);
      if (r < r_best) r_best = r, u_best = u0;
    }
    if (r_best < best_rss) best_rss = r_best, best_u0 = u_best;
  }
  return {t[first_above] + best_u0 * dt, j};
}

}  // namespace

const std::vector<std::string>& eight_channel_names() {
  static const std::vector<std::string> names{"Fx12", "Fx34", "Fy14", "Fy23", "Fz1", "Fz2", "Fz3", "Fz4"};
  return names;
}

Eigen::MatrixXd centre_of_pressure(const Eigen::MatrixXd& f_n, const Eigen::MatrixXd& m_n_m, double az0_m,
                                   double cop_min_fz_n) {
  const Eigen::Index n = f_n.rows();
  Eigen::MatrixXd cop(n, 2);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double fz = f_n(i, 2);
    if (std::abs(fz) >= cop_min_fz_n && fz != 0.0) {
      cop(i, 0) = (f_n(i, 0) * az0_m - m_n_m(i, 1)) / fz;
      cop(i, 1) = (f_n(i, 1) * az0_m + m_n_m(i, 0)) / fz;
    } else {
      cop(i, 0) = cop(i, 1) = kNaN;
    }
  }
  return cop;
}

Resultants from_eight_channels(const Eigen::VectorXd& t_s, const Eigen::MatrixXd& channels,
                               const PlateGeometry& plate, double cop_min_fz_n) {
  if (channels.cols() != 8) {
    throw Error(fmt::format("force record: expected 8 channels (Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4), got {}",
                            channels.cols()));
  }
  if (t_s.size() != channels.rows()) {
    throw Error(fmt::format("force record: {} times for {} samples", t_s.size(), channels.rows()));
  }
  check_no_nan(channels, 8, eight_channel_names());
  const double a = plate.a_m, b = plate.b_m;
  const auto fx12 = channels.col(0), fx34 = channels.col(1), fy14 = channels.col(2), fy23 = channels.col(3);
  const auto fz1 = channels.col(4), fz2 = channels.col(5), fz3 = channels.col(6), fz4 = channels.col(7);
  Resultants r;
  r.t_s = t_s;
  r.f_n.resize(channels.rows(), 3);
  r.m_n_m.resize(channels.rows(), 3);
  r.f_n.col(0) = fx12 + fx34;
  r.f_n.col(1) = fy14 + fy23;
  r.f_n.col(2) = fz1 + fz2 + fz3 + fz4;
  r.m_n_m.col(0) = b * (fz1 + fz2 - fz3 - fz4);
  r.m_n_m.col(1) = a * (-fz1 + fz2 + fz3 - fz4);
  r.m_n_m.col(2) = b * (-fx12 + fx34) + a * (fy14 - fy23);
  r.az0_m = plate.az0_m;
  r.cop_m = centre_of_pressure(r.f_n, r.m_n_m, plate.az0_m, cop_min_fz_n);
  r.channels_n = channels;
  r.channel_names = eight_channel_names();
  return r;
}

Resultants from_resultant_columns(const Eigen::VectorXd& t_s, const Eigen::MatrixXd& columns,
                                  double cop_min_fz_n, double az0_m) {
  if (columns.cols() < 8) {
    throw Error(fmt::format("force record: expected the columns Fx Fy Fz Mx My Mz Ax Ay, got {} columns",
                            columns.cols()));
  }
  if (t_s.size() != columns.rows()) {
    throw Error(fmt::format("force record: {} times for {} samples", t_s.size(), columns.rows()));
  }
  static const std::vector<std::string> names{"Fx", "Fy", "Fz", "Mx", "My", "Mz"};
  Resultants r;
  std::vector<int> present;
  for (int c = 0; c < 6; ++c) {
    if (columns.rows() > 0 && columns.col(c).array().isNaN().all()) {
      if (c == 2) throw Error("force record: no Fz: the ground reaction force is not in the record");
      r.absent.push_back(names[c]);
    } else {
      present.push_back(c);
    }
  }
  for (int c : present) check_no_nan(columns.col(c), 1, {names[c]});
  r.t_s = t_s;
  r.f_n = columns.leftCols(3);
  r.m_n_m = columns.middleCols(3, 3);
  r.cop_m = columns.middleCols(6, 2);
  for (Eigen::Index i = 0; i < columns.rows(); ++i) {
    if (!(std::abs(r.f_n(i, 2)) >= cop_min_fz_n)) r.cop_m.row(i).setConstant(kNaN);
  }
  auto is_absent = [&](const char* name) { return std::find(r.absent.begin(), r.absent.end(), name) != r.absent.end(); };
  const bool moments_cop = !is_absent("Fx") && !is_absent("Fy") && !is_absent("Mx") && !is_absent("My");
  const bool export_cop = !columns.col(6).array().isNaN().all() || !columns.col(7).array().isNaN().all();
  r.az0_m = moments_cop ? az0_m : kNaN;
  if (!moments_cop && !export_cop)
    r.cop_unavailable = "the record has neither Fx Fy Mx My nor Ax Ay: no centre of pressure";
  r.channels_n.resize(columns.rows(), static_cast<Eigen::Index>(present.size()));
  for (std::size_t k = 0; k < present.size(); ++k) {
    r.channels_n.col(static_cast<Eigen::Index>(k)) = columns.col(present[k]);
    r.channel_names.push_back(names[present[k]]);
  }
  return r;
}

namespace {

// Whether resultant column c (Fx Fy Fz Mx My Mz) is absent from the record.
bool column_absent(const Resultants& raw, int c) {
  static const char* const names[6] = {"Fx", "Fy", "Fz", "Mx", "My", "Mz"};
  return std::find(raw.absent.begin(), raw.absent.end(), names[c]) != raw.absent.end();
}

// The record's shape, values, clock and saturation (process); returns the
// sample spacing.
double check_record(const Resultants& raw, const ProcessOptions& options) {
  const Eigen::Index n_rows = raw.f_n.rows();
  if (n_rows < 8 || raw.f_n.cols() != 3 || raw.m_n_m.rows() != n_rows || raw.m_n_m.cols() != 3 ||
      raw.t_s.size() != n_rows) {
    throw Error(fmt::format("force record: malformed resultants ({} samples)", n_rows));
  }
  const int n = static_cast<int>(n_rows);
  if (column_absent(raw, 2)) throw Error("force record: no Fz: the ground reaction force is not in the record");
  static const std::vector<std::string> names{"Fx", "Fy", "Fz", "Mx", "My", "Mz"};
  for (int c = 0; c < 6; ++c) {
    if (column_absent(raw, c)) continue;
    check_no_nan(c < 3 ? raw.f_n.col(c) : raw.m_n_m.col(c - 3), 1, {names[c]});
  }
  for (int i = 1; i < n; ++i) {
    if (!(raw.t_s[i] > raw.t_s[i - 1])) {
      throw Error(fmt::format("force record: time does not increase at sample {}", i));
    }
  }
  const double dt = (raw.t_s[n - 1] - raw.t_s[0]) / (n - 1);
  if (options.sample_rate_hz > 0.0 && std::abs(dt * options.sample_rate_hz - 1.0) > 0.01) {
    throw Error(fmt::format("force record: samples are {:.6f} s apart, but the sample rate is {} Hz", dt,
                            options.sample_rate_hz));
  }
  if (raw.channels_n.size() > 0) check_range(raw, options);
  return dt;
}

// Zero offset and noise from the quiet part [0, quiet_end), and the zeroed
// plate on the force clock (0 at sample `declared`), into out.
void zero_plate(const Resultants& raw, int quiet_end, int declared, const ProcessOptions& options, ForceTrial& out) {
  for (int c = 0; c < 6; ++c) {
    if (column_absent(raw, c)) {
      out.offset[c] = kNaN;  // not measured: stays NaN
      continue;
    }
    const Eigen::VectorXd col = c < 3 ? raw.f_n.col(c).head(quiet_end) : raw.m_n_m.col(c - 3).head(quiet_end);
    const RobustLevel level = robust_level(col);
    out.offset[c] = level.mean;
    if (c == 2) out.noise_n = std::max(level.sd, options.min_noise_n);
  }
  out.quiet_samples = quiet_end;
  // A declared amplifier low-pass delays what each sample shows by its group
  // delay: the sample recorded at t shows the load at t - delay.
  const double delay_s = options.lowpass_hz > 0.0 ? butterworth_delay_s(options.lowpass_hz, options.lowpass_order) : 0.0;
  out.plate.t_s = raw.t_s.array() - raw.t_s[declared] - delay_s;
  out.plate.f_n = raw.f_n.rowwise() - out.offset.head<3>().transpose();
  out.plate.m_n_m = raw.m_n_m.rowwise() - out.offset.tail<3>().transpose();
}

// Mains hum: the pre-trigger Fz as a level plus one sinusoid at 50 or 60 Hz
// (least squares). Named when the sinusoid carries most of the pre-trigger
// variance (what is left is the channels' own noise) and its amplitude is
// more than half the trigger threshold, so that it alone, with that noise,
// can cross it. Empty otherwise.
std::string mains_hum_reason(const Eigen::VectorXd& fz, double dt, double threshold_n) {
  const Eigen::Index n = fz.size();
  if (n < 40) return {};
  std::string best;
  double best_explained = 0.0;
  for (double f_hz : {50.0, 60.0}) {
    if (!(2.0 * f_hz * dt < 1.0)) continue;  // above the Nyquist frequency
    Eigen::MatrixXd a(n, 3);
    for (Eigen::Index i = 0; i < n; ++i) {
      const double w = 2.0 * std::numbers::pi * f_hz * dt * static_cast<double>(i);
      a(i, 0) = 1.0, a(i, 1) = std::cos(w), a(i, 2) = std::sin(w);
    }
    const Eigen::Vector3d c = a.colPivHouseholderQr().solve(fz);
    const double total = (fz.array() - fz.mean()).square().sum();
    const double left = (fz - a * c).squaredNorm();
    const double explained = total > 0.0 ? 1.0 - left / total : 0.0;
    const double amplitude = std::hypot(c[1], c[2]);
    if (explained > 0.8 && amplitude > 0.5 * threshold_n && explained > best_explained) {
      best_explained = explained;
      best = fmt::format(
          "mains hum: before the trigger Fz oscillates at {:.0f} Hz with an amplitude of {:.1f} N ({:.0f} % of its "
          "variance; the rest, the channels' noise, {:.1f} N SD)",
          f_hz, amplitude, 100.0 * explained, std::sqrt(left / static_cast<double>(n)));
    }
  }
  return best;
}

// Why a record's trigger is not where it was declared, where the record
// shows it: a load read as tension (the vertical channels' sign reversed,
// e.g. an export in a plate frame whose z points down: a mat only pushes, so
// the zeroed Fz cannot fall far below zero), or a crossing one or two
// samples wide (an electrical glitch: a contact loads the plate for tens of
// milliseconds). Empty when neither.
std::string misplaced_trigger_cause(const Eigen::VectorXd& fz, int crossing, double threshold_n) {
  const double low = fz.minCoeff(), high = fz.maxCoeff();
  if (-low > 4.0 * threshold_n && -low > 2.0 * high) {
    return fmt::format(
        "the zeroed Fz reads down to {:.0f} N and at most {:+.0f} N: the vertical channels read the load as tension "
        "(their sign is reversed, e.g. an export whose z axis points down)",
        low, high);
  }
  const int n = static_cast<int>(fz.size());
  if (crossing >= 0 && crossing + 2 < n && fz[crossing + 2] < threshold_n &&
      (crossing == 0 || fz[crossing - 1] < threshold_n)) {
    return fmt::format(
        "Fz jumps to {:.0f} N at sample {} for {} and is back under {} N after it: a glitch on the force channels, "
        "not a contact",
        fz[crossing], crossing, fz[crossing + 1] < threshold_n ? "one sample" : "two samples", threshold_n);
  }
  return {};
}

// The first sample at or above the trigger threshold (and its interpolated
// time) into out; throws when there is none or it is far from the declared
// trigger sample, with the record's reason where it shows one.
int trigger_crossing(const Eigen::VectorXd& fz, const Eigen::VectorXd& t, double dt, int declared,
                     const ProcessOptions& options, ForceTrial& out) {
  const int n = static_cast<int>(fz.size());
  int crossing = -1;
  for (int i = 0; i < n; ++i) {
    if (fz[i] >= options.trigger_threshold_n) {
      crossing = i;
      break;
    }
  }
  if (crossing < 0) {
    if (std::string cause = misplaced_trigger_cause(fz, crossing, options.trigger_threshold_n); !cause.empty())
      throw Error(fmt::format("force record: no trigger: {}", cause));
    throw Error(fmt::format("force record: no trigger (zeroed Fz never reaches {} N; largest {:.1f} N)",
                            options.trigger_threshold_n, fz.maxCoeff()));
  }
  out.trigger_index = crossing;
  out.trigger_time_s = t[crossing];
  if (crossing > 0) {
    const double f0 = fz[crossing - 1], f1 = fz[crossing];
    out.trigger_time_s = t[crossing - 1] + (options.trigger_threshold_n - f0) / (f1 - f0) * (t[crossing] - t[crossing - 1]);
  }
  if (std::abs(t[crossing]) > options.max_trigger_mismatch_s + 0.5 * dt) {
    if (std::string hum = mains_hum_reason(fz.head(std::min(declared, n)), dt, options.trigger_threshold_n); !hum.empty())
      throw Error(fmt::format("force record: {}: Fz first reaches {} N at sample {} ({:+.1f} ms from the declared "
                              "trigger sample {}) on the hum, not on a contact",
                              hum, options.trigger_threshold_n, crossing, 1e3 * t[crossing], declared));
    if (std::string cause = misplaced_trigger_cause(fz, crossing, options.trigger_threshold_n); !cause.empty())
      throw Error(fmt::format("force record: Fz first reaches {} N at sample {} ({:+.1f} ms from the declared trigger "
                              "sample {}): {}",
                              options.trigger_threshold_n, crossing, 1e3 * t[crossing], declared, cause));
    throw Error(fmt::format(
        "force record: Fz first reaches {} N at sample {} ({:+.1f} ms from the declared trigger sample {}): the "
        "pre-trigger share does not match the record",
        options.trigger_threshold_n, crossing, 1e3 * t[crossing], declared));
  }
  return crossing;
}

// The peak after the crossing (parabolic refinement) and the end of contact
// (Fz back within `band`, interpolated) into out.
void peak_and_end(const Eigen::VectorXd& fz, const Eigen::VectorXd& t, int crossing, double band, double dt,
                  ForceTrial& out) {
  const int n = static_cast<int>(fz.size());
  int ip = crossing;
  for (int i = crossing; i < n; ++i) {
    if (fz[i] > fz[ip]) ip = i;
  }
  out.peak_fz_n = fz[ip];
  out.peak_time_s = t[ip];
  if (ip > 0 && ip + 1 < n) {
    const double ym = fz[ip - 1], y0 = fz[ip], yp = fz[ip + 1];
    const double curv = ym - 2.0 * y0 + yp;
    if (curv < 0.0) {
      const double d = 0.5 * (ym - yp) / curv;
      out.peak_fz_n = y0 - 0.25 * (ym - yp) * d;
      out.peak_time_s = t[ip] + d * dt;
    }
  }
  out.time_to_peak_s = out.peak_time_s - out.contact_time_s;

  out.end_found = false;
  out.end_index = n - 1;
  out.end_time_s = t[n - 1];
  for (int i = ip + 1; i < n; ++i) {
    if (fz[i] <= band) {
      out.end_found = true;
      out.end_index = i;
      const double f0 = fz[i - 1], f1 = fz[i];
      out.end_time_s = t[i - 1] + (f0 - band) / (f0 - f1) * (t[i] - t[i - 1]);
      break;
    }
  }
}

// Centre of pressure of the zeroed resultants and what the record passes on.
void finish_plate(const Resultants& raw, const ProcessOptions& options, ForceTrial& out) {
  const int n = static_cast<int>(raw.f_n.rows());
  if (std::isfinite(raw.az0_m)) {
    out.plate.cop_m = centre_of_pressure(out.plate.f_n, out.plate.m_n_m, raw.az0_m, options.cop_min_fz_n);
  } else {
    out.plate.cop_m = raw.cop_m.rows() == n ? raw.cop_m : Eigen::MatrixXd::Constant(n, 2, kNaN);
    for (int i = 0; i < n; ++i) {
      if (!(std::abs(out.plate.f_n(i, 2)) >= options.cop_min_fz_n)) out.plate.cop_m.row(i).setConstant(kNaN);
    }
  }
  out.plate.az0_m = raw.az0_m;
  out.plate.channels_n = raw.channels_n;
  out.plate.channel_names = raw.channel_names;
  out.plate.absent = raw.absent;
  out.plate.cop_unavailable = raw.cop_unavailable;
  out.absent = raw.absent;
  out.cop_unavailable = raw.cop_unavailable;
}

// Throws when the eight channels of a Kistler record cannot be one rigid
// plate's under the contact (see forceplate.h, ProcessOptions::check_channels).
void check_eight_channels(ForceTrial& trial, int quiet_end) {
  const Eigen::MatrixXd& x = trial.plate.channels_n;
  if (x.cols() != 8 || trial.plate.channel_names != eight_channel_names() || quiet_end < 2) return;
  Eigen::MatrixXd z(x.rows(), 8);  // zeroed on the quiet part
  for (int c = 0; c < 8; ++c) z.col(c) = x.col(c).array() - robust_level(x.col(c).head(quiet_end)).mean;
  const Eigen::VectorXd fz = z.col(4) + z.col(5) + z.col(6) + z.col(7);
  const double peak = trial.peak_fz_n;
  std::vector<int> loaded;  // the contact's samples above 30 % of its peak
  for (int i = trial.contact_index; i <= trial.end_index && i < fz.size(); ++i)
    if (i >= 0 && fz[i] >= 0.3 * peak) loaded.push_back(i);
  if (loaded.size() < 5 || !(peak > 0.0)) return;
  auto median_of = [&](auto&& share) {
    std::vector<double> v;
    for (int i : loaded) v.push_back(share(i));
    return median(v);
  };
  std::array<double, 8> shares{};
  for (int c = 0; c < 8; ++c) shares[c] = median_of([&](int i) { return z(i, c) / fz[i]; });
  const double twist = median_of([&](int i) { return (z(i, 4) - z(i, 5) + z(i, 6) - z(i, 7)) / fz[i]; });
  const double shear_x = median_of([&](int i) { return (z(i, 0) + z(i, 1)) / fz[i]; });
  const double shear_y = median_of([&](int i) { return (z(i, 2) + z(i, 3)) / fz[i]; });
  trial.twist_fraction = twist;
  for (int c = 0; c < 4; ++c) trial.vertical_shares[static_cast<std::size_t>(c)] = shares[static_cast<std::size_t>(c + 4)];
  std::vector<std::string> broken;
  if (std::abs(twist) > kMaxTwistFraction)
    broken.push_back(fmt::format("the vertical sensors' twist Fz1 - Fz2 + Fz3 - Fz4 is {:+.0f} % of Fz (a rigid "
                                 "plate keeps it near 0 wherever the load stands)",
                                 100.0 * twist));
  if (std::max(std::abs(shear_x), std::abs(shear_y)) > kMaxShearFraction)
    broken.push_back(fmt::format("the shear is {:+.0f} % (Fx) and {:+.0f} % (Fy) of Fz (a vertical drop stays "
                                 "within a few per cent)",
                                 100.0 * shear_x, 100.0 * shear_y));
  std::vector<std::string> suspects;
  const auto& names = eight_channel_names();
  for (int c = 4; c < 8; ++c) {
    if (shares[c] < -0.05) suspects.push_back(names[c] + " reads tension (sign reversed?)");
    else if (std::abs(shares[c]) < 0.03) suspects.push_back(names[c] + " reads almost nothing (dead or stuck?)");
  }
  for (int c = 0; c < 4; ++c)
    if (std::abs(shares[c]) > 0.12) suspects.push_back(names[c] + " carries a vertical share (exchanged?)");
  // Shares alone do not reject: a load near a sensor's edge may unload the opposite one.
  if (broken.empty()) return;
  std::string detail;
  for (int c = 0; c < 8; ++c) detail += fmt::format("{}{} {:+.1f} %", c ? ", " : "", names[c], 100.0 * shares[c]);
  throw Error(fmt::format(
      "force record: the eight channels are not one rigid plate's under the contact: {}; channel shares of Fz "
      "over samples {}-{} (above 30 % of the {:.0f} N peak): {}; {}",
      fmt::join(broken, "; "), loaded.front(), loaded.back(), peak, detail,
      suspects.empty() ? std::string("a channel is dead, stuck, exchanged, sign-reversed or miswired")
                       : fmt::format("{}", fmt::join(suspects, ", "))));
}

}  // namespace

double butterworth_delay_s(double corner_hz, int order) {
  if (!(corner_hz > 0.0) || order < 1) throw Error(fmt::format("low-pass: corner {} Hz, order {}", corner_hz, order));
  // H(s) = prod 1 / (1 - s / p_k), p_k = w_c exp(i theta_k) on the left half
  // circle: the delay at low frequency is sum -Re(1 / p_k) = sum sin(...) / w_c.
  double sum = 0.0;
  for (int k = 1; k <= order; ++k) sum += std::sin((2.0 * k - 1.0) * std::numbers::pi / (2.0 * order));
  return sum / (2.0 * std::numbers::pi * corner_hz);
}

void ProcessOptions::validate() const {
  constexpr std::string_view w = "forceplate options";
  check::positive(w, "trigger_threshold_n", trigger_threshold_n);
  check::in_range(w, "pretrigger_fraction", pretrigger_fraction, 0.0, 1.0, true);
  check::at_least(w, "pretrigger_samples", pretrigger_samples, -1);
  check::non_negative(w, "sample_rate_hz (0: not checked)", sample_rate_hz);
  check::positive(w, "max_trigger_mismatch_s", max_trigger_mismatch_s);
  check::non_negative(w, "quiet_guard_s", quiet_guard_s);
  check::at_least(w, "min_quiet_samples", min_quiet_samples, 1);
  check::positive(w, "onset_band_sd", onset_band_sd);
  check::non_negative(w, "min_noise_n", min_noise_n);
  check::non_negative(w, "cop_min_fz_n", cop_min_fz_n);
  check::non_negative(w, "saturation_n (0: off)", saturation_n);
  check::at_least(w, "saturation_flat_samples (0 or 1: off)", saturation_flat_samples, 0);
  check::non_negative(w, "lowpass_hz (0: none declared)", lowpass_hz);
  check::at_least(w, "lowpass_order", lowpass_order, 1);
}

ForceTrial process(const Resultants& raw, const ProcessOptions& options) {
  options.validate();
  const double dt = check_record(raw, options);
  const int n = static_cast<int>(raw.f_n.rows());
  const int declared = options.pretrigger_samples >= 0
                           ? options.pretrigger_samples
                           : static_cast<int>(std::lround(options.pretrigger_fraction * n));
  if (declared >= n) {
    throw Error(fmt::format("force record: {} pre-trigger samples declared, but the record has only {}", declared, n));
  }
  const int guard = static_cast<int>(std::lround(options.quiet_guard_s / dt));
  int quiet_end = declared - guard;  // exclusive
  if (quiet_end < options.min_quiet_samples) {
    throw Error(fmt::format(
        "force record: too few pre-trigger samples for a zero offset ({} before the trigger; need {} quiet samples "
        "plus {} s before the trigger)",
        declared, options.min_quiet_samples, options.quiet_guard_s));
  }

  ForceTrial out;
  out.declared_trigger_index = declared;
  for (int pass = 0; pass < 2; ++pass) {
    zero_plate(raw, quiet_end, declared, options, out);
    const Eigen::VectorXd fz = out.plate.f_n.col(2);
    const Eigen::VectorXd& t = out.plate.t_s;
    const int crossing = trigger_crossing(fz, t, dt, declared, options, out);

    // Contact onset.
    const double band = options.onset_band_sd * out.noise_n;
    const double peak = fz.tail(n - crossing).maxCoeff();
    const double upper = std::max({2.0 * options.trigger_threshold_n, 2.0 * band, 0.1 * peak});
    const Onset onset = find_onset(t, fz, crossing, band, upper);
    out.contact_time_s = onset.t0_s;
    out.contact_index = static_cast<int>(std::lower_bound(t.data(), t.data() + n, onset.t0_s) - t.data());

    // The quiet part must end before the rise: redo once if it did not.
    const int safe_end = onset.last_in_band - 5;
    if (pass == 0 && safe_end < quiet_end) {
      if (safe_end < options.min_quiet_samples) {
        throw Error(fmt::format(
            "force record: too few quiet pre-trigger samples for a zero offset (the rise starts at sample {})",
            onset.last_in_band));
      }
      quiet_end = safe_end;
      continue;
    }
    peak_and_end(fz, t, crossing, band, dt, out);
    break;
  }
  if (raw.channels_n.size() > 0) check_flat_tops(raw, quiet_end, options);
  finish_plate(raw, options, out);
  if (options.check_channels) check_eight_channels(out, quiet_end);
  return out;
}

std::string ForceTrial::report() const {
  return fmt::format(
      "force: offset Fz {:.2f} N (noise SD {:.2f} N over {} quiet samples); trigger crossing {:+.2f} ms; "
      "contact {:+.2f} ms; peak {:.1f} N at {:+.2f} ms ({:.2f} ms after contact); end of contact {}{:.2f} ms",
      offset[2], noise_n, quiet_samples, 1e3 * trigger_time_s, 1e3 * contact_time_s, peak_fz_n, 1e3 * peak_time_s,
      1e3 * time_to_peak_s, end_found ? "" : "not found, record ends at ", 1e3 * end_time_s) +
         (absent.empty() ? std::string() : fmt::format("; not in the record: {}", fmt::join(absent, " "))) +
         (cop_unavailable.empty() ? std::string() : "; " + cop_unavailable);
}

}  // namespace dropfit::forceplate
