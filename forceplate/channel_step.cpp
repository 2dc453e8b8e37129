// A step in one force channel (forceplate.h, find_channel_step).
//
// Once the impactor has left the mat the plate carries only what it carried
// before the drop (the mat, zeroed out), so every channel must read its
// pre-trigger zero again, give or take a baseline drift. A drift is slow: it
// shows as a slope in the quiet part before the trigger and in the unloaded
// stretch, and over the time between the two it moves the channel by at most
// that slope times that time. A charge amplifier that resets or jumps, or a
// knocked cable, moves one channel at one instant and leaves it there: flat
// before, flat after, a jump between that no slope explains.
//
// Per channel: a straight line (least squares) through the quiet part and
// one through the unloaded stretch; the jump is the second line at the
// stretch's start minus the first at the quiet part's end. What a drift may
// do over the gap is the larger of the two slopes (each plus two of its
// standard errors) times the gap. The excess of the jump over it is the
// step; it is named when beyond kStepNoiseFactor times the channel's noise
// and kStepFloorN.
//
// The instant: the step is hidden under the contact's load, so the channel
// is compared with the load it shares. Over the samples from the quiet
// part's end to the unloaded stretch's end the channel is fitted by
// a + b t + (c + d t) R(t) + s H(t - t0), R the load it shares (for a
// vertical sensor of an eight-channel plate the other three's sum, else
// Fz; a record with Fz alone has none, and the instant is left unknown),
// each sample weighted by 1 / (noise^2 + (1 % of R)^2) (a plate's share
// moves with the centre of pressure), for every t0; the best t0 is the
// instant. When that instant falls inside the unloaded stretch (a cable
// knocked while the impactor is in the air) the step's size is the
// stretch's level after it.
#include <fmt/format.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>
#include <vector>

#include "core/line_fit.h"
#include "forceplate/forceplate.h"

namespace dropfit::forceplate {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// The least-squares line through (t[k], y[k]) for k in [first, end) (N
// against s); not ok with fewer than 10 samples.
LineFit line_over(const Eigen::VectorXd& t, const Eigen::VectorXd& y, Eigen::Index first, Eigen::Index end) {
  if (end - first < 10) return {};
  const auto span = [&](const Eigen::VectorXd& v) { return std::vector<double>(v.data() + first, v.data() + end); };
  return fit_line(span(t), span(y));
}

// The load channel c shares (file comment); empty when there is none.
Eigen::VectorXd shared_load(const Resultants& plate, Eigen::Index c) {
  const auto& names = plate.channel_names;
  const Eigen::MatrixXd& x = plate.channels_n;
  const bool eight = x.cols() == 8 && names == eight_channel_names();
  if (eight && c >= 4) return x.col(4) + x.col(5) + x.col(6) + x.col(7) - x.col(c);
  if (c < static_cast<Eigen::Index>(names.size()) && names[static_cast<std::size_t>(c)] == "Fz") return {};
  return plate.f_n.col(2);
}

// The step's instant (file comment) over samples [first, end); NaN without a load to compare with.
double step_instant_s(const Eigen::VectorXd& t, const Eigen::VectorXd& y, const Eigen::VectorXd& load,
                      double noise_n, Eigen::Index first, Eigen::Index end) {
  if (load.size() != y.size() || end - first < 20) return kNaN;
  const Eigen::Index n = end - first;
  const double tm = t.segment(first, n).mean();
  const double zero = load.segment(0, first).mean();
  Eigen::MatrixXd a(n, 5);
  Eigen::VectorXd w(n), b = y.segment(first, n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const double u = t(first + k) - tm, r = load(first + k) - zero;
    a.row(k) << 1.0, u, r, r * u, 0.0;
    w(k) = 1.0 / (noise_n * noise_n + 1e-4 * r * r);
  }
  // Weighted sums: the fixed columns' normal equations once, the step
  // column's cross terms as suffix sums.
  const Eigen::Matrix4d xx = a.leftCols(4).transpose() * w.asDiagonal() * a.leftCols(4);
  const Eigen::Vector4d xy = a.leftCols(4).transpose() * w.asDiagonal() * b;
  Eigen::Vector4d sx = Eigen::Vector4d::Zero();
  double sw = 0.0, sy = 0.0, best = std::numeric_limits<double>::infinity(), best_t = kNaN;
  for (Eigen::Index k = n - 1; k >= 10; --k) {
    sx += w(k) * a.row(k).head<4>().transpose();
    sw += w(k);
    sy += w(k) * b(k);
    if (n - k < 5) continue;
    Eigen::Matrix<double, 5, 5> m;
    m.topLeftCorner<4, 4>() = xx;
    m.topRightCorner<4, 1>() = sx;
    m.bottomLeftCorner<1, 4>() = sx.transpose();
    m(4, 4) = sw;
    Eigen::Matrix<double, 5, 1> rhs;
    rhs << xy, sy;
    const Eigen::Matrix<double, 5, 1> coef = m.ldlt().solve(rhs);
    const double explained = coef.dot(rhs);  // weighted RSS = y'Wy - explained
    if (-explained < best) best = -explained, best_t = 0.5 * (t(first + k - 1) + t(first + k));
  }
  return best_t;
}

}  // namespace

ChannelStep find_channel_step(const ForceTrial& trial, double unloaded_from_s, double unloaded_to_s) {
  ChannelStep out;
  const Resultants& plate = trial.plate;
  const Eigen::MatrixXd& x = plate.channels_n;
  const Eigen::VectorXd& t = plate.t_s;
  const Eigen::Index n = t.size(), quiet_end = trial.quiet_samples;
  if (x.rows() != n || quiet_end < 10 || !(unloaded_to_s > unloaded_from_s)) return out;
  Eigen::Index from = 0, to = 0;
  while (from < n && t(from) < unloaded_from_s) ++from;
  to = from;
  while (to < n && t(to) <= unloaded_to_s) ++to;
  if (from < quiet_end || to - from < 20) return out;
  const double t_end = t(quiet_end - 1), t_start = t(from);
  double worst_excess = 0.0, zero_n = 0.0;  // zero_n: the stepped channel's level before, at the quiet part's end
  for (Eigen::Index c = 0; c < x.cols(); ++c) {
    const Eigen::VectorXd y = x.col(c);
    const LineFit before = line_over(t, y, 0, quiet_end), after = line_over(t, y, from, to);
    if (!before.ok || !after.ok) continue;
    const double jump = after.at(t_start) - before.at(t_end);
    const double slope = std::max(std::abs(before.slope) + 2.0 * before.slope_se,
                                  std::abs(after.slope) + 2.0 * after.slope_se);
    const double drift = slope * (t_start - t_end);
    const double noise = std::max(before.residual_sd, 1e-3);
    const double excess = std::abs(jump) - drift;
    const double ratio = excess / noise;
    if (ratio > out.excess_noise_ratio || !std::isfinite(out.excess_noise_ratio)) {
      out.channel = c < static_cast<Eigen::Index>(plate.channel_names.size())
                        ? plate.channel_names[static_cast<std::size_t>(c)]
                        : fmt::format("{}", c + 1);
      out.size_n = jump;
      out.drift_allowance_n = drift;
      out.noise_n = noise;
      out.excess_noise_ratio = ratio;
      out.unloaded_from_s = t_start;
      out.unloaded_to_s = t(to - 1);
      worst_excess = excess;
      zero_n = before.at(t_end);
      out.time_s = kNaN;
      out.column = static_cast<int>(c);
    }
  }
  out.found = std::isfinite(out.excess_noise_ratio) && out.excess_noise_ratio > kStepNoiseFactor &&
              worst_excess > kStepFloorN;
  if (!out.found) return out;
  const Eigen::VectorXd y = x.col(out.column);
  out.time_s = step_instant_s(t, y, shared_load(plate, out.column), out.noise_n, quiet_end, to);
  // A step inside the unloaded stretch: its size is the level after it.
  Eigen::Index k = from;
  while (k < to && std::isfinite(out.time_s) && t(k) < out.time_s) ++k;
  if (k > from && to - k >= 20)
    out.size_n = line_over(t, y, k, to).at(t(k)) - zero_n;
  return out;
}

std::string ChannelStep::reason() const {
  const std::string when =
      std::isfinite(time_s) ? fmt::format("at {:+.1f} ms (force clock; the instant that fits the channel against the "
                                          "load it shares)",
                                          1e3 * time_s)
                            : std::string("between the trigger and the unloaded stretch");
  return fmt::format(
      "force record: channel {} steps by {:+.1f} N {} and stays there: while the video shows the impactor in the "
      "air ({:+.0f} to {:+.0f} ms) the plate carries only what it carried before the drop, yet {} reads {:+.1f} N "
      "from its zero before the trigger ({:.1f} N noise SD), where a baseline drift at the slopes it shows before "
      "the trigger and in the air moves it by at most {:.1f} N: a charge amplifier's reset or jump, or a knocked "
      "cable; every force after the step is off by it",
      channel, size_n, when, 1e3 * unloaded_from_s, 1e3 * unloaded_to_s, channel, size_n, noise_n,
      drift_allowance_n);
}

}  // namespace dropfit::forceplate
