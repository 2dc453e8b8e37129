// The diagnosis result, its JSON, and the whole-session wiring of the stages
// (see diagnosis.h). The stages themselves live in *_stage.cpp.
#include "diagnosis/diagnosis.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

nlohmann::ordered_json number(double v) {
  if (!std::isfinite(v)) return nullptr;
  return v;
}

nlohmann::ordered_json error_set(const ErrorSet& e) {
  nlohmann::ordered_json j = nlohmann::ordered_json::object();
  for (const auto& [k, v] : e) j[k] = number(v);
  return j;
}

// The face height (contact face, lab z) per video frame: mean of the base
// markers minus their height above the face; NaN unless all are present.
Eigen::VectorXd face_heights(const reconstruction::Trajectories& traj, const std::vector<int>& base,
                             double base_height_m) {
  Eigen::VectorXd z = Eigen::VectorXd::Constant(traj.n_frames(), kNaN);
  if (base.empty()) return z;
  for (int f = 0; f < traj.n_frames(); ++f) {
    double sum = 0.0;
    bool ok = true;
    for (int p : base) {
      if (p < 0 || 3 * p + 2 >= traj.lab_m.cols()) {
        ok = false;
        break;
      }
      const double v = traj.lab_m(f, 3 * p + 2);
      if (!std::isfinite(v)) {
        ok = false;
        break;
      }
      sum += v;
    }
    if (ok) z(f) = sum / static_cast<double>(base.size()) - base_height_m;
  }
  return z;
}

// Linear interpolation of a per-frame series at a fractional frame; NaN when
// either neighbour is missing or out of range.
double at_frame(const Eigen::VectorXd& y, double frame) {
  if (!(frame >= 0.0) || frame > static_cast<double>(y.size() - 1)) return kNaN;
  const auto k = static_cast<Eigen::Index>(std::floor(frame));
  if (k >= y.size() - 1) return y(y.size() - 1);
  const double f = frame - static_cast<double>(k);
  if (f == 0.0) return y(k);
  return (1.0 - f) * y(k) + f * y(k + 1);
}

int index_of(const std::vector<std::string>& names, const std::string& name) {
  const auto it = std::find(names.begin(), names.end(), name);
  return it == names.end() ? -1 : static_cast<int>(it - names.begin());
}

}  // namespace

const Effect* DiagnosisResult::find(const std::string& name) const {
  for (const auto& e : effects)
    if (e.name == name) return &e;
  return nullptr;
}

std::string DiagnosisResult::report() const {
  std::string s = fmt::format("diagnosis (baseline {}): {} effect(s) added{}\n", baseline_model, effects.size(),
                              unexplained ? "; structured residual remains unexplained" : "");
  auto errors = [](const ErrorSet& e) {
    std::string out;
    for (const auto& [k, v] : e) out += fmt::format("{}{} {:.3g}", out.empty() ? "" : ", ", k, v);
    return out;
  };
  for (const auto& e : effects) {
    s += fmt::format("  + {} / {}: {}\n", e.stage, e.name, e.evidence);
    s += fmt::format("      before: {}\n      after:  {}\n", errors(e.error_before), errors(e.error_after));
  }
  for (const auto& r : remaining) s += fmt::format("  ? {} / {}: {}\n", r.stage, r.name, r.description);
  for (const auto& r : rejected) s += fmt::format("  - {} / {}: {}\n", r.stage, r.name, r.reason);
  for (const auto& n : notes) s += fmt::format("  note: {}\n", n);
  return s;
}

std::string diagnosis_json(const DiagnosisResult& result) {
  nlohmann::ordered_json j;
  j["baseline_model"] = result.baseline_model;
  j["effects"] = nlohmann::ordered_json::array();
  for (const auto& e : result.effects) {
    nlohmann::ordered_json o;
    o["stage"] = e.stage;
    o["name"] = e.name;
    o["evidence"] = e.evidence;
    o["error_before"] = error_set(e.error_before);
    o["error_after"] = error_set(e.error_after);
    o["estimate"] = error_set(e.estimate);
    j["effects"].push_back(o);
  }
  j["unexplained"] = result.unexplained;
  j["remaining"] = nlohmann::ordered_json::array();
  for (const auto& r : result.remaining)
    j["remaining"].push_back({{"stage", r.stage},
                              {"name", r.name},
                              {"description", r.description},
                              {"frequency_hz", std::isfinite(r.frequency_hz) ? nlohmann::ordered_json(r.frequency_hz)
                                                                             : nlohmann::ordered_json(nullptr)}});
  j["rejected"] = nlohmann::ordered_json::array();
  for (const auto& r : result.rejected)
    j["rejected"].push_back({{"stage", r.stage}, {"name", r.name}, {"reason", r.reason}});
  j["notes"] = result.notes;
  return j.dump(2) + "\n";
}

DiagnosisResult diagnose(const Session& session, const DiagnosisOptions& options) {
  const Manifest& man = session.manifest;
  DiagnosisResult result;
  result.baseline_model = fitting::model_name(options.mat_stage.fit.model);

  // ---- calibration ----
  std::vector<calibration::Marker> markers;
  for (const auto& m : session.frame) markers.push_back({m.id, m.lab_m, m.role == MarkerRole::Check});
  std::vector<calibration::CameraView> views;
  for (const auto& image : session.images) {
    calibration::CameraView view{image.camera, {}};
    for (const auto& o : image.observations) view.observations.emplace_back(o.id, o.image_px);
    views.push_back(std::move(view));
  }
  calibration::CalibrationResult cal;
  if (options.calibration) {
    const CalibrationDiagnosis cd = diagnose_calibration(markers, views, options.calibration_stage);
    append(result, cd);
    cal = cd.after;
  } else {
    cal = calibration::calibrate(markers, views, options.calibration_stage.calibration);
  }
  std::vector<calibration::Camera> cameras;
  for (const auto& c : cal.cameras) cameras.push_back(c.camera);

  // ---- every trial: reconstruction, force, trial analysis ----
  trial::TrialOptions base_to;
  base_to.impactor_mass_kg = man.impactor.mass_kg;
  base_to.gravity_m_s2 = man.gravity_m_s2;
  base_to.frame_rate_hz = man.video.frame_rate_hz;
  base_to.trigger_frame = man.video.trigger_frame;
  for (const auto& name : man.impactor.base_markers) base_to.base_markers.push_back(index_of(man.video.points, name));
  for (const auto& name : man.mat.surface_markers) base_to.surface_markers.push_back(index_of(man.video.points, name));
  base_to.point_names = man.video.points;
  base_to.base_marker_height_m = man.impactor.base_marker_height_m;
  base_to.mat_top_z_m = man.forceplate.mat_top_z_m;
  if (options.max_tilt_deg > 0.0) base_to.max_tilt_deg = options.max_tilt_deg;

  struct Bundle {
    trial::TrialResult result;
    forceplate::ForceTrial force;
    reconstruction::Trajectories traj;
    bool force_ok = false;
  };
  std::vector<Bundle> bundles;
  forceplate::ProcessOptions po_base;
  po_base.trigger_threshold_n = man.forceplate.trigger_threshold_n;
  po_base.pretrigger_fraction = man.forceplate.pretrigger_fraction;
  po_base.sample_rate_hz = man.forceplate.sample_rate_hz;
  for (const auto& tr : session.trials) {
    Bundle b;
    b.traj = reconstruction::reconstruct(cameras, tr.tracks.uv_px, tr.tracks.n_points());
    trial::TrialOptions to = base_to;
    to.id = tr.spec.id;
    forceplate::ProcessOptions po = po_base;
    if (tr.force.pretrigger_samples > 0) po.pretrigger_samples = tr.force.pretrigger_samples;
    try {
      const forceplate::Resultants raw =
          tr.force.layout == ForceLayout::EightChannel
              ? forceplate::from_eight_channels(tr.force.t_s, tr.force.data,
                                                {man.forceplate.a_m, man.forceplate.b_m, man.forceplate.az0_m})
              : forceplate::from_resultant_columns(tr.force.t_s, tr.force.data, 50.0, man.forceplate.az0_m);
      b.force = forceplate::process(raw, po);
      b.force_ok = true;
      b.result = trial::analyse(b.force, b.traj, to);
    } catch (const Error& e) {
      b.result.id = tr.spec.id;
      b.result.accepted = false;
      b.result.reject_reason = e.what();
    }
    if (!b.result.accepted)
      result.notes.push_back(fmt::format("trial {} left out: {}", tr.spec.id, b.result.reject_reason));
    bundles.push_back(std::move(b));
  }

  // ---- sync ----
  double offset_s = 0.0;
  if (options.sync) {
    std::vector<trial::TrialResult> results;
    for (const auto& b : bundles) results.push_back(b.result);
    const SyncDiagnosis sd = diagnose_sync(results, options.sync_stage);
    append(result, sd);
    offset_s = sd.offset_s;
  }

  // ---- force plate ----
  const double fps = man.video.frame_rate_hz;
  const double mat_top = man.forceplate.mat_top_z_m;
  PlateCorrection correction;
  std::vector<PlateTrial> plates;
  std::vector<const Bundle*> used;
  for (const auto& b : bundles) {
    if (!b.force_ok || !b.result.accepted) continue;
    PlateTrial p;
    p.id = b.result.id;
    p.t_s = b.force.plate.t_s;
    p.fz_n = b.force.plate.f_n.col(2);
    p.noise_n = b.force.noise_n;
    p.contact_time_s = b.force.contact_time_s;
    p.end_time_s = b.force.end_time_s;
    p.quiet_end_s = std::min(b.force.trigger_time_s, b.force.contact_time_s) - po_base.quiet_guard_s;
    p.impact_velocity_m_s = b.result.impact_velocity_m_s;
    const Eigen::VectorXd z = face_heights(b.traj, base_to.base_markers, base_to.base_marker_height_m);
    p.face_z_m = z;
    p.video_t_s.resize(z.size());
    for (Eigen::Index f = 0; f < z.size(); ++f)
      p.video_t_s(f) = (static_cast<double>(f) - man.video.trigger_frame) / fps - offset_s;
    plates.push_back(std::move(p));
    used.push_back(&b);
  }
  ForceplateStageOptions fo = options.forceplate_stage;
  fo.impactor_mass_kg = man.impactor.mass_kg;
  fo.gravity_m_s2 = man.gravity_m_s2;
  if (options.forceplate && !plates.empty()) {
    const ForceplateDiagnosis fd = diagnose_forceplate(plates, fo);
    append(result, fd);
    correction = fd.correction;
  }

  // ---- mat ----
  if (options.mat) {
    std::vector<fitting::TrialData> data;
    for (std::size_t i = 0; i < used.size(); ++i) {
      const Bundle& b = *used[i];
      const PlateTrial& p = plates[i];
      // The contact instant on the force clock from the video's free-fall fit
      // and the session's clock relation (sub-sample, and free of the plate
      // onset's threshold delay); the plate's onset when the video has none.
      const double tc = std::isfinite(b.result.video_contact_time_s) ? b.result.video_contact_time_s - offset_s
                                                                      : b.result.contact_time_s;
      const Eigen::VectorXd f = correction.apply(p.t_s, p.fz_n, p.contact_time_s);
      std::vector<Eigen::Index> keep;
      for (Eigen::Index k = 0; k < p.t_s.size(); ++k)
        if (p.t_s(k) >= tc - 0.005 && p.t_s(k) <= tc + 0.5) keep.push_back(k);
      if (keep.size() < 3) continue;
      fitting::TrialData td;
      td.id = b.result.id;
      td.accepted = true;
      td.impact_velocity_m_s = b.result.impact_velocity_m_s;
      td.impactor_mass_kg = man.impactor.mass_kg;
      td.gravity_m_s2 = man.gravity_m_s2;
      td.force_noise_n = p.noise_n / correction.gain;
      td.marker_noise_m = b.result.freefall_rms_m;
      const auto n = static_cast<Eigen::Index>(keep.size());
      td.t_s.resize(n);
      td.grf_n.resize(n);
      td.impactor_m.resize(n);
      td.surface_m.resize(n);
      Eigen::VectorXd surface = Eigen::VectorXd::Constant(b.traj.n_frames(), kNaN);
      if (!base_to.surface_markers.empty()) surface = face_heights(b.traj, base_to.surface_markers, 0.0);
      for (Eigen::Index j = 0; j < n; ++j) {
        const Eigen::Index k = keep[static_cast<std::size_t>(j)];
        td.t_s(j) = p.t_s(k) - tc;
        td.grf_n(j) = f(k);
        const double frame = (p.t_s(k) + offset_s) * fps + man.video.trigger_frame;
        td.impactor_m(j) = mat_top - at_frame(p.face_z_m, frame);
        td.surface_m(j) = mat_top - at_frame(surface, frame);
      }
      data.push_back(std::move(td));
    }
    MatStageOptions mo = options.mat_stage;
    if (!(mo.plate_noise_n > 0.0) && !plates.empty()) {
      double sum_sq = 0.0;
      for (const auto& p : plates) sum_sq += p.noise_n * p.noise_n;
      mo.plate_noise_n = std::sqrt(sum_sq / static_cast<double>(plates.size())) / correction.gain;
    }
    const auto& layers = man.mat.layers;
    if (layers.size() >= 2) {
      mo.fit.m2_kg = layers.back().mass_kg;
      mo.fit.m1_kg = 0.0;
      for (std::size_t i = 0; i + 1 < layers.size(); ++i) mo.fit.m1_kg += layers[i].mass_kg;
    }
    const MatDiagnosis md = diagnose_mat(data, mo);
    append(result, md);
  }
  return result;
}

}  // namespace dropfit::diagnosis
