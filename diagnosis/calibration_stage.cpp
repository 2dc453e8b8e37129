// The calibration stage of the loop: outlier markers (single, pairs, label
// swaps) and lens distortion, each decided by leave-one-out cross-validation
// on every marker, fit and check alike (see diagnosis.h).
#include <fmt/format.h>

#include <algorithm>
#include <optional>
#include <cmath>
#include <map>
#include <set>

#include "calibration/triangulation.h"

#include "core/error.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

// Every marker image's reprojection residual split into its radial part
// (along the ray from the image centre) and the normalised radius there.
struct Reprojection {
  std::vector<double> radial_px, radius, distance_px;
};

Reprojection reprojection(const calibration::CalibrationResult& result, const std::vector<calibration::Marker>& markers,
                          const std::vector<calibration::CameraView>& views) {
  std::map<std::string, Eigen::Vector3d> lab;
  for (const auto& m : markers) lab[m.id] = m.lab_m;
  Reprojection rep;
  for (std::size_t c = 0; c < views.size() && c < result.cameras.size(); ++c) {
    const calibration::Camera& cam = result.cameras[c].camera;
    Eigen::Vector2d centre;
    double focal = 0.0;
    if (cam.has_distortion()) {
      centre = cam.principal_point_px;
      focal = cam.focal_px;
    } else if (!calibration::principal_point_and_focal(cam.dlt, &centre, &focal)) {
      continue;  // no principal point: no radius to judge a lens by
    }
    for (const auto& [id, px] : views[c].observations) {
      const auto it = lab.find(id);
      if (it == lab.end() || !px.allFinite()) continue;
      const Eigen::Vector2d proj = cam.project(it->second);
      if (!proj.allFinite()) continue;
      const Eigen::Vector2d e = px - proj;
      const Eigen::Vector2d ray = proj - centre;
      const double r = ray.norm();
      if (r <= 0.0) continue;
      rep.radial_px.push_back(e.dot(ray) / r);
      rep.radius.push_back(r / focal);
      rep.distance_px.push_back(e.norm());
    }
  }
  return rep;
}

// Structure of the radial residual against the radius (r^3: Bouguet's k1).
StructureReport radial_structure(const Reprojection& rep, const DecisionOptions& d) {
  const Eigen::VectorXd e = detail::to_vector(rep.radial_px);
  const Eigen::VectorXd r = detail::to_vector(rep.radius);
  std::vector<Candidate> cands{{"r^3", "the image radius cubed", r.array().cube().matrix()},
                               {"r", "the image radius", r}};
  StructureOptions so;
  so.alpha = d.alpha;
  so.max_lag = 0;  // marker images have no order: no whiteness test
  return analyse_residual(e, cands, so);
}

ErrorSet check_errors(const calibration::CalibrationResult& r) {
  const double rms = std::sqrt(r.check_rms_m.squaredNorm() / 3.0);
  return {{"check_rms_mm", 1000.0 * rms}, {"check_max_mm", 1000.0 * r.check_max_m}};
}

// ---- Leave-one-out cross-validation on every marker ------------------------

// The calibration observations as a table: seen[c][m], NaN when camera c
// does not see marker m.
struct Scene {
  std::vector<calibration::Marker> markers;
  std::vector<std::string> cameras;
  std::vector<std::vector<Eigen::Vector2d>> seen;
  int n_markers() const { return static_cast<int>(markers.size()); }
  int n_cameras() const { return static_cast<int>(cameras.size()); }
};

Scene scene_of(const std::vector<calibration::Marker>& markers, const std::vector<calibration::CameraView>& views) {
  Scene s;
  s.markers = markers;
  std::map<std::string, int> index;
  for (int m = 0; m < s.n_markers(); ++m) index[markers[static_cast<std::size_t>(m)].id] = m;
  for (const auto& v : views) {
    s.cameras.push_back(v.name);
    std::vector<Eigen::Vector2d> row(markers.size(), Eigen::Vector2d::Constant(kNaN));
    for (const auto& [id, px] : v.observations) {
      const auto it = index.find(id);
      if (it != index.end() && px.allFinite()) row[static_cast<std::size_t>(it->second)] = px;
    }
    s.seen.push_back(std::move(row));
  }
  return s;
}

// A camera model hypothesis: markers left out of every fit, the DLT's terms.
struct Model {
  std::set<int> dropped;
  calibration::DltOptions dlt;
};

int parameters_per_camera(const calibration::DltOptions& dlt) {
  return 11 + (dlt.fit_distortion ? std::clamp(dlt.radial_terms, 0, 3) + (dlt.tangential ? 2 : 0) : 0);
}

std::string model_words(const calibration::DltOptions& dlt) {
  if (!dlt.fit_distortion) return "DLT without distortion";
  static const char* radial[] = {"", "k1", "k1 k2", "k1 k2 k3"};
  return fmt::format("DLT with {}{}", radial[std::clamp(dlt.radial_terms, 0, 3)], dlt.tangential ? " p1 p2" : "");
}

// Every marker not dropped, held out in turn: each camera that sees it is
// refitted on all the other (kept) markers, fit and check alike, and the
// marker is triangulated with those refits. error_m is its 3-D error (NaN
// when not judged); the all-marker fits give the RSS for the information
// criterion; k1_loo holds each camera's k1 over its leave-one-out refits
// (for a jackknife standard error).
struct CrossValidation {
  bool ok = false;
  std::string failure;
  Eigen::VectorXd error_m;
  std::vector<calibration::Camera> full;
  double rss_px2 = 0.0, n = 0.0;
  int k = 0;
  std::vector<std::vector<double>> k1_loo;
  double rms_mm(const std::set<int>& skip = {}) const {
    double sum = 0.0;
    int n_used = 0;
    for (Eigen::Index m = 0; m < error_m.size(); ++m)
      if (std::isfinite(error_m(m)) && !skip.count(static_cast<int>(m))) {
        sum += error_m(m) * error_m(m);
        ++n_used;
      }
    return n_used > 0 ? 1000.0 * std::sqrt(sum / n_used) : kNaN;
  }
  double max_mm() const {
    double mx = 0.0;
    for (Eigen::Index m = 0; m < error_m.size(); ++m)
      if (std::isfinite(error_m(m))) mx = std::max(mx, error_m(m));
    return 1000.0 * mx;
  }
  double median_m() const {
    std::vector<double> v;
    for (Eigen::Index m = 0; m < error_m.size(); ++m)
      if (std::isfinite(error_m(m))) v.push_back(error_m(m));
    if (v.empty()) return kNaN;
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  }
};

CrossValidation cross_validate(const Scene& s, const Model& model) {
  CrossValidation cv;
  const int nm = s.n_markers(), nc = s.n_cameras();
  cv.error_m = Eigen::VectorXd::Constant(nm, kNaN);
  cv.k1_loo.assign(static_cast<std::size_t>(nc), {});
  auto fit = [&](int c, int skip) {
    std::vector<calibration::Correspondence> pts;
    for (int m = 0; m < nm; ++m) {
      const auto& px = s.seen[static_cast<std::size_t>(c)][static_cast<std::size_t>(m)];
      if (m == skip || model.dropped.count(m) || !px.allFinite()) continue;
      pts.push_back({s.markers[static_cast<std::size_t>(m)].id, s.markers[static_cast<std::size_t>(m)].lab_m, px});
    }
    calibration::DltOptions o = model.dlt;
    // A fold starts from the fit on all the markers.
    if (skip >= 0 && static_cast<std::size_t>(c) < cv.full.size()) o.start = &cv.full[static_cast<std::size_t>(c)];
    return calibration::fit_dlt(s.cameras[static_cast<std::size_t>(c)], pts, o);
  };
  try {
    for (int c = 0; c < nc; ++c) {
      const calibration::DltFit f = fit(c, -1);
      cv.full.push_back(f.camera);
      cv.rss_px2 += f.fit_rms_px * f.fit_rms_px * f.n_fit_points;
      cv.n += 2.0 * f.n_fit_points;
      cv.k += parameters_per_camera(model.dlt);
    }
    std::vector<calibration::Camera> cams = cv.full;
    std::vector<Eigen::Vector2d> px(static_cast<std::size_t>(nc));
    for (int m = 0; m < nm; ++m) {
      if (model.dropped.count(m)) continue;
      int seeing = 0;
      for (int c = 0; c < nc; ++c) {
        px[static_cast<std::size_t>(c)] = s.seen[static_cast<std::size_t>(c)][static_cast<std::size_t>(m)];
        if (px[static_cast<std::size_t>(c)].allFinite()) {
          cams[static_cast<std::size_t>(c)] = fit(c, m).camera;
          if (cams[static_cast<std::size_t>(c)].has_distortion())
            cv.k1_loo[static_cast<std::size_t>(c)].push_back(cams[static_cast<std::size_t>(c)].distortion[0]);
          ++seeing;
        }
      }
      if (seeing >= 2) {
        const calibration::Triangulation tr = calibration::triangulate(cams, px, true);
        cv.error_m(m) = (tr.lab_m - s.markers[static_cast<std::size_t>(m)].lab_m).norm();
      }
      cams = cv.full;
    }
    cv.ok = true;
  } catch (const Error& e) {
    cv.failure = e.what();
  }
  return cv;
}

// Jackknife standard error of a statistic from its leave-one-out values.
double jackknife_se(const std::vector<double>& loo) {
  const auto n = static_cast<double>(loo.size());
  if (loo.size() < 2) return kNaN;
  const double mean = detail::to_vector(loo).mean();
  double ss = 0.0;
  for (double v : loo) ss += (v - mean) * (v - mean);
  return std::sqrt((n - 1.0) / n * ss);
}

std::vector<calibration::Marker> kept_markers(const Scene& s, const std::set<int>& dropped) {
  std::vector<calibration::Marker> out;
  for (int m = 0; m < s.n_markers(); ++m)
    if (!dropped.count(m)) out.push_back(s.markers[static_cast<std::size_t>(m)]);
  return out;
}

std::vector<calibration::CameraView> kept_views(const std::vector<calibration::CameraView>& views, const Scene& s,
                                                const std::set<int>& dropped) {
  std::set<std::string> ids;
  for (int m : dropped) ids.insert(s.markers[static_cast<std::size_t>(m)].id);
  std::vector<calibration::CameraView> out = views;
  for (auto& v : out)
    v.observations.erase(std::remove_if(v.observations.begin(), v.observations.end(),
                                        [&](const auto& o) { return ids.count(o.first) > 0; }),
                         v.observations.end());
  return out;
}

std::string marker_list(const Scene& s, const std::set<int>& ms) {
  std::string out;
  for (int m : ms) out += (out.empty() ? "" : " and ") + s.markers[static_cast<std::size_t>(m)].id;
  return out;
}

// Is a pair a label swap in one camera? The pair's images in that camera
// exchanged, nothing dropped: the camera whose swap brings both markers'
// cross-validated errors within `limit_m`; "" when none does.
std::string swap_camera(const Scene& s, const Model& model, int a, int b, double limit_m) {
  for (int c = 0; c < s.n_cameras(); ++c) {
    auto& row = s.seen[static_cast<std::size_t>(c)];
    if (!row[static_cast<std::size_t>(a)].allFinite() || !row[static_cast<std::size_t>(b)].allFinite()) continue;
    Scene swapped = s;
    std::swap(swapped.seen[static_cast<std::size_t>(c)][static_cast<std::size_t>(a)],
              swapped.seen[static_cast<std::size_t>(c)][static_cast<std::size_t>(b)]);
    Model m = model;
    m.dropped.erase(a);
    m.dropped.erase(b);
    const CrossValidation cv = cross_validate(swapped, m);
    if (cv.ok && cv.error_m(a) < limit_m && cv.error_m(b) < limit_m) return s.cameras[static_cast<std::size_t>(c)];
  }
  return "";
}

// A label swap screened over every pair: in each camera, the two kept
// markers whose images exchanged bring that camera's linear DLT (11
// parameters, all kept markers) closest to its images. Returns the pair when the swap
// cuts the camera's reprojection RMS below a third of what it is, else
// nothing. A slip between markers far apart spoils every leave-one-out
// fold (seed 1107: 751 px apart in one camera, 112 px RMS; the second
// marker's held-out error was below the median), so a pair cannot be
// found among the markers that stand out.
std::optional<std::pair<int, int>> screened_swap(const Scene& s, const Model& model) {
  std::optional<std::pair<int, int>> best;
  double best_ratio = 1.0 / 3.0;
  calibration::DltOptions plain;
  plain.refine = false;  // the linear DLT ranks the pairs (a Ceres refinement each: 60 ms a round)
  for (int c = 0; c < s.n_cameras(); ++c) {
    const auto& row = s.seen[static_cast<std::size_t>(c)];
    std::vector<int> kept;
    for (int m = 0; m < s.n_markers(); ++m)
      if (!model.dropped.count(m) && row[static_cast<std::size_t>(m)].allFinite()) kept.push_back(m);
    if (kept.size() < 8) continue;  // 11 parameters need more equations than a swap can test
    std::vector<calibration::Correspondence> pts;
    for (int m : kept) pts.push_back({s.markers[static_cast<std::size_t>(m)].id, s.markers[static_cast<std::size_t>(m)].lab_m,
                                      row[static_cast<std::size_t>(m)]});
    double now = 0.0;
    try {
      now = calibration::fit_dlt(s.cameras[static_cast<std::size_t>(c)], pts, plain).fit_rms_px;
    } catch (const Error&) {
      continue;
    }
    if (!(now > 0.0)) continue;
    for (std::size_t i = 0; i < kept.size(); ++i)
      for (std::size_t j = i + 1; j < kept.size(); ++j) {
        std::swap(pts[i].image_px, pts[j].image_px);
        try {
          const double r = calibration::fit_dlt(s.cameras[static_cast<std::size_t>(c)], pts, plain).fit_rms_px;
          if (r < best_ratio * now) {
            best_ratio = r / now;
            best = std::make_pair(kept[i], kept[j]);
          }
        } catch (const Error&) {
        }
        std::swap(pts[i].image_px, pts[j].image_px);
      }
  }
  return best;
}

// A hypothesis of one forward-selection round.
struct Cand {
  std::string name;
  Model model;
  std::set<int> newly_dropped;
};

// A hypothesis that passed, with its cross-validation.
struct Scored {
  const Cand* cand;
  CrossValidation cv;
  detail::Verdict verdict;
  double rms_mm;
  double log_t = kNaN;  // the paired test on log errors, when it decided
};

// The round's hypotheses. Lens distortion with as few terms as the markers
// support: k1 first (one more parameter per camera), then the tangential
// pair; each camera must keep twice as many equations as parameters.
// Outliers: the markers with the largest held-out errors, alone and in pairs
// (a label slip swaps two markers, and both then stand out).
std::vector<Cand> round_candidates(const Scene& scene, const Model& current, const CrossValidation& cv,
                                   const CalibrationStageOptions& options, bool distortion_done,
                                   bool tangential_done) {
  const double min_outlier_m = options.calibration.min_outlier_m;
  std::vector<Cand> cands;
  int min_seen = scene.n_markers();
  for (int c = 0; c < scene.n_cameras(); ++c) {
    int n = 0;
    for (int m = 0; m < scene.n_markers(); ++m)
      if (!current.dropped.count(m) && scene.seen[static_cast<std::size_t>(c)][static_cast<std::size_t>(m)].allFinite())
        ++n;
    min_seen = std::min(min_seen, n);
  }
  if (!distortion_done) {
    Model m = current;
    m.dlt.fit_distortion = true;
    m.dlt.radial_terms = 1;
    m.dlt.tangential = false;
    if (2 * (min_seen - 1) >= 2 * parameters_per_camera(m.dlt)) cands.push_back({"lens_distortion", m, {}});
  } else if (!tangential_done) {
    Model m = current;
    m.dlt.tangential = true;
    if (2 * (min_seen - 1) >= 2 * parameters_per_camera(m.dlt)) cands.push_back({"lens_distortion", m, {}});
  }
  const int room = options.max_outliers - static_cast<int>(current.dropped.size());
  if (room <= 0) return cands;
  std::vector<int> order;
  for (int m = 0; m < scene.n_markers(); ++m)
    if (std::isfinite(cv.error_m(m))) order.push_back(m);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return cv.error_m(a) > cv.error_m(b); });
  const double med = cv.median_m();
  std::vector<int> top;
  for (int m : order)
    if (static_cast<int>(top.size()) < 4 && cv.error_m(m) > std::max(min_outlier_m, 2.0 * med)) top.push_back(m);
  if (room >= 2) {
    if (const auto sw = screened_swap(scene, current)) {
      const std::set<int> pair{sw->first, sw->second};
      const bool among_top = std::count(top.begin(), top.end(), sw->first) && std::count(top.begin(), top.end(), sw->second);
      if (!among_top) {
        Model p = current;
        p.dropped.insert(pair.begin(), pair.end());
        cands.push_back({"outlier_marker", p, pair});
      }
    }
  }
  for (std::size_t i = 0; i < top.size(); ++i) {
    Model m = current;
    m.dropped.insert(top[i]);
    cands.push_back({"outlier_marker", m, {top[i]}});
    if (room < 2) continue;
    for (std::size_t j = i + 1; j < top.size(); ++j) {
      Model p = current;
      p.dropped.insert(top[i]);
      p.dropped.insert(top[j]);
      cands.push_back({"outlier_marker", p, {top[i], top[j]}});
    }
  }
  return cands;
}

// Cross-validates each hypothesis against the current model `cv`: those
// that pass (held-out test and information criterion), and the reasons for
// the others.
std::pair<std::vector<Scored>, std::vector<Rejected>> score_candidates(const Scene& scene,
                                                                       const std::vector<Cand>& cands,
                                                                       const CrossValidation& cv,
                                                                       const CalibrationStageOptions& options) {
  std::vector<Scored> passing;
  std::vector<Rejected> round_rejected;
  for (const Cand& cand : cands) {
    CrossValidation next = cross_validate(scene, cand.model);
    const std::string label = cand.name + (cand.newly_dropped.empty() ? " (" + model_words(cand.model.dlt) + ")"
                                                                      : " " + marker_list(scene, cand.newly_dropped));
    if (!next.ok) {
      round_rejected.push_back({"calibration", label, "refit failed: " + next.failure});
      continue;
    }
    std::vector<double> hb, ha;
    for (int m = 0; m < scene.n_markers(); ++m)
      if (std::isfinite(cv.error_m(m)) && std::isfinite(next.error_m(m))) {
        hb.push_back(1000.0 * cv.error_m(m));
        ha.push_back(1000.0 * next.error_m(m));
      }
    double n_large = next.n;
    int k_large = next.k;
    if (!cand.newly_dropped.empty()) {
      // Mean-shift outlier model on the same data: each dropped marker
      // keeps its images but gets two free coordinates per camera.
      n_large = cv.n;
      for (int m : cand.newly_dropped)
        for (int c = 0; c < scene.n_cameras(); ++c)
          if (scene.seen[static_cast<std::size_t>(c)][static_cast<std::size_t>(m)].allFinite()) k_large += 2;
    }
    detail::Verdict v = detail::judge(detail::to_vector(hb), detail::to_vector(ha), 0.0, cv.rss_px2, cv.k,
                                      next.rss_px2, k_large, std::max(cv.n, n_large), 0.0, options.criterion,
                                      options.decision);
    double log_t = kNaN;
    if (!v.held_out.significant && !cand.newly_dropped.empty() && v.held_out.mean_drop > 0.0 &&
        v.held_out.mean_drop >= options.decision.min_relative * v.held_out.mean_before) {
      log_t = log_paired_t(hb, ha);
      if (log_t >= options.decision.t_critical) v.held_out.significant = true;
      else log_t = kNaN;
    }
    if (!v.keep()) {
      round_rejected.push_back({"calibration", label, v.reason("cross-validated marker error (mm)", options.criterion)});
      continue;
    }
    const double r = next.rms_mm();
    passing.push_back({&cand, std::move(next), v, r, log_t});
  }
  return {std::move(passing), std::move(round_rejected)};
}

// Estimates and evidence of a kept lens-distortion hypothesis.
void describe_distortion(const Scene& scene, const Scored& best, const CrossValidation& cv,
                         const CalibrationStageOptions& options, Effect& e) {
  const Cand& cand = *best.cand;
  const CrossValidation& next = best.cv;
  std::string ks;
  for (int c = 0; c < scene.n_cameras(); ++c) {
    const calibration::Camera& cam = next.full[static_cast<std::size_t>(c)];
    if (!cam.has_distortion()) continue;
    const double se = jackknife_se(next.k1_loo[static_cast<std::size_t>(c)]);
    e.estimate.push_back({cam.name + "_k1", cam.distortion[0]});
    e.estimate.push_back({cam.name + "_k1_se", se});
    if (cand.model.dlt.tangential) {
      e.estimate.push_back({cam.name + "_p1", cam.distortion[2]});
      e.estimate.push_back({cam.name + "_p2", cam.distortion[3]});
    }
    ks += fmt::format("{}{} k1 = {:.3f} +- {:.3f}", ks.empty() ? "" : ", ", cam.name, cam.distortion[0], se);
  }
  e.evidence = fmt::format(
      "leave-one-out 3-D error over all {} markers falls from {:.2f} to {:.2f} mm RMS with the {} "
      "(t = {:.1f}, {} {:+.1f}); {}",
      static_cast<int>(best.verdict.held_out.mean_before > 0 ? (next.error_m.array().isFinite()).count() : 0),
      cv.rms_mm(), next.rms_mm(), model_words(cand.model.dlt), best.verdict.held_out.t,
      criterion_name(options.criterion), best.verdict.ic.delta, ks);
}

// Estimates and evidence of a kept outlier hypothesis (one marker or a
// pair, and whether the pair is a label swap); the dropped markers' ids go
// to `dropped_markers`.
void describe_outliers(const Scene& scene, const Model& current, const Scored& best, const CrossValidation& cv,
                       double fit_after_px, const CalibrationStageOptions& options, Effect& e,
                       std::vector<std::string>& dropped_markers) {
  const Cand& cand = *best.cand;
  const CrossValidation& next = best.cv;
  const double min_outlier_m = options.calibration.min_outlier_m, ratio = options.calibration.outlier_ratio;
  const double med = next.median_m();
  std::string swap;
  if (cand.newly_dropped.size() == 2) {
    const int a = *cand.newly_dropped.begin(), b = *cand.newly_dropped.rbegin();
    swap = swap_camera(scene, current, a, b, std::max(min_outlier_m, ratio * med));
  }
  std::string per;
  for (int m : cand.newly_dropped) {
    const std::string& id = scene.markers[static_cast<std::size_t>(m)].id;
    e.estimate.push_back({id + "_loo_error_mm", 1000.0 * cv.error_m(m)});
    per += fmt::format("{}{} {:.1f} mm", per.empty() ? "" : ", ", id, 1000.0 * cv.error_m(m));
    dropped_markers.push_back(id);
  }
  e.estimate.push_back({"others_median_mm", 1000.0 * med});
  e.estimate.push_back({"noise_px", fit_after_px});
  e.evidence = fmt::format(
      "{} stand{} out in leave-one-out on all markers ({}); with {} left out of every fit the others' "
      "held-out error falls from {:.1f} to {:.2f} mm RMS (t = {:.1f}{}, {} {:+.1f}){}",
      marker_list(scene, cand.newly_dropped), cand.newly_dropped.size() == 1 ? "s" : "", per,
      cand.newly_dropped.size() == 1 ? "it" : "both", cv.rms_mm(cand.newly_dropped), next.rms_mm(),
      std::isfinite(best.log_t) ? best.log_t : best.verdict.held_out.t,
      std::isfinite(best.log_t) ? " on the log errors" : "", criterion_name(options.criterion), best.verdict.ic.delta,
      swap.empty() ? "" : fmt::format("; exchanging their images in {} fits as well: a label swap", swap));
}

// What remains after the chosen model: a marker that still stands out, or
// radial structure in the reprojection residual.
void remaining_calibration(const Scene& scene, const std::vector<calibration::CameraView>& views,
                           const Model& current, const CrossValidation& cv, const CalibrationStageOptions& options,
                           CalibrationDiagnosis& out) {
  const double min_outlier_m = options.calibration.min_outlier_m, ratio = options.calibration.outlier_ratio;
  const double med = cv.median_m();
  for (int m = 0; m < scene.n_markers(); ++m)
    if (std::isfinite(cv.error_m(m)) && cv.error_m(m) > std::max(min_outlier_m, ratio * med))
      out.remaining.push_back({"calibration", "outlier_marker",
                               fmt::format("marker {} still stands out ({:.1f} mm leave-one-out against a median "
                                           "of {:.2f} mm) and no hypothesis explains it",
                                           scene.markers[static_cast<std::size_t>(m)].id, 1000.0 * cv.error_m(m),
                                           1000.0 * med)});
  const std::vector<calibration::Marker> km = kept_markers(scene, current.dropped);
  const std::vector<calibration::CameraView> kv = kept_views(views, scene, current.dropped);
  const Reprojection rep = reprojection(out.after, km, kv);
  const StructureReport radial = radial_structure(rep, options.decision);
  const TermScore* cube = radial.find("r^3");
  const double mean_px = rep.distance_px.empty() ? 0.0 : detail::to_vector(rep.distance_px).mean();
  // A radial pattern is worth naming only when it is strong and its size
  // clearly exceeds sub-pixel digitising noise.
  if (cube && cube->share_alone >= 0.5 && mean_px > 1.0)
    out.remaining.push_back(
        {"calibration", "radial_residual",
         fmt::format("reprojection residual still grows with the image radius (r = {:.2f}, mean {:.2f} px)", cube->r,
                     mean_px)});
}

}  // namespace

CalibrationDiagnosis diagnose_calibration(const std::vector<calibration::Marker>& markers,
                                          const std::vector<calibration::CameraView>& views,
                                          const CalibrationStageOptions& options) {
  CalibrationDiagnosis out;
  const calibration::CalibrationOptions base = options.calibration;
  out.before = calibration::calibrate(markers, views, base);
  const Scene scene = scene_of(markers, views);

  Model current{{}, base.dlt};
  CrossValidation cv = cross_validate(scene, current);
  if (!cv.ok) {
    out.notes.push_back("calibration: leave-one-out cross-validation failed (" + cv.failure +
                        "); effects cannot be judged");
    out.after = out.before;
    out.options_after = base;
    return out;
  }

  // Forward selection: each round scores every candidate by cross-validation
  // and keeps the passing one with the lowest held-out RMS.
  bool distortion_done = current.dlt.fit_distortion, tangential_done = current.dlt.tangential && distortion_done;
  for (int round = 0; round < 4; ++round) {
    const std::vector<Cand> cands = round_candidates(scene, current, cv, options, distortion_done, tangential_done);
    if (cands.empty()) break;
    auto [passing, round_rejected] = score_candidates(scene, cands, cv, options);
    if (passing.empty()) {
      out.rejected.insert(out.rejected.end(), round_rejected.begin(), round_rejected.end());
      break;
    }
    const auto best = std::min_element(passing.begin(), passing.end(),
                                       [](const Scored& a, const Scored& b) { return a.rms_mm < b.rms_mm; });
    const Cand& cand = *best->cand;
    const CrossValidation& next = best->cv;

    Effect e;
    e.stage = "calibration";
    e.name = cand.name;
    const double fit_before = std::sqrt(cv.rss_px2 / std::max(cv.n / 2.0, 1.0));
    const double fit_after = std::sqrt(next.rss_px2 / std::max(next.n / 2.0, 1.0));
    e.error_before = {{"cv_rms_mm", cv.rms_mm(cand.newly_dropped)}, {"cv_max_mm", cv.max_mm()},
                      {"fit_rms_px", fit_before}};
    e.error_after = {{"cv_rms_mm", next.rms_mm()}, {"cv_max_mm", next.max_mm()}, {"fit_rms_px", fit_after}};
    if (cand.name == "lens_distortion") {
      describe_distortion(scene, *best, cv, options, e);
      if (cand.model.dlt.tangential) tangential_done = true;
      distortion_done = true;
    } else {
      describe_outliers(scene, current, *best, cv, fit_after, options, e, out.dropped_markers);
    }
    out.effects.push_back(std::move(e));
    current = cand.model;
    cv = next;
  }

  // The calibration every later stage uses: the fit markers (the protocol)
  // less those dropped, with the chosen camera model.
  calibration::CalibrationOptions opt = base;
  opt.dlt = current.dlt;
  try {
    out.after = calibration::calibrate(kept_markers(scene, current.dropped), kept_views(views, scene, current.dropped),
                                       opt);
    out.options_after = opt;
  } catch (const Error& e) {
    out.notes.push_back(std::string("calibration: the chosen model could not be refitted on the fit markers (") +
                        e.what() + "); the baseline is kept");
    out.after = out.before;
    out.options_after = base;
  }
  const ErrorSet check_before = check_errors(out.before), check_after = check_errors(out.after);
  for (auto& e : out.effects) {
    e.error_before.insert(e.error_before.begin(), check_before.begin(), check_before.end());
    e.error_after.insert(e.error_after.begin(), check_after.begin(), check_after.end());
  }
  remaining_calibration(scene, views, current, cv, options, out);
  return out;
}

}  // namespace dropfit::diagnosis
