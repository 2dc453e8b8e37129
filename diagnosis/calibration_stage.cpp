// The calibration stage of the loop: lens distortion and outlier markers,
// judged on the check markers (see diagnosis.h).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <map>

#include "core/error.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

// Principal point and focal length (pixels) of a DLT (the decomposition
// calibration.h describes), for the radius of a distortion-free camera.
void decompose(const calibration::Dlt11& L, Eigen::Vector2d* centre_px, double* focal_px) {
  const double d = L(8) * L(8) + L(9) * L(9) + L(10) * L(10);
  const double u0 = (L(0) * L(8) + L(1) * L(9) + L(2) * L(10)) / d;
  const double v0 = (L(4) * L(8) + L(5) * L(9) + L(6) * L(10)) / d;
  const double fu2 = (L(0) * L(0) + L(1) * L(1) + L(2) * L(2)) / d - u0 * u0;
  const double fv2 = (L(4) * L(4) + L(5) * L(5) + L(6) * L(6)) / d - v0 * v0;
  *centre_px = {u0, v0};
  *focal_px = 0.5 * (std::sqrt(std::max(fu2, 1e-12)) + std::sqrt(std::max(fv2, 1e-12)));
}

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
    double focal;
    if (cam.has_distortion()) {
      centre = cam.principal_point_px;
      focal = cam.focal_px;
    } else {
      decompose(cam.dlt, &centre, &focal);
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

// Per check marker 3-D error (mm), paired by id; markers missing on either
// side are left out.
void paired_check(const calibration::CalibrationResult& before, const calibration::CalibrationResult& after,
                  Eigen::VectorXd* b, Eigen::VectorXd* a) {
  std::vector<double> vb, va;
  for (const auto& p : before.check_points)
    for (const auto& q : after.check_points)
      if (p.id == q.id) {
        vb.push_back(1000.0 * p.error_m.norm());
        va.push_back(1000.0 * q.error_m.norm());
      }
  *b = detail::to_vector(vb);
  *a = detail::to_vector(va);
}

// Fit RSS (pixels^2), equations and parameters over all cameras.
struct FitSize {
  double rss = 0.0;
  double n = 0.0;
  int k = 0;
};
FitSize fit_size(const calibration::CalibrationResult& r, const calibration::DltOptions& dlt) {
  FitSize s;
  const int per_camera = 11 + (dlt.fit_distortion ? std::clamp(dlt.radial_terms, 0, 3) + (dlt.tangential ? 2 : 0) : 0);
  for (const auto& c : r.cameras) {
    s.rss += c.fit_rms_px * c.fit_rms_px * c.n_fit_points;
    s.n += 2.0 * c.n_fit_points;
    s.k += per_camera;
  }
  return s;
}

std::vector<calibration::CameraView> without_marker(const std::vector<calibration::CameraView>& views,
                                                    const std::string& id) {
  std::vector<calibration::CameraView> out = views;
  for (auto& v : out)
    v.observations.erase(std::remove_if(v.observations.begin(), v.observations.end(),
                                        [&](const auto& o) { return o.first == id; }),
                         v.observations.end());
  return out;
}

int cameras_seeing(const std::vector<calibration::CameraView>& views, const std::string& id) {
  int n = 0;
  for (const auto& v : views)
    for (const auto& o : v.observations)
      if (o.first == id && o.second.allFinite()) ++n;
  return n;
}

double loo_residual(const calibration::CalibrationResult& r, const std::string& id) {
  for (std::size_t i = 0; i < r.outliers.size(); ++i)
    if (r.outliers[i] == id && i < r.outlier_error_m.size()) return r.outlier_error_m[i];
  for (const auto& l : r.leave_one_out)
    if (l.id == id) return l.residual_m;
  return kNaN;
}

}  // namespace

CalibrationDiagnosis diagnose_calibration(const std::vector<calibration::Marker>& markers_in,
                                          const std::vector<calibration::CameraView>& views_in,
                                          const CalibrationStageOptions& options) {
  CalibrationDiagnosis out;
  const DecisionOptions& d = options.decision;
  std::vector<calibration::Marker> markers = markers_in;
  std::vector<calibration::CameraView> views = views_in;
  calibration::CalibrationOptions opt = options.calibration;
  calibration::CalibrationResult current = calibration::calibrate(markers, views, opt);
  out.before = current;
  if (current.check_points.size() < 3) {
    out.notes.push_back(fmt::format("calibration: only {} check markers reconstructed; effects cannot be judged",
                                    current.check_points.size()));
    out.after = current;
    out.options_after = opt;
    return out;
  }

  bool distortion_tried = opt.dlt.fit_distortion;
  std::vector<std::string> outliers_tried;
  for (int round = 0; round < 2 + options.max_outliers; ++round) {
    // 1. Structure of the current residual.
    const Reprojection rep = reprojection(current, markers, views);
    const StructureReport radial = radial_structure(rep, d);
    const TermScore* cube = radial.find("r^3");

    // 2. Rank the candidates: the outlier's share of the leave-one-out
    // residual variance, the radius' share of the radial residual's.
    struct Option {
      std::string name, marker;
      double share;
    };
    std::vector<Option> ranked;
    if (!distortion_tried && cube) ranked.push_back({"lens_distortion", "", cube->share_alone});
    if (static_cast<int>(out.dropped_markers.size()) < options.max_outliers) {
      double sum_sq = 0.0;
      for (const auto& l : current.leave_one_out)
        if (std::isfinite(l.residual_m)) sum_sq += l.residual_m * l.residual_m;
      for (std::size_t i = 0; i < current.outliers.size(); ++i) {
        const std::string& id = current.outliers[i];
        if (std::find(outliers_tried.begin(), outliers_tried.end(), id) != outliers_tried.end()) continue;
        const double e = loo_residual(current, id);
        ranked.push_back({"outlier_marker", id, sum_sq > 0.0 ? std::min(1.0, e * e / (sum_sq + e * e)) : 1.0});
      }
    }
    std::stable_sort(ranked.begin(), ranked.end(), [](const Option& a, const Option& b) { return a.share > b.share; });
    if (ranked.empty()) break;

    // 3. Try them in order; keep the first that passes both tests.
    bool kept = false;
    for (const Option& cand : ranked) {
      std::vector<calibration::Marker> m2 = markers;
      std::vector<calibration::CameraView> v2 = views;
      calibration::CalibrationOptions o2 = opt;
      if (cand.name == "lens_distortion") {
        distortion_tried = true;
        o2.dlt.fit_distortion = true;
      } else {
        outliers_tried.push_back(cand.marker);
        m2.erase(std::remove_if(m2.begin(), m2.end(), [&](const auto& m) { return m.id == cand.marker; }), m2.end());
        v2 = without_marker(views, cand.marker);
      }
      calibration::CalibrationResult next;
      try {
        next = calibration::calibrate(m2, v2, o2);
      } catch (const Error& e) {
        out.rejected.push_back({"calibration", cand.name, std::string("refit failed: ") + e.what()});
        continue;
      }
      Eigen::VectorXd hb, ha;
      paired_check(current, next, &hb, &ha);
      const FitSize small = fit_size(current, opt.dlt);
      FitSize large = fit_size(next, o2.dlt);
      if (cand.name == "outlier_marker") {
        // Mean-shift outlier model on the same data: the marker keeps its
        // images but gets two free coordinates per camera that sees it.
        large.n = small.n;
        large.k = small.k + 2 * cameras_seeing(views, cand.marker);
      }
      const detail::Verdict v = detail::judge(hb, ha, 0.0, small.rss, small.k, large.rss, large.k, small.n, 0.0,
                                              options.criterion, d);
      if (!v.keep()) {
        out.rejected.push_back({"calibration", cand.name + (cand.marker.empty() ? "" : " " + cand.marker),
                                v.reason("check-marker error (mm)", options.criterion)});
        continue;
      }
      Effect e;
      e.stage = "calibration";
      e.name = cand.name;
      e.error_before = check_errors(current);
      e.error_after = check_errors(next);
      e.error_before.push_back({"fit_rms_px", std::sqrt(small.rss / std::max(small.n / 2.0, 1.0))});
      e.error_after.push_back({"fit_rms_px", std::sqrt(fit_size(next, o2.dlt).rss / std::max(fit_size(next, o2.dlt).n / 2.0, 1.0))});
      if (cand.name == "lens_distortion") {
        e.evidence = fmt::format(
            "radial reprojection residual grows with the image radius cubed (r = {:.2f} over {} marker images); "
            "refitted with Bouguet distortion (dlt16), {} {:.1f}",
            cube ? cube->r : 0.0, rep.radial_px.size(), criterion_name(options.criterion), v.ic.delta);
        for (const auto& c : next.cameras)
          if (c.camera.has_distortion()) e.estimate.push_back({c.camera.name + "_k1", c.camera.distortion[0]});
      } else {
        const double loo = loo_residual(current, cand.marker);
        e.evidence = fmt::format(
            "marker {}'s leave-one-out residual is {:.1f} mm, {:.0f} x the median of the others ({:.2f} mm); "
            "dropped from the fit, {} {:.1f}",
            cand.marker, 1000.0 * loo, loo / std::max(current.outlier_baseline_m, 1e-12),
            1000.0 * current.outlier_baseline_m, criterion_name(options.criterion), v.ic.delta);
        e.estimate.push_back({"loo_residual_mm", 1000.0 * loo});
        out.dropped_markers.push_back(cand.marker);
      }
      out.effects.push_back(std::move(e));
      markers = std::move(m2);
      views = std::move(v2);
      opt = o2;
      current = std::move(next);
      kept = true;
      break;
    }
    if (!kept) break;
  }

  // 4. What remains: an outlier still named, or radial structure left.
  for (const auto& id : current.outliers)
    if (std::find(out.dropped_markers.begin(), out.dropped_markers.end(), id) == out.dropped_markers.end())
      out.remaining.push_back({"calibration", "outlier_marker",
                               fmt::format("marker {} still stands out ({:.1f} mm leave-one-out) but dropping it "
                                           "did not improve the check markers",
                                           id, 1000.0 * loo_residual(current, id))});
  {
    const Reprojection rep = reprojection(current, markers, views);
    const StructureReport radial = radial_structure(rep, d);
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
  out.after = std::move(current);
  out.options_after = opt;
  return out;
}

}  // namespace dropfit::diagnosis
