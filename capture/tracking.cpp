#include "capture/tracking.h"

#include <fmt/format.h>
#include <Eigen/Cholesky>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <optional>
#include <sstream>
#include <utility>

#include "core/error.h"
#include "core/progress.h"
#include "core/validate.h"

namespace dropfit::capture {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---- Connected components in a window ---------------------------------------

// One 4-connected blob of pixels above the threshold, with the sums its
// centre and shape come from.
struct Component {
  int area = 0;
  double sw = 0, swx = 0, swy = 0;           // weights I - threshold
  double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;  // unweighted, for the shape
  int peak = 0;
  bool touches_window = false;
  bool touches_image = false;

  Eigen::Vector2d centre_px() const { return {swx / sw, swy / sw}; }
  double axis_ratio() const {
    const double n = area;
    const double mx = sx / n, my = sy / n;
    const double cxx = sxx / n - mx * mx + 1.0 / 12.0;  // + the pixel's own extent
    const double cyy = syy / n - my * my + 1.0 / 12.0;
    const double cxy = sxy / n - mx * my;
    const double mean = 0.5 * (cxx + cyy);
    const double diff = std::sqrt(0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy);
    const double major = mean + diff, minor = std::max(mean - diff, 0.0);
    return major > 0 ? std::sqrt(minor / major) : 1.0;
  }
};

PixelWindow clip(PixelWindow w, int width, int height) {
  w.x0 = std::clamp(w.x0, 0, width);
  w.x1 = std::clamp(w.x1, 0, width);
  w.y0 = std::clamp(w.y0, 0, height);
  w.y1 = std::clamp(w.y1, 0, height);
  return w;
}

bool empty(const PixelWindow& w) { return w.x1 <= w.x0 || w.y1 <= w.y0; }

PixelWindow window_around(const Eigen::Vector2d& c, double half, int width, int height) {
  PixelWindow w;
  w.x0 = static_cast<int>(std::floor(c.x() - half));
  w.y0 = static_cast<int>(std::floor(c.y() - half));
  w.x1 = static_cast<int>(std::ceil(c.x() + half));
  w.y1 = static_cast<int>(std::ceil(c.y() + half));
  return clip(w, width, height);
}

// Scratch buffers reused from window to window, so tracking allocates nothing
// per frame once warmed up.
class WindowScanner {
 public:
  // Median of the window's border pixels: the local background.
  double background(const ImageView8& img, const PixelWindow& w) {
    ring_.clear();
    for (int x = w.x0; x < w.x1; ++x) {
      ring_.push_back(img.at(x, w.y0));
      if (w.y1 - 1 > w.y0) ring_.push_back(img.at(x, w.y1 - 1));
    }
    for (int y = w.y0 + 1; y < w.y1 - 1; ++y) {
      ring_.push_back(img.at(w.x0, y));
      if (w.x1 - 1 > w.x0) ring_.push_back(img.at(w.x1 - 1, y));
    }
    const auto mid = ring_.begin() + static_cast<std::ptrdiff_t>(ring_.size() / 2);
    std::nth_element(ring_.begin(), mid, ring_.end());
    return *mid;
  }

  // Brightest pixel within `radius` of `c` (inside the window).
  static int peak_near(const ImageView8& img, const PixelWindow& w, const Eigen::Vector2d& c, double radius) {
    int peak = 0;
    const double r2 = radius * radius;
    for (int y = w.y0; y < w.y1; ++y) {
      const double dy = y + 0.5 - c.y();
      if (dy * dy > r2) continue;
      const std::uint8_t* row = img.row(y);
      for (int x = w.x0; x < w.x1; ++x) {
        const double dx = x + 0.5 - c.x();
        if (dx * dx + dy * dy <= r2) peak = std::max<int>(peak, row[x]);
      }
    }
    return peak;
  }

  static int peak(const ImageView8& img, const PixelWindow& w) {
    int peak = 0;
    for (int y = w.y0; y < w.y1; ++y) {
      const std::uint8_t* row = img.row(y);
      for (int x = w.x0; x < w.x1; ++x) peak = std::max<int>(peak, row[x]);
    }
    return peak;
  }

  // 4-connected components of pixels > threshold in the window.
  const std::vector<Component>& components(const ImageView8& img, const PixelWindow& w, double threshold) {
    comps_.clear();
    const int ww = w.x1 - w.x0, wh = w.y1 - w.y0;
    if (ww <= 0 || wh <= 0) return comps_;
    const int above = static_cast<int>(std::floor(threshold)) + 1;  // first grey level above
    if (above > 255) return comps_;
    visited_.assign(static_cast<std::size_t>(ww) * wh, 0);
    for (int y = 0; y < wh; ++y) {
      const std::uint8_t* row = img.row(w.y0 + y) + w.x0;
      for (int x = 0; x < ww; ++x) {
        if (row[x] < above || visited_[y * ww + x]) continue;
        Component c;
        stack_.clear();
        stack_.push_back(y * ww + x);
        visited_[y * ww + x] = 1;
        while (!stack_.empty()) {
          const int i = stack_.back();
          stack_.pop_back();
          const int ly = i / ww, lx = i - ly * ww;
          const int gx = w.x0 + lx, gy = w.y0 + ly;
          const int v = img.at(gx, gy);
          const double wgt = v - threshold;
          const double px = gx + 0.5, py = gy + 0.5;
          c.area += 1;
          c.sw += wgt;
          c.swx += wgt * px;
          c.swy += wgt * py;
          c.sx += px;
          c.sy += py;
          c.sxx += px * px;
          c.syy += py * py;
          c.sxy += px * py;
          c.peak = std::max(c.peak, v);
          if (lx == 0 || ly == 0 || lx == ww - 1 || ly == wh - 1) {
            const bool at_image = (lx == 0 && gx == 0) || (ly == 0 && gy == 0) ||
                                  (lx == ww - 1 && gx == img.width - 1) || (ly == wh - 1 && gy == img.height - 1);
            if (at_image) c.touches_image = true;
            else c.touches_window = true;
          }
          auto visit = [&](int j, int jx, int jy) {
            if (visited_[j]) return;
            if (img.at(w.x0 + jx, w.y0 + jy) < above) return;
            visited_[j] = 1;
            stack_.push_back(j);
          };
          if (lx > 0) visit(i - 1, lx - 1, ly);
          if (lx < ww - 1) visit(i + 1, lx + 1, ly);
          if (ly > 0) visit(i - ww, lx, ly - 1);
          if (ly < wh - 1) visit(i + ww, lx, ly + 1);
        }
        comps_.push_back(c);
      }
    }
    return comps_;
  }

 private:
  std::vector<std::uint8_t> ring_;
  std::vector<std::uint8_t> visited_;
  std::vector<int> stack_;
  std::vector<Component> comps_;
};

}  // namespace

// ---- detect_blobs -------------------------------------------------------------

void DetectionOptions::validate() const {
  constexpr std::string_view w = "tracking options";
  check::in_range(w, "detection.threshold_fraction", threshold_fraction, 0.0, 1.0);
  check::non_negative(w, "detection.min_contrast", min_contrast);
  check::non_negative(w, "detection.min_area_px2", min_area_px2);
  check::positive(w, "detection.max_area_px2", max_area_px2);
  if (max_area_px2 < min_area_px2)
    throw Error(fmt::format("tracking options: detection.max_area_px2 = {} (below detection.min_area_px2 = {})",
                            max_area_px2, min_area_px2));
  check::in_range(w, "detection.min_axis_ratio", min_axis_ratio, 0.0, 1.0);
}

void TrackingOptions::validate() const {
  constexpr std::string_view w = "tracking options";
  detection.validate();
  check::positive(w, "gate_px", gate_px);
  check::non_negative(w, "widen_px_per_frame", widen_px_per_frame);
  check::positive(w, "max_gate_px", max_gate_px);
  if (max_gate_px < gate_px)
    throw Error(fmt::format("tracking options: max_gate_px = {} (below gate_px = {})", max_gate_px, gate_px));
  check::at_least(w, "max_lost_frames", max_lost_frames, 0);
  check::positive(w, "seed_radius_px", seed_radius_px);
  check::in_range(w, "ambiguity_ratio", ambiguity_ratio, 1.0, 1e6);
  check::in_range(w, "min_area_ratio", min_area_ratio, 0.0, 1.0);
  check::in_range(w, "max_area_ratio", max_area_ratio, 1.0, 1e6);
  check::in_range(w, "max_axis_ratio_drop", max_axis_ratio_drop, 0.0, 1.0);
  check::in_range(w, "min_contrast_ratio", min_contrast_ratio, 0.0, 1.0);
}

std::vector<Blob> detect_blobs(const ImageView8& image, const DetectionOptions& options, PixelWindow window) {
  options.validate();
  if (empty(window)) window = {0, 0, image.width, image.height};
  window = clip(window, image.width, image.height);
  std::vector<Blob> blobs;
  if (empty(window)) return blobs;
  WindowScanner scan;
  const double bg = scan.background(image, window);
  const double contrast = WindowScanner::peak(image, window) - bg;
  if (contrast < options.min_contrast) return blobs;
  const double threshold = bg + std::max(options.threshold_fraction * contrast, 0.5 * options.min_contrast);
  for (const Component& c : scan.components(image, window, threshold)) {
    if (c.touches_window) continue;
    if (c.area < options.min_area_px2 || c.area > options.max_area_px2) continue;
    if (c.peak - bg < options.min_contrast) continue;
    const double ratio = c.axis_ratio();
    if (ratio < options.min_axis_ratio) continue;
    blobs.push_back({c.centre_px(), static_cast<double>(c.area), ratio, c.peak - bg, c.touches_image});
  }
  std::stable_sort(blobs.begin(), blobs.end(), [](const Blob& a, const Blob& b) { return a.contrast > b.contrast; });
  return blobs;
}

// ---- Flags, gaps, report ----------------------------------------------------

const char* to_string(TrackFlag flag) {
  switch (flag) {
    case TrackFlag::BeforeSeed: return "before-seed";
    case TrackFlag::Tracked: return "tracked";
    case TrackFlag::Reacquired: return "reacquired";
    case TrackFlag::Missing: return "missing";
    case TrackFlag::Rejected: return "rejected";
    case TrackFlag::Ambiguous: return "ambiguous";
    case TrackFlag::Shared: return "shared";
    case TrackFlag::GivenUp: return "given-up";
  }
  return "?";
}

std::vector<TrackGap> TrackingResult::gaps() const {
  std::vector<TrackGap> out;
  const int n = tracks.n_frames(), np = tracks.n_points();
  for (int p = 0; p < np; ++p) {
    int f = 0;
    while (f < n) {
      if (!is_gap(flag(f, p))) {
        ++f;
        continue;
      }
      TrackGap g;
      g.point = tracks.points[p];
      g.first_frame = f;
      while (f < n && is_gap(flag(f, p))) ++f;
      g.last_frame = f - 1;
      g.reacquired = f < n && flag(f, p) == TrackFlag::Reacquired;
      out.push_back(g);
    }
  }
  return out;
}

std::string TrackingResult::report() const {
  const int n = tracks.n_frames(), np = tracks.n_points();
  std::string out = fmt::format("tracking {}: {} frames, {} points\n",
                                tracks.cameras.empty() ? std::string("?") : tracks.cameras[0], n, np);
  const auto gap_list = gaps();
  for (int p = 0; p < np; ++p) {
    int found = 0, before = 0;
    for (int f = 0; f < n; ++f) {
      const TrackFlag fl = flag(f, p);
      if (fl == TrackFlag::Tracked || fl == TrackFlag::Reacquired) ++found;
      if (fl == TrackFlag::BeforeSeed) ++before;
    }
    int n_gaps = 0, gap_frames = 0;
    for (const auto& g : gap_list) {
      if (g.point != tracks.points[p]) continue;
      ++n_gaps;
      gap_frames += g.last_frame - g.first_frame + 1;
    }
    if (before == n) {
      out += fmt::format("  {}: not seeded\n", tracks.points[p]);
      continue;
    }
    out += fmt::format("  {}: found in {} frames, {} gap(s) totalling {} frames\n", tracks.points[p], found, n_gaps,
                       gap_frames);
  }
  if (!warnings.empty()) out += fmt::format("  {} warning(s):\n", warnings.size());
  const std::size_t shown = std::min<std::size_t>(warnings.size(), 20);
  for (std::size_t i = 0; i < shown; ++i) {
    const auto& w = warnings[i];
    if (w.last_frame > w.frame)
      out += fmt::format("    {} frames {}-{}: {}\n", w.point, w.frame, w.last_frame, w.reason);
    else
      out += fmt::format("    {} frame {}: {}\n", w.point, w.frame, w.reason);
  }
  if (shown < warnings.size()) out += fmt::format("    ... and {} more\n", warnings.size() - shown);
  return out;
}

// ---- MarkerTracker ------------------------------------------------------------

namespace {

struct PointState {
  std::optional<Seed> seed;
  bool started = false;
  bool given_up = false;
  int last_seen = -1;
  std::vector<std::pair<int, Eigen::Vector2d>> history;  // last few detections (frame, centre)
  double area_ref = 0, contrast_ref = 0, radius_ref = 0, axis_ref = 1;
  Eigen::Vector2d prediction = Eigen::Vector2d::Zero();  // this frame's
};

// A blob seen from one marker's window, with its distance to the prediction.
struct Candidate {
  Blob blob;
  double distance = 0;
  std::string problem;  // empty when plausible for this marker
  bool too_large = false;
};

// A marker's decision for this frame, before markers are compared.
struct Proposal {
  bool has_blob = false;
  Blob blob;
  TrackFlag flag = TrackFlag::Missing;
  std::string reason;          // for a gap
  std::string second_warning;  // tracked, but another blob lies in the gate
  bool merged = false;         // rejected as too large: perhaps two markers
};

}  // namespace

struct MarkerTracker::Impl {
  std::string camera;
  std::vector<std::string> points;
  TrackingOptions opt;
  std::vector<PointState> state;
  int width = 0, height = 0;
  int n_frames = 0;
  std::vector<double> uv;  // n_frames x 2 n_points
  std::vector<TrackFlag> flags;
  std::vector<TrackWarning> warnings;
  std::map<std::pair<int, std::string>, std::size_t> open_warning;  // (point, reason) -> last index
  WindowScanner scan;

  [[noreturn]] void seed_error(const Seed& s, const std::string& field, const std::string& reason) const {
    if (!s.source.empty()) throw InputError(s.source, s.line, 0, field, reason);
    throw Error(fmt::format("seed for {}: {}", s.point, reason));
  }

  void warn(int p, int frame, const std::string& reason) {
    const auto key = std::make_pair(p, reason);
    auto it = open_warning.find(key);
    if (it != open_warning.end() && warnings[it->second].last_frame == frame - 1) {
      warnings[it->second].last_frame = frame;
      return;
    }
    open_warning[key] = warnings.size();
    warnings.push_back({points[p], frame, frame, reason});
  }

  double same_blob_px(int a, int b) const {
    return std::max(1.0, 0.5 * std::min(state[a].radius_ref, state[b].radius_ref));
  }

  // Where point s should be at `frame`: constant velocity from the last two
  // detections (or constant acceleration from a least-squares quadratic
  // through the last six); through a gap, constant velocity.
  Eigen::Vector2d predict(const PointState& s, int frame) const {
    const auto& h = s.history;
    const auto& [f1, p1] = h.back();
    const double dt = frame - f1;
    if (h.size() < 2) return p1;
    if (dt > 1.0 && opt.motion == MotionModel::ConstantVelocity) {
      // Coasting through a gap: the velocity of a least-squares line through
      // the last (up to) four detections, less sensitive to the last one.
      const std::size_t n = std::min<std::size_t>(h.size(), 4);
      double st = 0, stt = 0;
      Eigen::Vector2d sp = Eigen::Vector2d::Zero(), stp = Eigen::Vector2d::Zero();
      for (std::size_t i = h.size() - n; i < h.size(); ++i) {
        const double t = h[i].first - f1;
        st += t;
        stt += t * t;
        sp += h[i].second;
        stp += t * h[i].second;
      }
      const double den = n * stt - st * st;
      if (den > 0) return p1 + (n * stp - st * sp) / den * dt;
    }
    if (opt.motion == MotionModel::ConstantAcceleration && h.size() >= 3) {
      // Least-squares quadratic in t = f - f1 through the last detections.
      Eigen::Matrix3d ata = Eigen::Matrix3d::Zero();
      Eigen::Matrix<double, 3, 2> atb = Eigen::Matrix<double, 3, 2>::Zero();
      for (const auto& [f, p] : h) {
        const double t = f - f1;
        const Eigen::Vector3d a(1.0, t, t * t);
        ata += a * a.transpose();
        atb += a * p.transpose();
      }
      const Eigen::Matrix<double, 3, 2> coef = ata.ldlt().solve(atb);
      const Eigen::Vector2d c0 = coef.row(0).transpose(), c1 = coef.row(1).transpose(),
                            c2 = coef.row(2).transpose();
      if (dt <= 1.0) return c0 + c1 * dt + c2 * dt * dt;
      return c0 + c1 * dt;  // coasting through a gap: constant velocity
    }
    const auto& [f0, p0] = h[h.size() - 2];
    const Eigen::Vector2d v = (p1 - p0) / static_cast<double>(f1 - f0);
    return p1 + v * dt;
  }

  void start_point(int p, const ImageView8& img, int frame) {
    PointState& s = state[p];
    const Seed& seed = *s.seed;
    const double max_radius = std::sqrt(opt.detection.max_area_px2 / std::numbers::pi);
    const PixelWindow w = window_around(seed.uv_px, opt.seed_radius_px + max_radius + 3.0, width, height);
    const double bg = scan.background(img, w);
    const double contrast = WindowScanner::peak_near(img, w, seed.uv_px, opt.seed_radius_px) - bg;
    if (contrast < opt.detection.min_contrast)
      seed_error(seed, "u_px",
                 fmt::format("no marker within {:g} px of the seed ({:.1f}, {:.1f}) for {} in frame {} (brightest "
                             "pixel {:.0f} grey levels above the background)",
                             opt.seed_radius_px, seed.uv_px.x(), seed.uv_px.y(), seed.point, frame, contrast));
    const double threshold = bg + std::max(opt.detection.threshold_fraction * contrast, 0.5 * opt.detection.min_contrast);
    std::vector<Candidate> near;
    for (const Component& c : scan.components(img, w, threshold)) {
      const double d = (c.centre_px() - seed.uv_px).norm();
      if (d > opt.seed_radius_px) continue;
      if (c.area < opt.detection.min_area_px2 || c.peak - bg < opt.detection.min_contrast) continue;
      Candidate cand;
      cand.blob = {c.centre_px(), static_cast<double>(c.area), c.axis_ratio(), c.peak - bg, c.touches_image};
      cand.distance = d;
      if (c.touches_image) cand.problem = "touches the image edge";
      else if (c.touches_window || c.area > opt.detection.max_area_px2) cand.problem = "is larger than max_area_px2";
      else if (cand.blob.axis_ratio < opt.detection.min_axis_ratio) cand.problem = "is not round";
      near.push_back(cand);
    }
    std::sort(near.begin(), near.end(), [](const Candidate& a, const Candidate& b) { return a.distance < b.distance; });
    if (near.empty())
      seed_error(seed, "u_px",
                 fmt::format("no marker within {:g} px of the seed ({:.1f}, {:.1f}) for {} in frame {}",
                             opt.seed_radius_px, seed.uv_px.x(), seed.uv_px.y(), seed.point, frame));
    if (near.size() > 1 && near[1].distance < opt.ambiguity_ratio * std::max(near[0].distance, 0.5))
      seed_error(seed, "u_px",
                 fmt::format("two markers within {:g} px of the seed for {} in frame {}, at ({:.1f}, {:.1f}) and "
                             "({:.1f}, {:.1f}); give the seed closer to one of them",
                             opt.seed_radius_px, seed.point, frame, near[0].blob.centre_px.x(),
                             near[0].blob.centre_px.y(), near[1].blob.centre_px.x(), near[1].blob.centre_px.y()));
    if (!near[0].problem.empty())
      seed_error(seed, "u_px",
                 fmt::format("the marker nearest the seed for {} in frame {} {}", seed.point, frame, near[0].problem));
    const Blob& b = near[0].blob;
    s.started = true;
    s.area_ref = b.area_px2;
    s.contrast_ref = b.contrast;
    s.radius_ref = std::sqrt(b.area_px2 / std::numbers::pi);
    s.axis_ref = b.axis_ratio;
    s.last_seen = frame;
    s.history.assign(1, {frame, b.centre_px});
    set(frame, p, b.centre_px, TrackFlag::Tracked);
  }

  void set(int frame, int p, const Eigen::Vector2d& uv_px, TrackFlag flag) {
    const std::size_t row = static_cast<std::size_t>(frame) * points.size();
    flags[row + p] = flag;
    uv[2 * (row + p)] = uv_px.x();
    uv[2 * (row + p) + 1] = uv_px.y();
  }

  // Every blob in point p's gate, with what (if anything) makes it implausible.
  // `neighbours` counts the other marker-like blobs in the search window
  // beyond the gate.
  std::vector<Candidate> candidates(int p, const ImageView8& img, const Eigen::Vector2d& pred, double gate,
                                    int& neighbours) {
    const PointState& s = state[p];
    std::vector<Candidate> out;
    neighbours = 0;
    const PixelWindow w = window_around(pred, gate + 2.0 * s.radius_ref + 3.0, width, height);
    if (empty(w) || w.x1 - w.x0 < 3 || w.y1 - w.y0 < 3) return out;
    const double bg = scan.background(img, w);
    const double threshold =
        bg + std::max(opt.detection.threshold_fraction * s.contrast_ref, 0.5 * opt.detection.min_contrast);
    for (const Component& c : scan.components(img, w, threshold)) {
      if (c.area < opt.detection.min_area_px2) continue;  // a speck of noise
      const double contrast = c.peak - bg;
      if (contrast < opt.detection.min_contrast) continue;
      const Eigen::Vector2d centre = c.centre_px();
      const double d = (centre - pred).norm();
      if (d > gate) {
        if (!c.touches_window && !c.touches_image && c.area >= opt.min_area_ratio * s.area_ref &&
            c.area <= opt.max_area_ratio * s.area_ref)
          ++neighbours;
        continue;
      }
      Candidate cand;
      cand.blob = {centre, static_cast<double>(c.area), c.axis_ratio(), contrast, c.touches_image};
      cand.distance = d;
      if (c.touches_image) cand.problem = "blob at the image edge";
      else if (c.touches_window) cand.problem = "blob larger than the search window (merged markers?)";
      else if (c.area > opt.max_area_ratio * s.area_ref || c.area > opt.detection.max_area_px2)
        cand.problem = "blob too large (merged markers?)";
      else if (c.area < opt.min_area_ratio * s.area_ref) cand.problem = "blob too small (partly hidden?)";
      else if (cand.blob.axis_ratio < opt.detection.min_axis_ratio ||
               cand.blob.axis_ratio < s.axis_ref - opt.max_axis_ratio_drop)
        cand.problem = "blob not round (partly hidden?)";
      else if (contrast < opt.min_contrast_ratio * s.contrast_ref) cand.problem = "blob too faint";
      cand.too_large = !c.touches_image && (c.touches_window || c.area > opt.max_area_ratio * s.area_ref);
      out.push_back(cand);
    }
    std::sort(out.begin(), out.end(), [](const Candidate& a, const Candidate& b) { return a.distance < b.distance; });
    return out;
  }

  // The nearest plausible candidate, if it is clearly the nearest.
  Proposal choose(const std::vector<Candidate>& cands, int neighbours, bool reacquiring) const {
    Proposal prop;
    if (cands.empty()) {
      prop.flag = TrackFlag::Missing;
      prop.reason = "lost: no marker near the prediction";
      return prop;
    }
    const Candidate& best = cands.front();
    if (!best.problem.empty()) {
      prop.flag = TrackFlag::Rejected;
      prop.reason = "lost: " + best.problem;
      prop.blob = best.blob;
      prop.merged = best.too_large;
      return prop;
    }
    if (cands.size() > 1) {
      const double d1 = std::max(best.distance, 0.5);
      if (cands[1].distance < opt.ambiguity_ratio * d1) {
        prop.flag = TrackFlag::Ambiguous;
        prop.reason = reacquiring ? "re-acquisition refused: two candidates at similar distance"
                                  : "gap: two candidates at similar distance from the prediction";
        return prop;
      }
    }
    if (cands.size() > 1 || neighbours > 0) prop.second_warning = "another marker inside the search window (could be confused)";
    prop.has_blob = true;
    prop.blob = best.blob;
    prop.flag = reacquiring ? TrackFlag::Reacquired : TrackFlag::Tracked;
    return prop;
  }

  void accept(int frame, int p, const Blob& b, TrackFlag flag) {
    PointState& s = state[p];
    set(frame, p, b.centre_px, flag);
    s.last_seen = frame;
    s.history.emplace_back(frame, b.centre_px);
    if (s.history.size() > 6) s.history.erase(s.history.begin());
    constexpr double kFollow = 0.2;  // slow update of the marker's size, shape and contrast
    s.area_ref += kFollow * (b.area_px2 - s.area_ref);
    s.contrast_ref += kFollow * (b.contrast - s.contrast_ref);
    s.axis_ref += kFollow * (b.axis_ratio - s.axis_ref);
    s.radius_ref = std::sqrt(s.area_ref / std::numbers::pi);
  }

  // For a blob rejected as too large for p: the other marker whose
  // prediction it covers (the two have merged in the image), or -1.
  int merged_with(int p, const Proposal& prop, int frame) const {
    if (prop.has_blob || prop.flag != TrackFlag::Rejected || !prop.merged) return -1;
    const double reach = std::sqrt(prop.blob.area_px2 / std::numbers::pi);
    for (int q = 0; q < static_cast<int>(points.size()); ++q) {
      const PointState& s = state[q];
      if (q == p || !s.started || s.given_up || s.last_seen == frame) continue;
      if ((s.prediction - prop.blob.centre_px).norm() <= reach) return q;
    }
    return -1;
  }

  // Checks the frame against the first (and the seeds against its size),
  // then makes room for its row; returns its index.
  int begin_frame(const ImageView8& img) {
    const int frame = n_frames;
    if (img.data == nullptr || img.width <= 0 || img.height <= 0) throw Error(fmt::format("{}: frame {} is empty", camera, frame));
    if (frame == 0) {
      width = img.width;
      height = img.height;
      for (const PointState& s : state) {
        if (!s.seed) continue;
        const Eigen::Vector2d& uv_px = s.seed->uv_px;
        if (!(uv_px.x() >= 0 && uv_px.x() < width && uv_px.y() >= 0 && uv_px.y() < height))
          seed_error(*s.seed, uv_px.x() >= 0 && uv_px.x() < width ? "v_px" : "u_px",
                     fmt::format("seed ({:.1f}, {:.1f}) for {} lies outside the {} x {} image", uv_px.x(), uv_px.y(),
                                 s.seed->point, width, height));
      }
    } else if (img.width != width || img.height != height) {
      throw Error(fmt::format("{}: frame {} is {} x {}, earlier frames {} x {}", camera, frame, img.width, img.height,
                              width, height));
    }
    ++n_frames;
    uv.resize(uv.size() + 2 * points.size(), kNaN);
    flags.resize(flags.size() + points.size(), TrackFlag::BeforeSeed);
    return frame;
  }

  using Claims = std::vector<std::pair<Eigen::Vector2d, int>>;  // blob centres held this frame, by whom

  // Starts the points seeded in this frame (their blobs claimed), gives up
  // those lost too long, and sorts the others into tracked in the previous
  // frame and lost.
  void sort_points(const ImageView8& img, int frame, std::vector<int>& tracked, std::vector<int>& lost,
                   Claims& claimed) {
    const int np = static_cast<int>(points.size());
    for (int p = 0; p < np; ++p) {
      PointState& s = state[p];
      if (!s.started) {
        if (s.seed && s.seed->frame == frame) {
          start_point(p, img, frame);
          claimed.emplace_back(s.history.back().second, p);
        }
        continue;
      }
      if (s.given_up) {
        flags[static_cast<std::size_t>(frame) * np + p] = TrackFlag::GivenUp;
        continue;
      }
      if (frame - s.last_seen > opt.max_lost_frames) {
        s.given_up = true;
        flags[static_cast<std::size_t>(frame) * np + p] = TrackFlag::GivenUp;
        warn(p, frame, fmt::format("lost for more than {} frames; no longer searched for", opt.max_lost_frames));
        continue;
      }
      (s.last_seen == frame - 1 ? tracked : lost).push_back(p);
    }
  }

  // Tracked markers: each picks its blob; two picking one blob overlap (a
  // gap for both), as does a blob too large for a marker that also covers
  // another marker's prediction (the two have merged in the image).
  void place_tracked(const ImageView8& img, int frame, const std::vector<int>& tracked, std::vector<Proposal>& props,
                     Claims& claimed) {
    const int np = static_cast<int>(points.size());
    for (int p : tracked) {
      int neighbours = 0;
      const auto cands = candidates(p, img, state[p].prediction, opt.gate_px, neighbours);
      props[p] = choose(cands, neighbours, false);
    }
    std::vector<bool> shared(np, false);
    const auto overlap = [&](int a, int b) {
      shared[a] = true;
      warn(a, frame, fmt::format("gap: overlaps {} in the image (one blob for both)", points[b]));
    };
    for (std::size_t i = 0; i < tracked.size(); ++i)
      for (std::size_t j = i + 1; j < tracked.size(); ++j) {
        const int a = tracked[i], b = tracked[j];
        if (!props[a].has_blob || !props[b].has_blob) continue;
        if ((props[a].blob.centre_px - props[b].blob.centre_px).norm() > same_blob_px(a, b)) continue;
        overlap(a, b);
        overlap(b, a);
      }
    for (int p : tracked)
      if (const int q = merged_with(p, props[p], frame); q >= 0) overlap(p, q);
    for (int p : tracked) {
      Proposal& prop = props[p];
      if (shared[p]) {
        flags[static_cast<std::size_t>(frame) * np + p] = TrackFlag::Shared;
        claimed.emplace_back(prop.blob.centre_px, p);
        continue;
      }
      if (!prop.has_blob) {
        flags[static_cast<std::size_t>(frame) * np + p] = prop.flag;
        warn(p, frame, prop.reason);
        continue;
      }
      if (!prop.second_warning.empty()) warn(p, frame, prop.second_warning);
      claimed.emplace_back(prop.blob.centre_px, p);
    }
    for (int p : tracked)
      if (props[p].has_blob && !shared[p]) accept(frame, p, props[p].blob, TrackFlag::Tracked);
  }

  // Lost markers: re-acquire only an unclaimed, unambiguous candidate that
  // no other lost marker claims too.
  void place_lost(const ImageView8& img, int frame, const std::vector<int>& lost, std::vector<Proposal>& props,
                  const Claims& claimed) {
    const int np = static_cast<int>(points.size());
    for (int p : lost) {
      const PointState& s = state[p];
      const int since = frame - s.last_seen;
      const double gate = std::min(opt.max_gate_px, opt.gate_px + opt.widen_px_per_frame * (since - 1));
      int neighbours = 0;
      std::vector<Candidate> cands = candidates(p, img, s.prediction, gate, neighbours);
      std::string holder;
      std::erase_if(cands, [&](const Candidate& c) {
        for (const auto& [centre, q] : claimed)
          if ((c.blob.centre_px - centre).norm() <= same_blob_px(p, q)) {
            if (holder.empty()) holder = points[q];
            return true;
          }
        return false;
      });
      props[p] = choose(cands, neighbours, true);
      if (props[p].has_blob) continue;
      if (const int q = merged_with(p, props[p], frame); q >= 0) {
        props[p].flag = TrackFlag::Shared;
        props[p].reason = fmt::format("gap: overlaps {} in the image (one blob for both)", points[q]);
        continue;
      }
      if (props[p].flag == TrackFlag::Missing && !holder.empty()) {
        props[p].flag = TrackFlag::Ambiguous;
        props[p].reason = fmt::format("lost: the only blob near the prediction belongs to {}", holder);
      }
    }
    std::vector<bool> clash(np, false);
    for (std::size_t i = 0; i < lost.size(); ++i)
      for (std::size_t j = i + 1; j < lost.size(); ++j) {
        const int a = lost[i], b = lost[j];
        if (!props[a].has_blob || !props[b].has_blob) continue;
        if ((props[a].blob.centre_px - props[b].blob.centre_px).norm() <= same_blob_px(a, b))
          clash[a] = clash[b] = true;
      }
    for (int p : lost)
      if (clash[p]) {
        props[p].has_blob = false;
        props[p].flag = TrackFlag::Ambiguous;
        props[p].reason = "re-acquisition refused: another lost marker claims the same blob";
      }
    for (int p : lost) {
      const Proposal& prop = props[p];
      if (prop.has_blob) {
        accept(frame, p, prop.blob, TrackFlag::Reacquired);
        if (!prop.second_warning.empty()) warn(p, frame, prop.second_warning);
      } else {
        flags[static_cast<std::size_t>(frame) * np + p] = prop.flag;
        warn(p, frame, prop.reason);
      }
    }
  }

  void add_frame(const ImageView8& img) {
    const int frame = begin_frame(img);
    // Markers tracked in the previous frame first, then lost ones, which
    // may not take a blob a tracked marker holds.
    std::vector<int> tracked, lost;
    Claims claimed;
    sort_points(img, frame, tracked, lost, claimed);
    for (int p : tracked) state[p].prediction = predict(state[p], frame);
    for (int p : lost) state[p].prediction = predict(state[p], frame);
    std::vector<Proposal> props(points.size());
    place_tracked(img, frame, tracked, props, claimed);
    place_lost(img, frame, lost, props, claimed);
  }
};

MarkerTracker::MarkerTracker(std::string camera, std::vector<std::string> points, std::vector<Seed> seeds,
                             TrackingOptions options)
    : impl_(std::make_unique<Impl>()) {
  options.validate();
  impl_->camera = std::move(camera);
  impl_->points = std::move(points);
  impl_->opt = options;
  impl_->state.resize(impl_->points.size());
  for (const Seed& s : seeds) {
    const auto it = std::find(impl_->points.begin(), impl_->points.end(), s.point);
    if (it == impl_->points.end())
      impl_->seed_error(s, "point", fmt::format("unknown point '{}' (not in [video].points)", s.point));
    PointState& st = impl_->state[it - impl_->points.begin()];
    if (st.seed) impl_->seed_error(s, "point", fmt::format("point '{}' is seeded twice", s.point));
    if (s.frame < 0) impl_->seed_error(s, "frame", fmt::format("negative frame {}", s.frame));
    if (!std::isfinite(s.uv_px.x()) || !std::isfinite(s.uv_px.y()))
      impl_->seed_error(s, "u_px", "seed position is not a finite number");
    st.seed = s;
  }
}

MarkerTracker::~MarkerTracker() = default;
MarkerTracker::MarkerTracker(MarkerTracker&&) noexcept = default;
MarkerTracker& MarkerTracker::operator=(MarkerTracker&&) noexcept = default;

void MarkerTracker::add_frame(const ImageView8& frame) { impl_->add_frame(frame); }
int MarkerTracker::n_frames() const { return impl_->n_frames; }

TrackingResult MarkerTracker::result() const {
  const Impl& m = *impl_;
  for (const PointState& s : m.state)
    if (s.seed && s.seed->frame >= m.n_frames)
      m.seed_error(*s.seed, "frame",
                   fmt::format("seed frame {} for {} is beyond the footage ({} frames)", s.seed->frame, s.seed->point,
                               m.n_frames));
  TrackingResult r;
  const int np = static_cast<int>(m.points.size());
  r.tracks.points = m.points;
  r.tracks.cameras = {m.camera};
  r.tracks.uv_px.resize(m.n_frames, 2 * np);
  for (int f = 0; f < m.n_frames; ++f)
    for (int c = 0; c < 2 * np; ++c) r.tracks.uv_px(f, c) = m.uv[static_cast<std::size_t>(f) * 2 * np + c];
  r.flags = m.flags;
  r.warnings = m.warnings;
  r.image_width_px = m.width;
  r.image_height_px = m.height;
  std::stable_sort(r.warnings.begin(), r.warnings.end(), [&](const TrackWarning& a, const TrackWarning& b) {
    return a.frame < b.frame;
  });
  return r;
}

TrackingResult shift_frames(TrackingResult r, int first_frame) {
  if (first_frame < 0) throw Error(fmt::format("shift_frames: negative first frame {}", first_frame));
  if (first_frame == 0) return r;
  const int np = r.tracks.n_points();
  const Eigen::Index n = r.tracks.uv_px.rows();
  Eigen::MatrixXd uv(n + first_frame, r.tracks.uv_px.cols());
  uv.topRows(first_frame).setConstant(kNaN);
  uv.bottomRows(n) = r.tracks.uv_px;
  r.tracks.uv_px = std::move(uv);
  r.flags.insert(r.flags.begin(), static_cast<std::size_t>(first_frame) * np, TrackFlag::BeforeSeed);
  for (TrackWarning& w : r.warnings) {
    w.frame += first_frame;
    w.last_frame += first_frame;
  }
  return r;
}

void merge_camera_tracks(MarkerTracks2D& all, const MarkerTracks2D& camera_tracks) {
  if (camera_tracks.n_cameras() != 1) throw Error("merge_camera_tracks: expected one camera's tracks");
  const std::string& cam = camera_tracks.cameras[0];
  const auto cit = std::find(all.cameras.begin(), all.cameras.end(), cam);
  if (cit == all.cameras.end()) throw Error(fmt::format("camera '{}' is not in [video].cameras", cam));
  const int c = static_cast<int>(cit - all.cameras.begin());
  const int width = 2 * all.n_points() * all.n_cameras();
  if (all.uv_px.cols() != width) {
    if (all.uv_px.rows() != 0) throw Error("merge_camera_tracks: track table has the wrong number of columns");
    all.uv_px.resize(0, width);
  }
  if (camera_tracks.n_frames() > all.n_frames()) {
    const int old = all.n_frames();
    all.uv_px.conservativeResize(camera_tracks.n_frames(), width);
    all.uv_px.bottomRows(camera_tracks.n_frames() - old).setConstant(kNaN);
  }
  for (int p = 0; p < camera_tracks.n_points(); ++p) {
    const auto pit = std::find(all.points.begin(), all.points.end(), camera_tracks.points[p]);
    if (pit == all.points.end())
      throw Error(fmt::format("point '{}' is not in [video].points", camera_tracks.points[p]));
    const int col = all.column(static_cast<int>(pit - all.points.begin()), c);
    all.uv_px.col(col).setConstant(kNaN);
    all.uv_px.col(col + 1).setConstant(kNaN);
    all.uv_px.block(0, col, camera_tracks.n_frames(), 2) = camera_tracks.uv_px.middleCols(camera_tracks.column(p, 0), 2);
  }
}

}  // namespace dropfit::capture
