// One drop trial: methods in trial.h.
#include "trial/trial.h"

#include <fmt/format.h>

#include <Eigen/Dense>
#include <Eigen/SVD>
#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <vector>

#include "core/error.h"
#include "core/median.h"
#include "core/validate.h"

namespace dropfit::trial {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kPi = 3.14159265358979323846;

// A unit vector whose angle from vertical is the base's tilt (trial.h):
// the plane normal (three or more points) or the normal of the base line
// within its vertical plane (two points); oriented upwards. NaN if missing.
Eigen::Vector3d base_up_vector(const std::vector<Eigen::Vector3d>& p) {
  const Eigen::Vector3d none = Eigen::Vector3d::Constant(kNaN);
  if (p.size() < 2) return none;
  for (const auto& q : p) {
    if (!q.allFinite()) return none;
  }
  if (p.size() == 2) {
    const Eigen::Vector3d d = p[1] - p[0];
    const double len = d.norm();
    const double h = std::hypot(d.x(), d.y());
    if (len <= 0.0) return none;
    if (h <= 0.0) return Eigen::Vector3d(1.0, 0.0, 0.0);  // vertical base line: 90 degrees
    const double dz = d.z() / len, hx = d.x() / h, hy = d.y() / h, hn = h / len;
    return Eigen::Vector3d(-dz * hx, -dz * hy, hn);
  }
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& q : p) centroid += q;
  centroid /= static_cast<double>(p.size());
  Eigen::MatrixXd a(p.size(), 3);
  for (std::size_t i = 0; i < p.size(); ++i) a.row(static_cast<Eigen::Index>(i)) = (p[i] - centroid).transpose();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeFullV);
  Eigen::Vector3d n = svd.matrixV().col(2);
  if (n.z() < 0.0) n = -n;
  return n;
}

double angle_from_vertical_deg(const Eigen::Vector3d& v) {
  const double len = v.norm();
  if (!(len > 0.0)) return kNaN;
  return std::acos(std::clamp(std::abs(v.z()) / len, 0.0, 1.0)) * 180.0 / kPi;
}

// Linear interpolation of samples (uniform grid from t0 with step dt) at t;
// NaN outside or when a neighbour is NaN.
double interpolate_uniform(const Eigen::VectorXd& y, double t0, double dt, double t) {
  const double u = (t - t0) / dt;
  const Eigen::Index n = y.size();
  if (!(u >= 0.0) || u > static_cast<double>(n - 1)) return kNaN;
  const Eigen::Index i = std::min<Eigen::Index>(static_cast<Eigen::Index>(std::floor(u)), n - 1);
  const double w = u - static_cast<double>(i);
  if (w == 0.0 || i + 1 >= n) return y[i];
  return (1.0 - w) * y[i] + w * y[i + 1];
}

std::string join(const std::vector<std::string>& parts, const char* sep) {
  std::string out;
  for (const auto& p : parts) {
    if (!out.empty()) out += sep;
    out += p;
  }
  return out;
}

// A single-sample force spike (trial.h), as a reason; empty when none.
// Samples [first, last] are the contact: they must be finite, and their
// median-filtered peak scales the gate. Spikes are sought over the whole
// record: one in the free flight after the contact biases the plate's
// impulse balance as much as one inside it.
std::string force_spike(const Eigen::VectorXd& t, const Eigen::VectorXd& fz, Eigen::Index first, Eigen::Index last,
                        double max_fraction) {
  const Eigen::Index n = fz.size();
  first = std::max<Eigen::Index>(first, 0);
  last = std::min<Eigen::Index>(last, n - 1);
  for (Eigen::Index k = first; k <= last; ++k) {
    if (!std::isfinite(fz[k])) {
      return fmt::format("force: sample {} (t = {:.1f} ms) is not a finite number", k, 1e3 * t[k]);
    }
  }
  if (last - first < 4) return {};
  // The contact's peak after a 5-sample median filter: one spike cannot raise it.
  double peak = 0.0;
  std::array<double, 5> w{};
  for (Eigen::Index k = first + 2; k <= last - 2; ++k) {
    for (int j = 0; j < 5; ++j) w[j] = fz[k - 2 + j];
    std::nth_element(w.begin(), w.begin() + 2, w.end());
    peak = std::max(peak, std::abs(w[2]));
  }
  const double limit = max_fraction * peak;
  Eigen::Index worst = -1;
  double worst_dev = 0.0;
  for (Eigen::Index k = 1; k <= n - 2; ++k) {
    const double a = fz[k] - fz[k - 1], b = fz[k] - fz[k + 1];
    if (!std::isfinite(a) || !std::isfinite(b) || (a > 0.0) != (b > 0.0)) continue;  // not standing away from both
    const double dev = std::min(std::abs(a), std::abs(b));
    if (dev > limit && dev > worst_dev) worst = k, worst_dev = dev;
  }
  if (worst < 0) return {};
  return fmt::format(
      "force: single-sample spike at sample {} (t = {:.1f} ms{}): {:.4g} N against {:.4g} N and {:.4g} N beside it "
      "(a mat's force cannot jump by more than {:.0f} % of its {:.0f} N peak within one sample)",
      worst, 1e3 * t[worst], worst < first ? ", before the contact" : (worst > last ? ", after the contact" : ""),
      fz[worst], fz[worst - 1], fz[worst + 1], 100.0 * max_fraction, peak);
}

// The video clock: frame numbers against seconds, 0 at the trigger frame.
struct VideoClock {
  double fps = 1000.0, dt_s = 1e-3;
  int trigger_frame = 0;
  double time(double frame) const { return (frame - trigger_frame) * dt_s; }
  double frame(double t_s) const { return t_s * fps + trigger_frame; }
};

std::string point_name(const TrialOptions& o, int p) {
  return p < static_cast<int>(o.point_names.size()) ? o.point_names[p] : fmt::format("point {}", p + 1);
}

// Options and trajectories a user must fix: thrown, not a rejected trial.
void check_inputs(const reconstruction::Trajectories& markers, const TrialOptions& o) {
  if (!(o.frame_rate_hz > 0.0)) throw Error(fmt::format("trial {}: frame rate must be positive", o.id));
  if (!(o.impactor_mass_kg > 0.0)) throw Error(fmt::format("trial {}: impactor mass must be positive", o.id));
  if (o.base_markers.empty()) throw Error(fmt::format("trial {}: no impactor base markers named", o.id));
  if (markers.lab_m.cols() % 3 != 0) {
    throw Error(fmt::format("trial {}: trajectories have {} columns, not 3 per point", o.id, markers.lab_m.cols()));
  }
  const int n_points = static_cast<int>(markers.lab_m.cols() / 3);
  auto check_index = [&](int p, const char* what) {
    if (p < 0 || p >= n_points) {
      throw Error(fmt::format("trial {}: {} marker index {} is not among the {} points", o.id, what, p, n_points));
    }
  };
  for (int p : o.base_markers) check_index(p, "base");
  for (int p : o.surface_markers) check_index(p, "surface");
}

// Mean height of `points` per frame (minus `below_m`); NaN in a frame where
// one is missing, and throughout when `points` is empty.
Eigen::VectorXd mean_height(const reconstruction::Trajectories& markers, const std::vector<int>& points,
                            double below_m) {
  const int nf = static_cast<int>(markers.lab_m.rows());
  Eigen::VectorXd out(nf);
  for (int i = 0; i < nf; ++i) {
    double sum = 0.0;
    bool all = !points.empty();
    for (int p : points) {
      const double z = markers.lab_m(i, 3 * p + 2);
      all = all && std::isfinite(z);
      sum += z;
    }
    out[i] = all ? sum / static_cast<double>(points.size()) - below_m : kNaN;
  }
  return out;
}

// The frame where the face first appears below the mat top (after a frame
// above it, and staying below in most of the next three present frames);
// with a nominal frame (the force's contact), the candidate nearest it. -1
// when none.
int find_crossing(const Eigen::VectorXd& h, double top, double nominal) {
  const int nf = static_cast<int>(h.size());
  int crossing = -1;
  int last_above = -1;
  for (int i = 0; i < nf; ++i) {
    if (!std::isfinite(h[i])) continue;
    if (h[i] >= top) {
      last_above = i;
      continue;
    }
    if (last_above < 0) continue;
    int seen = 0, below = 0;
    for (int k = i + 1; k < nf && seen < 3; ++k) {
      if (!std::isfinite(h[k])) continue;
      ++seen;
      below += h[k] < top;
    }
    if (seen > 0 && 2 * below < seen) continue;  // a stray frame
    if (crossing < 0 || (std::isfinite(nominal) && std::abs(i - nominal) < std::abs(crossing - nominal))) {
      crossing = i;
    }
    if (!std::isfinite(nominal)) break;
    last_above = -1;  // the next candidate needs a new approach from above
  }
  return crossing;
}

// A frame lost or repeated in the fall (a camera dropping frames, or a
// video re-encoded at another rate): every later row is then a frame off in
// time, so the fall steps once by a whole frame's travel against its fit.
// A misdigitised frame (or up to three in a row) steps out and back
// (neighbouring differences that cancel) and is the robust fit's to drop; a
// step stays. Judged on the
// frame-to-frame differences of the fall's frames (ts in either order; across
// gaps of up to 5 frames) against the fit's: beyond half a frame's travel and
// 8 robust SDs of the differences, one difference is a step. Empty when none is.
std::string frame_step_reason(const std::vector<double>& ts, const std::vector<double>& zs, const FreeFallFit& ff,
                              const TrialOptions& o) {
  const double dt = 1.0 / o.frame_rate_hz;
  std::vector<double> e, travel;
  std::vector<std::size_t> at;
  for (std::size_t i = 0; i + 1 < ts.size(); ++i) {
    // Neighbours, or frames either side of a short gap (a step hidden in
    // the gap still shows across it).
    const double frames = std::round(std::abs(ts[i + 1] - ts[i]) / dt);
    if (!(frames >= 1.0 && frames <= 6.0)) continue;
    const double predicted = ff.height_at(ts[i + 1], o.gravity_m_s2) - ff.height_at(ts[i], o.gravity_m_s2);
    e.push_back(zs[i + 1] - zs[i] - predicted);
    travel.push_back(std::abs(predicted) / frames);
    at.push_back(i);
  }
  if (e.size() < 10) return {};
  std::vector<double> a(e.size());
  for (std::size_t k = 0; k < e.size(); ++k) a[k] = std::abs(e[k]);
  std::nth_element(a.begin(), a.begin() + static_cast<std::ptrdiff_t>(a.size() / 2), a.end());
  const double sd = 1.4826 * a[a.size() / 2];
  for (std::size_t k = 0; k < e.size(); ++k) {
    if (!(std::abs(e[k]) > std::max(0.5 * travel[k], 8.0 * sd))) continue;
    // Out and back: the differences up to three on either side bring the
    // sum back (one to three misdigitised frames in a row).
    bool back = false;
    for (int dir : {-1, 1}) {
      double sum = e[k];
      std::size_t j = k;
      for (int m = 0; m < 3 && !back; ++m) {
        const std::size_t next = dir > 0 ? j + 1 : j - 1;
        if ((dir < 0 && j == 0) || next >= e.size() || (dir > 0 ? at[j] + 1 != at[next] : at[next] + 1 != at[j])) break;
        j = next;
        sum += e[j];
        back = std::abs(sum) < 0.5 * std::abs(e[k]);
      }
    }
    if (back) continue;
    const std::size_t i = at[k];
    return fmt::format(
        "video: the falling face moves {:.1f} mm between the frames at {:+.1f} and {:+.1f} ms where its free fall "
        "moves {:.1f} mm ({:.1f} mm a frame; differences scatter by {:.2f} mm): a frame lost or repeated, which puts "
        "every later frame a frame off in time and the impact velocity with it",
        1e3 * std::abs(zs[i + 1] - zs[i]), 1e3 * ts[i], 1e3 * ts[i + 1], 1e3 * std::abs(zs[i + 1] - zs[i] - e[k]),
        1e3 * travel[k], 1e3 * sd);
  }
  return {};
}

// The points the manifest names as the impactor's base markers stand
// still while other points fall: the tracks' columns are not in the order
// of [video].points (DLTdv's pt1, pt2, ... follow the manifest's list). The
// impactor falls tens of centimetres or more in any digitised window that
// shows its approach, the mat's surface moves by its deformation only.
// Empty when the base markers move, or no other point moves much more.
std::string point_order_reason(const reconstruction::Trajectories& markers, const TrialOptions& o) {
  auto vertical_range = [&](int p) {
    double lo = std::numeric_limits<double>::infinity(), hi = -lo;
    for (int i = 0; i < markers.n_frames(); ++i) {
      const double z = markers.lab_m(i, 3 * p + 2);
      if (std::isfinite(z)) lo = std::min(lo, z), hi = std::max(hi, z);
    }
    return hi >= lo ? hi - lo : 0.0;
  };
  double base = 0.0;
  std::vector<std::string> base_names, falling;
  for (int p : o.base_markers) {
    if (p < 0 || p >= markers.n_points()) continue;
    base = std::max(base, vertical_range(p));
    base_names.push_back(point_name(o, p));
  }
  double fall = 0.0;
  for (int p = 0; p < markers.n_points(); ++p) {
    if (std::find(o.base_markers.begin(), o.base_markers.end(), p) != o.base_markers.end()) continue;
    const double r = vertical_range(p);
    if (r > kPointOrderFallM && r > kPointOrderRatio * base) {
      falling.push_back(fmt::format("{} (column pair {})", point_name(o, p), p + 1));
      fall = std::max(fall, r);
    }
  }
  if (base_names.empty() || falling.empty()) return {};
  return fmt::format(
      "the points named as the impactor's base markers ({}) move {:.3f} m up and down in this trial while {} move "
      "{:.2f} m: the tracks' columns are not in the order of [video].points (DLTdv's pt1, pt2, ... follow that list)",
      join(base_names, ", "), base, join(falling, ", "), fall);
}

// Free-fall fit before the crossing and the video contact instant, into res.
FreeFallFit free_fall_before(const Eigen::VectorXd& h, int crossing, const VideoClock& clock, const TrialOptions& o,
                             TrialResult& res, std::vector<std::string>& reasons) {
  const double top = o.mat_top_z_m;
  FreeFallFit ff;
  if (crossing < 0) {
    reasons.push_back(fmt::format("video: the impactor's contact face is never seen reaching the mat top (z = {:.3f} m)",
                                  top));
    return ff;
  }
  const double t_cross = clock.time(crossing);
  std::vector<double> ts, zs;
  for (int i = crossing - 1; i >= 0 && clock.time(i) >= t_cross - o.freefall_window_s; --i) {
    if (std::isfinite(h[i]) && h[i] >= top + o.freefall_clearance_m) {
      ts.push_back(clock.time(i));
      zs.push_back(h[i]);
    }
  }
  ff = fit_free_fall(Eigen::Map<Eigen::VectorXd>(ts.data(), static_cast<Eigen::Index>(ts.size())),
                     Eigen::Map<Eigen::VectorXd>(zs.data(), static_cast<Eigen::Index>(zs.size())), o.gravity_m_s2, top,
                     t_cross);
  res.freefall_frames = ff.n_frames;
  if (static_cast<int>(ts.size()) < o.min_freefall_frames) {
    std::vector<std::string> names;
    for (int p : o.base_markers) names.push_back(point_name(o, p));
    reasons.push_back(fmt::format("video: only {} free-fall frames of the base markers ({}) in the {:.0f} ms before "
                                  "contact (need {})",
                                  ts.size(), join(names, ", "), 1e3 * o.freefall_window_s, o.min_freefall_frames));
  } else if (!ff.ok) {
    reasons.push_back("video: the free-fall fit before contact does not reach the mat top");
  }
  if (ff.ok) {
    res.impact_velocity_m_s = ff.contact_speed_m_s;
    res.impact_velocity_ci_m_s = ff.contact_speed_ci_m_s;
    res.impact_velocity_se_m_s = ff.contact_speed_se_m_s;
    res.video_contact_time_s = ff.contact_time_s;
    res.velocity_contact_time_cov = ff.speed_time_cov;
    // The contact height's own error moves the arrival by dH / v.
    const double dh = std::isfinite(res.contact_height_se_m) ? res.contact_height_se_m / ff.contact_speed_m_s : 0.0;
    res.video_contact_time_se_s = std::hypot(ff.contact_time_se_s, dh);
    res.freefall_rms_m = ff.rms_m;
    // The fall's own acceleration over a longer stretch (never back to a
    // release from rest at this speed) against gravity.
    const double span = std::min(o.fall_check_window_s, 0.8 * ff.contact_speed_m_s / o.gravity_m_s2);
    ts.clear(), zs.clear();
    for (int i = crossing - 1; i >= 0 && clock.time(i) >= t_cross - span; --i)
      if (std::isfinite(h[i]) && h[i] >= top + o.freefall_clearance_m) ts.push_back(clock.time(i)), zs.push_back(h[i]);
    const FallAcceleration fall = fit_fall_acceleration(Eigen::Map<Eigen::VectorXd>(ts.data(), std::ssize(ts)),
                                                        Eigen::Map<Eigen::VectorXd>(zs.data(), std::ssize(zs)));
    res.fall_accel_m_s2 = fall.accel_m_s2;
    res.fall_accel_se_m_s2 = fall.se_m_s2;
    // A frame lost or repeated bends the fall's fitted acceleration too: the
    // step, the cause, is the first reason.
    if (std::string r = frame_step_reason(ts, zs, ff, o); !r.empty()) reasons.push_back(std::move(r));
    if (std::string r = fall_acceleration_reason(fall, o); !r.empty()) reasons.push_back(std::move(r));
  }
  return ff;
}

// The contact's start and end on the video clock (NaN when unknown).
std::pair<double, double> contact_on_video(const forceplate::ForceTrial* force, const FreeFallFit& ff, int crossing,
                                           const Eigen::VectorXd& h, double top, double offset,
                                           const VideoClock& clock) {
  const int nf = static_cast<int>(h.size());
  double start_v = kNaN, end_v = kNaN;
  if (ff.ok) {
    start_v = ff.contact_time_s;
  } else if (force) {
    start_v = force->contact_time_s + offset;
  } else if (crossing >= 0) {
    start_v = clock.time(crossing - 0.5);
  }
  if (force && force->end_found) {
    end_v = force->end_time_s + offset;
  } else if (std::isfinite(start_v)) {
    end_v = clock.time(nf - 1);
    for (int i = std::max(0, static_cast<int>(std::ceil(clock.frame(start_v)))) + 1; i < nf; ++i) {
      if (std::isfinite(h[i]) && h[i] >= top) {
        end_v = clock.time(i);
        break;
      }
    }
  }
  return {start_v, end_v};
}

// The impactor is rigid: the distance between two base markers is one
// length in every frame, to within the reconstruction noise. A frame where
// it departs by more than max(10 mm, 6 robust SDs) from its median over
// frames [first, last] has a marker mistracked, swapped with another or
// come loose; its face height (their mean) is then wrong by about half the
// jump. Returns the reason; empty when every pair holds its length.
std::string rigidity_reason(const reconstruction::Trajectories& markers, const TrialOptions& o, int first, int last) {
  const auto& b = o.base_markers;
  first = std::max(first, 0);
  last = std::min(last, markers.n_frames() - 1);
  for (std::size_t i = 0; i < b.size(); ++i) {
    for (std::size_t j = i + 1; j < b.size(); ++j) {
      std::vector<double> d;
      std::vector<int> frame;
      for (int f = first; f <= last; ++f) {
        const Eigen::Vector3d a = markers.lab_m.row(f).segment<3>(3 * b[i]).transpose();
        const Eigen::Vector3d c = markers.lab_m.row(f).segment<3>(3 * b[j]).transpose();
        if (!a.allFinite() || !c.allFinite()) continue;
        d.push_back((a - c).norm());
        frame.push_back(f);
      }
      if (d.size() < 10) continue;
      std::vector<double> sorted = d;
      std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
      const double med = sorted[sorted.size() / 2];
      std::vector<double> dev;
      for (double x : d) dev.push_back(std::abs(x - med));
      std::nth_element(dev.begin(), dev.begin() + static_cast<std::ptrdiff_t>(dev.size() / 2), dev.end());
      const double limit = std::max(0.010, 6.0 * 1.4826 * dev[dev.size() / 2]);
      int worst = -1;
      double worst_dev = 0.0;
      for (std::size_t k = 0; k < d.size(); ++k)
        if (std::abs(d[k] - med) > std::max(limit, worst_dev)) worst = frame[k], worst_dev = std::abs(d[k] - med);
      if (worst >= 0)
        return fmt::format(
            "base markers {} and {} are {:.1f} mm apart but {:.1f} mm off that in frame {} (the impactor is rigid): a "
            "marker mistracked, swapped or loose",
            point_name(o, b[i]), point_name(o, b[j]), 1e3 * med, 1e3 * worst_dev, worst);
    }
  }
  return {};
}

// Base-marker coverage from coverage_lead_s before contact to frame `last`,
// as a reason; empty when every base marker is there often enough.
std::string coverage_reason(const reconstruction::Trajectories& markers, const TrialOptions& o,
                            const VideoClock& clock, double start_v, int last) {
  const int nf = static_cast<int>(markers.lab_m.rows());
  const int c0 = static_cast<int>(std::ceil(clock.frame(start_v - o.coverage_lead_s)));
  const int total = std::max(1, last - c0 + 1);
  std::vector<std::string> missing;
  for (int p : o.base_markers) {
    int present = 0, gap = 0, longest = 0;
    for (int i = c0; i <= last; ++i) {
      const bool ok = i >= 0 && i < nf && std::isfinite(markers.lab_m(i, 3 * p + 2));
      present += ok;
      gap = ok ? 0 : gap + 1;
      longest = std::max(longest, gap);
    }
    const double share = static_cast<double>(present) / total;
    if (share < o.min_marker_coverage || longest * clock.dt_s > o.max_marker_gap_s + 1e-9) {
      missing.push_back(fmt::format("{} ({:.0f} % of frames, longest gap {:.0f} ms)", point_name(o, p), 100.0 * share,
                                    1e3 * longest * clock.dt_s));
    }
  }
  if (missing.empty()) return {};
  return fmt::format("markers missing around contact (from {:.0f} ms before contact to its end): {}",
                     1e3 * o.coverage_lead_s, join(missing, "; "));
}

// Maximum deformation (the lowest face height in frames [first, last],
// refined by a parabola over deformation_fit_half_window_s) into res. The
// parabola needs two frames seen on each side of the lowest one seen; when a
// gap leaves fewer within the half window, the window doubles once (the
// bottom of a gap-bridging parabola). Returns a reason when even that leaves
// a side short (the bottom lies in a gap and is not measured), or when the
// face is never seen.
std::string max_deformation(const Eigen::VectorXd& h, int first, int last, const TrialOptions& o,
                            const VideoClock& clock, double offset, TrialResult& res) {
  const int nf = static_cast<int>(h.size());
  int imin = -1;
  for (int i = std::max(0, first); i <= std::min(last, nf - 1); ++i) {
    if (std::isfinite(h[i]) && (imin < 0 || h[i] < h[imin])) imin = i;
  }
  if (imin < 0) return "video: the impactor face is never seen during the contact";
  const int hw0 = std::max(1, static_cast<int>(std::lround(o.deformation_fit_half_window_s * clock.fps)));
  auto seen_each_side = [&](int hw) {
    int before = 0, after = 0;
    for (int i = std::max(0, imin - hw); i <= std::min(nf - 1, imin + hw); ++i) {
      if (!std::isfinite(h[i]) || i == imin) continue;
      if (i < imin) ++before; else ++after;
    }
    return std::min(before, after);
  };
  const int hw = seen_each_side(hw0) >= 2 ? hw0 : 2 * hw0;
  double hmin = h[imin], umin = 0.0;
  Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
  Eigen::Vector3d atb = Eigen::Vector3d::Zero();
  int count = 0;
  for (int i = std::max(0, imin - hw); i <= std::min(nf - 1, imin + hw); ++i) {
    if (!std::isfinite(h[i])) continue;
    const double u = i - imin;
    const Eigen::Vector3d row(1.0, u, u * u);
    ata += row * row.transpose();
    atb += row * h[i];
    ++count;
  }
  if (count >= 5) {
    const Eigen::Vector3d c = ata.ldlt().solve(atb);
    if (c(2) > 0.0) {
      const double u = -c(1) / (2.0 * c(2));
      if (std::abs(u) <= hw) {
        umin = u;
        hmin = c(0) + c(1) * u + c(2) * u * u;
      }
    }
  }
  res.max_deformation_m = o.mat_top_z_m - hmin;
  res.max_deformation_time_s = clock.time(imin + umin) - offset;
  if (seen_each_side(hw) < 2) {
    return fmt::format("video: the lowest point of the impactor face falls in a marker gap (fewer than two frames "
                       "seen on one side of the lowest one seen within {:.0f} ms; max deformation not measured)",
                       1e3 * hw / clock.fps);
  }
  return {};
}

// The largest tilt of the base over frames [first, last], each frame's up
// vector averaged over tilt_smoothing_frames; NaN when never seen.
double worst_tilt_deg(const reconstruction::Trajectories& markers, const TrialOptions& o, int first, int last) {
  const int nf = static_cast<int>(markers.lab_m.rows());
  std::vector<Eigen::Vector3d> up(nf, Eigen::Vector3d::Constant(kNaN));
  std::vector<Eigen::Vector3d> pts(o.base_markers.size());
  const int i0 = std::max(0, first), i1 = std::min(last, nf - 1);
  for (int i = i0; i <= i1; ++i) {
    for (std::size_t k = 0; k < o.base_markers.size(); ++k) pts[k] = markers.point(i, o.base_markers[k]);
    up[i] = base_up_vector(pts);
  }
  const int half = std::max(0, o.tilt_smoothing_frames / 2);
  const int need = half + 1;
  double worst = kNaN;
  for (int i = i0; i <= i1; ++i) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int k = 0;
    for (int j = std::max(i0, i - half); j <= std::min(i1, i + half); ++j) {
      if (up[j].allFinite()) {
        sum += up[j];
        ++k;
      }
    }
    if (k < std::min(need, i1 - i0 + 1)) continue;
    const double a = angle_from_vertical_deg(sum);
    if (!(a <= worst)) worst = a;
  }
  return worst;
}

// The force and video series over the contact (from series_lead_s before it).
Series contact_series(const forceplate::ForceTrial& force, const Eigen::VectorXd& h, const Eigen::VectorXd& surf,
                      const TrialOptions& o, const VideoClock& clock, double offset) {
  const Eigen::VectorXd& t = force.plate.t_s;
  const Eigen::VectorXd fz = force.plate.f_n.col(2);
  const double t_first = clock.time(0), top = o.mat_top_z_m;
  const double a = force.contact_time_s - o.series_lead_s, b = force.end_time_s;
  std::vector<Eigen::Index> rows;
  for (Eigen::Index k = 0; k < t.size(); ++k) {
    if (t[k] >= a && t[k] <= b) rows.push_back(k);
  }
  const auto m = static_cast<Eigen::Index>(rows.size());
  Series s;
  s.t_s.resize(m);
  s.fz_n.resize(m);
  s.impactor_z_m.resize(m);
  s.deformation_m.resize(m);
  s.surface_z_m.resize(m);
  for (Eigen::Index r = 0; r < m; ++r) {
    const Eigen::Index k = rows[r];
    s.t_s[r] = t[k];
    s.fz_n[r] = fz[k];
    s.impactor_z_m[r] = interpolate_uniform(h, t_first, clock.dt_s, t[k] + offset);
    s.deformation_m[r] = top - s.impactor_z_m[r];
    s.surface_z_m[r] = interpolate_uniform(surf, t_first, clock.dt_s, t[k] + offset);
  }
  return s;
}

// Second synchronisation estimate: face heights against free fall plus the
// plate force's double integral over the impactor mass; the clock offset
// (video_offset_s searched +-5 ms around the contact estimate) that matches
// them best, or NaN with fewer than 10 frames to compare.
double trajectory_offset_s(const forceplate::ForceTrial& force, const Eigen::VectorXd& h, const FreeFallFit& ff,
                           double video_offset_s, double start_v, double end_v, const TrialOptions& o,
                           const VideoClock& clock) {
  const Eigen::VectorXd& t = force.plate.t_s;
  const Eigen::Index n = t.size();
  const int nf = static_cast<int>(h.size());
  const Eigen::Index k0 = std::max<Eigen::Index>(0, force.contact_index - 5);
  std::vector<double> tv, dz;
  const double search = 0.005;
  // Only frames whose every shifted time stays inside the record.
  for (int i = std::max(0, static_cast<int>(std::ceil(clock.frame(start_v)))); i < nf && clock.time(i) <= end_v; ++i) {
    const double tf = clock.time(i) - video_offset_s;
    if (!std::isfinite(h[i]) || tf - search < t[0] || tf + search > t[n - 1]) continue;
    tv.push_back(clock.time(i));
    dz.push_back(h[i] - ff.height_at(clock.time(i), o.gravity_m_s2));
  }
  return trajectory_shift_s(t, force.plate.f_n.col(2), k0, o.impactor_mass_kg, tv, dz, video_offset_s, search);
}

// Force spikes, the impulse to maximum deformation against the video's
// momentum, and the restitution (trial.h): ratios into res, reasons when
// outside physical bounds. The impulse checks wait for a record without a
// spike (they are meaningless with one).
void impulse_checks(const forceplate::ForceTrial& force, const TrialOptions& o, TrialResult& res,
                    std::vector<std::string>& reasons) {
  const Eigen::VectorXd& t = force.plate.t_s;
  const Eigen::VectorXd fz = force.plate.f_n.col(2);
  const double g = o.gravity_m_s2;
  const std::string spike = force_spike(t, fz, force.contact_index, force.end_index, o.max_spike_fraction);
  if (!spike.empty()) reasons.push_back(spike);

  // Impulse check to maximum deformation.
  if (std::isfinite(res.max_deformation_time_s) && std::isfinite(res.impact_velocity_m_s) &&
      res.max_deformation_time_s > force.contact_time_s) {
    const double impulse = integrate(t, fz, force.contact_time_s, res.max_deformation_time_s) -
                           o.impactor_mass_kg * g * (res.max_deformation_time_s - force.contact_time_s);
    res.impulse_ratio = impulse / (o.impactor_mass_kg * res.impact_velocity_m_s);
    res.velocity_from_impulse_m_s = impulse / o.impactor_mass_kg;
  }
  // Impulse over the whole contact: restitution.
  if (force.end_found && std::isfinite(res.impact_velocity_m_s) && force.end_time_s > force.contact_time_s) {
    const double impulse = integrate(t, fz, force.contact_time_s, force.end_time_s) -
                           o.impactor_mass_kg * g * (force.end_time_s - force.contact_time_s);
    res.restitution = impulse / (o.impactor_mass_kg * res.impact_velocity_m_s) - 1.0;
  }
  if (!spike.empty()) return;
  const double tol = o.impulse_tolerance + std::max(0.0, o.mat_mass_kg) / o.impactor_mass_kg;
  if (std::isfinite(res.impact_velocity_m_s) && std::isfinite(res.max_deformation_time_s) &&
      !(std::abs(res.impulse_ratio - 1.0) <= tol)) {
    reasons.push_back(fmt::format(
        "impact velocity {:.3f} m/s from video against {:.3g} m/s from the force impulse to maximum deformation "
        "(ratio {:.3g}, physically within {:.2f}-{:.2f}): check [video].frame_rate_hz, [impactor].mass_kg, the "
        "force scale and the contact face's height ([impactor].base_marker_height_m, [forceplate].mat_top_z_m: "
        "they place the contact instant the impulse starts from)",
        res.impact_velocity_m_s, res.velocity_from_impulse_m_s, res.impulse_ratio, 1.0 - tol, 1.0 + tol));
  }
  if (std::isfinite(res.impact_velocity_m_s) && force.end_found &&
      !(res.restitution >= -tol && res.restitution <= 1.0 + tol)) {
    reasons.push_back(fmt::format(
        "impulse over the contact is {:.3g} times the impactor's momentum at contact; a rebound bounded by the "
        "impact speed allows 1-2 (restitution 0-1, tolerance {:.2f})",
        res.restitution + 1.0, tol));
  }
}

// The mat top as the cameras see it: the surface markers' mean height over
// the frames where every one is seen, before the face first comes within
// 20 mm of the surveyed top (after the rebound the mat may still be
// recovering); NaN when fewer than min_rest_frames such frames (see the
// header: contact height). `se_m`: the mean's standard error (the frames'
// scatter over sqrt(n)).
double surface_rest_height_m(const Eigen::VectorXd& h, const Eigen::VectorXd& surf, const TrialOptions& o,
                             double* se_m) {
  constexpr double kClear_m = 0.020;
  double sum = 0.0, sum2 = 0.0;
  int n = 0;
  for (Eigen::Index i = 0; i < surf.size() && i < h.size(); ++i) {
    if (std::isfinite(h[i]) && h[i] < o.mat_top_z_m + kClear_m) break;  // the approach: at rest only before it
    if (std::isfinite(surf[i])) {
      sum += surf[i];
      sum2 += surf[i] * surf[i];
      ++n;
    }
  }
  if (n < o.min_rest_frames) return kNaN;
  const double rest = sum / n;
  *se_m = std::sqrt(std::max(sum2 / n - rest * rest, 0.0) / std::max(n - 1, 1));
  return rest;
}

TrialResult analyse_impl(const forceplate::ForceTrial* force, const std::string& force_error,
                         const reconstruction::Trajectories& markers, const TrialOptions& given) {
  given.validate();
  check_inputs(markers, given);
  TrialResult res;
  res.id = given.id;
  std::vector<std::string> reasons;
  if (!force_error.empty()) reasons.push_back(force_error);

  const VideoClock clock{given.frame_rate_hz, 1.0 / given.frame_rate_hz, given.trigger_frame};
  if (std::string r = point_order_reason(markers, given); !r.empty()) reasons.push_back(r);
  // Face height and surface height per frame.
  const Eigen::VectorXd h = mean_height(markers, given.base_markers, given.base_marker_height_m);
  const Eigen::VectorXd surf = mean_height(markers, given.surface_markers, 0.0);
  // Everything below measures from the contact height.
  TrialOptions o = given;
  double rest_se_m = kNaN;
  const double rest = surface_rest_height_m(h, surf, given, &rest_se_m);
  res.surface_rest_z_m = rest;
  if (std::abs(rest - given.mat_top_z_m) <= given.max_surface_reference_m) {
    o.mat_top_z_m = rest;
    res.contact_height_se_m = rest_se_m;
  }
  if (std::abs(rest - given.mat_top_z_m) > given.max_surface_disagreement_m) {
    reasons.push_back(fmt::format(
        "the cameras see the mat top (the surface markers at rest) at z = {:.4f} m, {:+.1f} mm from the declared "
        "[forceplate] mat_top_z_m = {:.4f} m (tolerance {:.0f} mm): either mat_top_z_m is wrong or the surface "
        "markers are not on the mat top; the contact instant, impact velocity and deformation depend on which",
        rest, 1e3 * (rest - given.mat_top_z_m), given.mat_top_z_m, 1e3 * given.max_surface_disagreement_m));
  }
  res.contact_height_m = o.mat_top_z_m;
  const double top = o.mat_top_z_m;

  if (force) {
    res.contact_time_s = force->contact_time_s;
    res.force_noise_n = force->noise_n;
    res.peak_force_n = force->peak_fz_n;
    res.time_to_peak_s = force->time_to_peak_s;
    res.end_time_s = force->end_time_s;
  }

  const int crossing = find_crossing(h, top, force ? clock.frame(force->contact_time_s) : kNaN);
  const FreeFallFit ff = free_fall_before(h, crossing, clock, o, res, reasons);

  // Clock offset.
  if (force && ff.ok) {
    res.video_offset_s = ff.contact_time_s - force->contact_time_s;
    if (std::abs(res.video_offset_s) > o.max_video_offset_s) {
      reasons.push_back(fmt::format(
          "video and force disagree on the contact instant by {:.1f} ms (limit {:.1f} ms): check [video].trigger_frame",
          1e3 * res.video_offset_s, 1e3 * o.max_video_offset_s));
    }
  }
  const double offset = std::isfinite(res.video_offset_s) ? res.video_offset_s : 0.0;

  const auto [start_v, end_v] = contact_on_video(force, ff, crossing, h, top, offset, clock);
  if (std::isfinite(start_v) && end_v > start_v) {
    const int first = static_cast<int>(std::ceil(clock.frame(start_v)));
    const int last = static_cast<int>(std::floor(clock.frame(end_v)));
    if (std::string r = coverage_reason(markers, o, clock, start_v, last); !r.empty()) reasons.push_back(r);
    const int lead = static_cast<int>(std::lround(o.freefall_window_s * o.frame_rate_hz));
    if (std::string r = rigidity_reason(markers, o, first - lead, last); !r.empty()) reasons.push_back(r);
    if (std::string r = max_deformation(h, first, last, o, clock, offset, res); !r.empty()) reasons.push_back(r);
    res.tilt_deg = worst_tilt_deg(markers, o, first, last);
    if (std::isfinite(res.tilt_deg) && res.tilt_deg > o.max_tilt_deg) {
      reasons.push_back(fmt::format("tilt {:.1f} deg exceeds the {:.1f} deg limit", res.tilt_deg, o.max_tilt_deg));
    }
  }

  if (force) {
    res.series = contact_series(*force, h, surf, o, clock, offset);
    if (ff.ok && std::isfinite(res.video_offset_s) && std::isfinite(end_v)) {
      const double d = trajectory_offset_s(*force, h, ff, res.video_offset_s, start_v, end_v, o, clock);
      if (std::isfinite(d)) res.video_offset_trajectory_s = d;
    }
    impulse_checks(*force, o, res, reasons);
    if (std::isfinite(start_v)) {
      const auto [from, to] =
          airborne_stretch_s(h, top, clock.frame(start_v), o.frame_rate_hz, o.trigger_frame, offset, o.gravity_m_s2);
      if (std::isfinite(from)) {
        const forceplate::ChannelStep step = forceplate::find_channel_step(*force, from, to);
        if (step.found) reasons.insert(reasons.begin(), step.reason());
      }
    }
  }

  res.accepted = reasons.empty();
  res.reject_reason = join(reasons, "; ");
  return res;
}

}  // namespace

double integrate(const Eigen::VectorXd& t, const Eigen::VectorXd& f, double a, double b) {
  if (!(b > a)) return 0.0;
  const Eigen::Index n = t.size();
  auto at = [&](double x) {
    const Eigen::Index k = std::upper_bound(t.data(), t.data() + n, x) - t.data();
    if (k <= 0) return f[0];
    if (k >= n) return f[n - 1];
    const double w = (x - t[k - 1]) / (t[k] - t[k - 1]);
    return (1.0 - w) * f[k - 1] + w * f[k];
  };
  double sum = 0.0, prev_t = a, prev_f = at(a);
  for (Eigen::Index k = std::upper_bound(t.data(), t.data() + n, a) - t.data(); k < n && t[k] < b; ++k) {
    sum += 0.5 * (prev_f + f[k]) * (t[k] - prev_t);
    prev_t = t[k];
    prev_f = f[k];
  }
  sum += 0.5 * (prev_f + at(b)) * (b - prev_t);
  return sum;
}

// See trial.h.
double trajectory_shift_s(const Eigen::VectorXd& force_t_s, const Eigen::VectorXd& force_n, Eigen::Index force_first,
                          double mass_kg, const std::vector<double>& lag_t_s, const std::vector<double>& lag_m,
                          double centre_s, double search_s) {
  const Eigen::VectorXd& t = force_t_s;
  const Eigen::Index n = t.size();
  if (lag_t_s.size() < 10 || lag_m.size() != lag_t_s.size() || n < 2 || force_n.size() != n) return kNaN;
  Eigen::VectorXd disp = Eigen::VectorXd::Zero(n);
  double vel = 0.0;
  for (Eigen::Index k = std::max<Eigen::Index>(0, force_first) + 1; k < n; ++k) {
    const double step = t[k] - t[k - 1];
    const double v_new = vel + 0.5 * (force_n[k - 1] + force_n[k]) / mass_kg * step;
    disp[k] = disp[k - 1] + 0.5 * (vel + v_new) * step;
    vel = v_new;
  }
  const double dt = (t[n - 1] - t[0]) / static_cast<double>(n - 1);
  auto disp_at = [&](double x) {
    if (x <= t[0]) return 0.0;
    if (x >= t[n - 1]) return disp[n - 1];
    return interpolate_uniform(disp, t[0], dt, x);
  };
  auto cost = [&](double delta) {
    double sum = 0.0;
    for (std::size_t i = 0; i < lag_t_s.size(); ++i) {
      const double r = lag_m[i] - disp_at(lag_t_s[i] - delta);
      sum += r * r;
    }
    return sum;
  };
  const double step = 1e-5;
  const int steps = static_cast<int>(std::lround(search_s / step));
  double best = std::numeric_limits<double>::infinity();
  int best_k = 0;
  std::vector<double> c(2 * steps + 1);
  for (int k = -steps; k <= steps; ++k) {
    c[k + steps] = cost(centre_s + k * step);
    if (c[k + steps] < best) best = c[k + steps], best_k = k;
  }
  double refine = 0.0;
  if (best_k > -steps && best_k < steps) {
    const double cm = c[best_k + steps - 1], c0 = c[best_k + steps], cp = c[best_k + steps + 1];
    const double curv = cm - 2.0 * c0 + cp;
    if (curv > 0.0) refine = 0.5 * (cm - cp) / curv;
  }
  return centre_s + (best_k + refine) * step;
}

void TrialOptions::validate() const {
  const std::string w = id.empty() ? std::string("trial options") : fmt::format("trial {} options", id);
  check::positive(w, "impactor_mass_kg", impactor_mass_kg);
  check::positive(w, "gravity_m_s2", gravity_m_s2);
  check::positive(w, "frame_rate_hz", frame_rate_hz);
  check::at_least(w, "trigger_frame", trigger_frame, 0);
  check::finite(w, "base_marker_height_m", base_marker_height_m);
  check::finite(w, "mat_top_z_m", mat_top_z_m);
  check::non_negative(w, "max_surface_reference_m", max_surface_reference_m);
  check::non_negative(w, "max_surface_disagreement_m", max_surface_disagreement_m);
  check::at_least(w, "min_rest_frames", min_rest_frames, 1);
  check::in_range(w, "max_tilt_deg", max_tilt_deg, 0.0, 90.0);
  check::positive(w, "freefall_window_s", freefall_window_s);
  check::non_negative(w, "freefall_clearance_m", freefall_clearance_m);
  check::at_least(w, "min_freefall_frames", min_freefall_frames, 3);
  check::non_negative(w, "coverage_lead_s", coverage_lead_s);
  check::in_range(w, "min_marker_coverage", min_marker_coverage, 0.0, 1.0);
  check::non_negative(w, "max_marker_gap_s", max_marker_gap_s);
  check::positive(w, "max_video_offset_s", max_video_offset_s);
  check::non_negative(w, "deformation_fit_half_window_s", deformation_fit_half_window_s);
  check::at_least(w, "tilt_smoothing_frames", tilt_smoothing_frames, 0);
  check::non_negative(w, "series_lead_s", series_lead_s);
  check::non_negative(w, "mat_mass_kg", mat_mass_kg);
  check::positive(w, "impulse_tolerance", impulse_tolerance);
  check::positive(w, "max_spike_fraction", max_spike_fraction);
  check::positive(w, "fall_check_window_s", fall_check_window_s);
  check::non_negative(w, "fall_accel_excess", fall_accel_excess);
  check::in_range(w, "fall_accel_deficit", fall_accel_deficit, 0.0, 1.0);
  check::positive(w, "fall_accel_sigma", fall_accel_sigma);
}

double base_tilt_deg(const std::vector<Eigen::Vector3d>& base_points_m) {
  return angle_from_vertical_deg(base_up_vector(base_points_m));
}

TrialResult analyse(const forceplate::ForceTrial& force, const reconstruction::Trajectories& markers,
                    const TrialOptions& options) {
  return analyse_impl(&force, std::string(), markers, options);
}

TrialResult analyse(const forceplate::Resultants& raw_force, const forceplate::ProcessOptions& force_options,
                    const reconstruction::Trajectories& markers, const TrialOptions& options) {
  // Options a user must fix are an error, not a rejected trial.
  force_options.validate();
  options.validate();
  std::optional<forceplate::ForceTrial> force;
  std::string error;
  try {
    force = forceplate::process(raw_force, force_options);
  } catch (const Error& e) {
    error = e.what();
  }
  return force ? analyse_impl(&*force, std::string(), markers, options) : analyse_impl(nullptr, error, markers, options);
}

TrialResult analyse_without_force(const reconstruction::Trajectories& markers, const TrialOptions& options,
                                  const std::string& force_error) {
  return analyse_impl(nullptr, force_error.empty() ? std::string("force record: missing") : force_error, markers,
                      options);
}

CalibrationQuality calibration_quality(const calibration::CalibrationResult& calibration, double markers_z_span_m) {
  CalibrationQuality q;
  if (std::isfinite(calibration.check_rms_m.z()) && markers_z_span_m > 0.0)
    q.vertical_scale_sd = calibration.check_rms_m.z() / markers_z_span_m;
  std::string worst_camera;
  for (const auto& camera : calibration.cameras) {
    // NaN: not measured (coefficients given, e.g. by a wand calibration).
    if (!std::isfinite(camera.fit_rms_px)) continue;
    if (!(camera.fit_rms_px <= q.fit_rms_px)) {
      q.fit_rms_px = camera.fit_rms_px;
      worst_camera = camera.camera.name;
    }
  }
  if (calibration.check_rms_m.allFinite()) q.check_rms_m = calibration.check_rms_m.norm();
  std::vector<std::string> problems;
  if (std::isfinite(q.fit_rms_px) && q.fit_rms_px > kMaxCalibrationFitRmsPx) {
    problems.push_back(fmt::format("camera {} fits its calibration points to {:.3g} px RMS (limit {:.0f} px)",
                                   worst_camera, q.fit_rms_px, kMaxCalibrationFitRmsPx));
  }
  if (std::isfinite(q.check_rms_m) && q.check_rms_m > kMaxCalibrationCheckRmsM) {
    problems.push_back(fmt::format("check markers reconstructed to {:.3g} mm RMS (limit {:.0f} mm)", 1e3 * q.check_rms_m,
                                   1e3 * kMaxCalibrationCheckRmsM));
  }
  if (!problems.empty()) {
    q.problem = "calibration failed its own check: " + join(problems, "; ") +
                " (a mislabelled or mistyped calibration point?)";
  }
  return q;
}

namespace {

// One camera's rows change their lag part-way (CameraLag::changes_part_way).
std::string camera_lag_change_reason(const reconstruction::CameraLag& lag, const TrialOptions& o) {
  const int d = lag.lag_after - lag.lag_before;
  const auto row = [](int l) {
    return l == 0 ? std::string("row k") : fmt::format("row k {} {}", l < 0 ? '-' : '+', std::abs(l));
  };
  return fmt::format(
      "camera {} {} {} frame{} at its row {} ({:+.1f} ms on the video clock) that camera {} did not: its {} matches "
      "camera {}'s row k before that row and its {} from it on (the base markers reproject {:.2g} px RMS so, against "
      "{:.2g} px with any one lag for the whole trial); every position from that row on is triangulated from two "
      "instants",
      lag.name, d < 0 ? "lost" : "repeated", std::abs(d), std::abs(d) == 1 ? "" : "s", lag.change_row,
      1e3 * (lag.change_row - o.trigger_frame) / o.frame_rate_hz, lag.reference, row(lag.lag_before), lag.reference,
      row(lag.lag_after), lag.split_rms_px, lag.rms_px(lag.best_lag));
}

}  // namespace

void apply_calibration_gates(TrialResult& result, const reconstruction::Trajectories& markers,
                             const TrialOptions& options, const CalibrationQuality& quality) {
  std::vector<double> r, change;
  for (int p : options.base_markers) {
    if (p < 0 || p >= markers.n_points()) continue;
    for (int i = 0; i < markers.n_frames(); ++i) {
      const double v = markers.residual_px(i, p);
      if (std::isfinite(v)) r.push_back(v);
      if (i > 0 && std::isfinite(v) && std::isfinite(markers.residual_px(i - 1, p)))
        change.push_back(std::abs(v - markers.residual_px(i - 1, p)));
    }
  }
  std::vector<std::string> reasons;
  if (!quality.problem.empty()) reasons.push_back(quality.problem);
  if (!r.empty()) {
    std::nth_element(r.begin(), r.begin() + static_cast<std::ptrdiff_t>(r.size() / 2), r.end());
    result.reprojection_residual_px = r[r.size() / 2];
    const double limit =
        std::max(kMinResidualLimitPx, kResidualFactor * (std::isfinite(quality.fit_rms_px) ? quality.fit_rms_px : 0.0));
    if (!(result.reprojection_residual_px <= limit)) {
      reasons.push_back(fmt::format(
          "markers reproject {:.3g} px from where they were digitised (median over the base markers; the calibration "
          "fits its points to {:.2g} px, limit {:.2g} px): check the order of [video].cameras and of the tracked points, "
          "and that each camera's pixel rows run the way its calibration's do (DLTdv's v runs up from the bottom-left "
          "corner; many trackers' runs down from the top-left)",
          result.reprojection_residual_px, quality.fit_rms_px, limit));
    }
  }
  for (const auto& lag : markers.camera_lags) {
    // A lag that changes part-way leaves the rays meeting as well as the
    // calibration's own do; one that only trades a steady miss (a camera
    // moved) against the marker's motion, which reverses at the bottom,
    // leaves several times that.
    const bool meets = !std::isfinite(quality.fit_rms_px) ||
                       lag.split_rms_px <= reconstruction::kLagResidualFactor * quality.fit_rms_px;
    if (lag.changes_part_way() && meets) {
      reasons.push_back(camera_lag_change_reason(lag, options));
      continue;
    }
    if (!lag.desynchronised()) continue;
    reasons.push_back(fmt::format(
        "the cameras' rows are not the same instants: the base markers reproject {:.2g} px RMS with the rows as "
        "they stand and {:.2g} px when camera {}'s row k + {} is read beside camera {}'s row k (the cameras were not "
        "synchronised, or one lost or repeated a frame: align the rows, e.g. with DLTdv's frame offsets)",
        lag.rms_px(0), lag.rms_px(lag.best_lag), lag.name, lag.best_lag, lag.reference));
  }
  if (reasons.empty() && change.size() >= 20 && std::isfinite(quality.fit_rms_px)) {
    const double steady = median(change), calibration_px = quality.fit_rms_px;
    if (result.reprojection_residual_px > kSteadyResidualFactor * std::max(steady, calibration_px))
      reasons.push_back(fmt::format(
          "the cameras' rays miss each other by a steady {:.2g} px (median over the base markers; it changes by "
          "{:.2g} px from frame to frame, so it is not the digitising noise, and the calibration leaves {:.2g} px "
          "between its own rays): a camera moved after calibration (a bumped tripod or lens), the calibration is "
          "another setup's, or one camera's rows lost a frame the other's did not; every position, and the impact "
          "velocity, is measured through the wrong rays",
          result.reprojection_residual_px, steady, calibration_px));
  }
  if (reasons.empty()) return;
  // Rays that do not meet make every measurement of the trial wrong (the
  // fall's acceleration, the tilt): they are its first reason.
  std::string first = join(reasons, "; ");
  result.reject_reason = result.reject_reason.empty() ? first : first + "; " + result.reject_reason;
  result.accepted = false;
}

void add_calibration_uncertainty(TrialResult& result, const CalibrationQuality& quality) {
  const bool checked = std::isfinite(quality.vertical_scale_sd);
  if (!checked && !quality.declared_term) {
    // No camera calibration measured these positions: no term, and said so.
    result.calibration_uncertainty =
        fmt::format("none: {}; the interval is the free-fall fit's alone", quality.unchecked_reason);
    return;
  }
  const double sd = checked ? quality.vertical_scale_sd : kDeclaredCalibrationScaleSd;
  result.calibration_scale_sd = sd;
  result.calibration_uncertainty =
      checked ? "check markers"
              : fmt::format("declared: {}, so its vertical scale is taken as accurate to {:.2g} %",
                            quality.unchecked_reason, 100.0 * sd);
  // Travel measured from the manifest's mat top (no surface reference): the
  // calibration's error at that height.
  if (!std::isfinite(result.contact_height_se_m) && std::isfinite(result.contact_height_m)) {
    result.contact_height_se_m = sd * std::abs(result.contact_height_m);
    if (std::isfinite(result.video_contact_time_se_s) && result.impact_velocity_m_s > 0.0)
      result.video_contact_time_se_s =
          std::hypot(result.video_contact_time_se_s, result.contact_height_se_m / result.impact_velocity_m_s);
  }
  if (!std::isfinite(result.impact_velocity_ci_m_s)) return;
  result.impact_velocity_ci_m_s =
      std::hypot(result.impact_velocity_ci_m_s, 1.96 * std::abs(result.impact_velocity_m_s) * sd);
}

std::string TrialResult::report() const {
  std::string out = fmt::format("trial {}: {}{}\n", id, accepted ? "accepted" : "rejected: ", reject_reason);
  out += fmt::format("  impact velocity {:.3f} +- {:.3f} m/s (95 %, {} free-fall frames, rms {:.2f} mm)\n",
                     impact_velocity_m_s, impact_velocity_ci_m_s, freefall_frames, 1e3 * freefall_rms_m);
  out += fmt::format("  max deformation {:.1f} mm; tilt {:.1f} deg\n", 1e3 * max_deformation_m, tilt_deg);
  out += fmt::format("  peak force {:.0f} N, {:.1f} ms after contact; contact at {:+.2f} ms (force clock)\n",
                     peak_force_n, 1e3 * time_to_peak_s, 1e3 * contact_time_s);
  out += fmt::format("  video offset {:+.2f} ms (contact instant), {:+.2f} ms (trajectory); impulse ratio {:.3f}\n",
                     1e3 * video_offset_s, 1e3 * video_offset_trajectory_s, impulse_ratio);
  return out;
}

}  // namespace dropfit::trial
