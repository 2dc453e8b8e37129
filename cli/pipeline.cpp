#include "cli/pipeline.h"

#include "report/results.h"

#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <optional>
#include <thread>
#include <cmath>

#include "capture/io.h"
#include "core/error.h"
#include "diagnosis/diagnosis.h"

namespace dropfit::pipeline {

std::vector<calibration::Marker> calibration_markers(const std::vector<CalibrationMarker>& frame) {
  std::vector<calibration::Marker> markers;
  markers.reserve(frame.size());
  for (const auto& m : frame) markers.push_back({m.id, m.lab_m, m.role == MarkerRole::Check});
  return markers;
}

std::vector<calibration::CameraView> camera_views(const std::vector<CalibrationImage>& images) {
  std::vector<calibration::CameraView> views;
  views.reserve(images.size());
  for (const auto& image : images) {
    calibration::CameraView view{image.camera, {}};
    for (const auto& o : image.observations) view.observations.emplace_back(o.id, o.image_px);
    views.push_back(std::move(view));
  }
  return views;
}

calibration::CalibrationResult calibrate_session(const Session& session,
                                                 const calibration::CalibrationOptions& options) {
  // Coefficients given in the manifest ([calibration] dlt_coefficients):
  // used as they are, checked on the frame's check markers when there is one.
  if (!session.dlt_coefficients.empty()) {
    std::vector<calibration::Camera> cameras;
    for (std::size_t c = 0; c < session.dlt_coefficients.size(); ++c) {
      calibration::Camera& camera = cameras.emplace_back();
      camera.name = session.manifest.video.cameras[c];
      camera.dlt = session.dlt_coefficients[c];
    }
    return calibration::given_calibration(cameras, calibration_markers(session.frame), camera_views(session.images));
  }
  return calibration::calibrate(calibration_markers(session.frame), camera_views(session.images), options);
}

std::vector<calibration::Camera> cameras_of(const calibration::CalibrationResult& result) {
  std::vector<calibration::Camera> cameras;
  for (const auto& fit : result.cameras) cameras.push_back(fit.camera);
  return cameras;
}

void add_calibration_outputs(report::OutputSet& out, const calibration::CalibrationResult& result) {
  out.add("calibration.json", report::calibration_json(result));
  out.add("dlt_coefficients.csv", report::dlt_coefficients_csv(cameras_of(result)));
}

void add_reconstruction_outputs(report::OutputSet& out, const std::string& trial_id,
                                const reconstruction::Trajectories& trajectories) {
  out.add("trials/" + trial_id + "/xyzpts.csv", report::xyzpts_csv(trajectories));
  out.add("trials/" + trial_id + "/residuals.csv", report::residuals_csv(trajectories));
}

trial::TrialOptions trial_options(const Manifest& manifest, const std::string& trial_id) {
  auto index_of = [&](const std::string& name) {
    const auto& points = manifest.video.points;
    return static_cast<int>(std::find(points.begin(), points.end(), name) - points.begin());
  };
  trial::TrialOptions options;
  options.id = trial_id;
  options.impactor_mass_kg = manifest.impactor.mass_kg;
  options.gravity_m_s2 = manifest.gravity_m_s2;
  options.frame_rate_hz = manifest.video.frame_rate_hz;
  options.trigger_frame = manifest.video.trigger_frame;
  for (const auto& name : manifest.impactor.base_markers) options.base_markers.push_back(index_of(name));
  for (const auto& name : manifest.mat.surface_markers) options.surface_markers.push_back(index_of(name));
  options.point_names = manifest.video.points;
  options.base_marker_height_m = manifest.impactor.base_marker_height_m;
  options.mat_top_z_m = manifest.forceplate.mat_top_z_m;
  return options;
}

forceplate::ProcessOptions force_options(const Manifest& manifest, const ForceRecord& record) {
  forceplate::ProcessOptions options;
  options.trigger_threshold_n = manifest.forceplate.trigger_threshold_n;
  options.pretrigger_fraction = manifest.forceplate.pretrigger_fraction;
  options.pretrigger_samples = record.pretrigger_samples > 0 ? record.pretrigger_samples : -1;
  options.sample_rate_hz = manifest.forceplate.sample_rate_hz;
  return options;
}

forceplate::Resultants raw_resultants(const Manifest& manifest, const ForceRecord& record) {
  // A C3D's FORCE_PLATFORM:ORIGIN replaces the manifest's geometry.
  const Eigen::Vector3d g = record.plate_geometry_m.value_or(
      Eigen::Vector3d(manifest.forceplate.a_m, manifest.forceplate.b_m, manifest.forceplate.az0_m));
  if (record.layout == ForceLayout::EightChannel) {
    return forceplate::from_eight_channels(record.t_s, record.data, {g[0], g[1], g[2]});
  }
  return forceplate::from_resultant_columns(record.t_s, record.data, 50.0, g[2]);
}

TrialOutcome process_trial(const Manifest& manifest, const TrialData& trial,
                           const std::vector<calibration::Camera>& cameras, double max_tilt_deg) {
  TrialOutcome outcome;
  outcome.trajectories = reconstruction::reconstruct(cameras, trial.tracks.uv_px, trial.tracks.n_points());
  auto options = trial_options(manifest, trial.spec.id);
  if (max_tilt_deg > 0.0) options.max_tilt_deg = max_tilt_deg;
  forceplate::Resultants raw;
  try {
    raw = raw_resultants(manifest, trial.force);
  } catch (const Error& e) {
    // A force record that cannot even be converted: the trial is rejected
    // with the reason; the video-only numbers are still measured.
    outcome.result = trial::analyse_without_force(outcome.trajectories, options, e.what());
    return outcome;
  }
  outcome.result = trial::analyse(raw, force_options(manifest, trial.force), outcome.trajectories, options);
  return outcome;
}

void add_trial_outputs(report::OutputSet& out, const TrialOutcome& outcome) {
  const std::string dir = "trials/" + outcome.result.id + "/";
  out.add(dir + "trial.json", report::trial_json(outcome.result));
  out.add(dir + "series.csv", report::series_csv(outcome.result.series));
  add_reconstruction_outputs(out, outcome.result.id, outcome.trajectories);
}

fitting::TrialData fitting_trial(const Manifest& manifest, const trial::TrialResult& result) {
  fitting::TrialData data;
  data.id = result.id;
  data.accepted = result.accepted;
  data.impact_velocity_m_s = result.impact_velocity_m_s;
  data.impactor_mass_kg = manifest.impactor.mass_kg;
  data.gravity_m_s2 = manifest.gravity_m_s2;
  const auto& s = result.series;
  // The surface markers' height at rest: their mean before contact.
  double rest_sum = 0.0;
  int rest_n = 0;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] < result.contact_time_s && std::isfinite(s.surface_z_m[i])) {
      rest_sum += s.surface_z_m[i];
      ++rest_n;
    }
  }
  const double surface_rest_m = rest_n > 0 ? rest_sum / rest_n : manifest.forceplate.mat_top_z_m;
  std::vector<Eigen::Index> keep;
  for (Eigen::Index i = 0; i < s.t_s.size(); ++i) {
    if (s.t_s[i] >= result.contact_time_s) keep.push_back(i);
  }
  const auto n = static_cast<Eigen::Index>(keep.size());
  data.t_s.resize(n);
  data.grf_n.resize(n);
  data.impactor_m.resize(n);
  data.surface_m.resize(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const Eigen::Index i = keep[k];
    data.t_s[k] = s.t_s[i] - result.contact_time_s;
    data.grf_n[k] = s.fz_n[i];
    data.impactor_m[k] = s.deformation_m[i];
    data.surface_m[k] = surface_rest_m - s.surface_z_m[i];
  }
  return data;
}

fitting::Model5Geometry model5_geometry(const Manifest& manifest) {
  fitting::Model5Geometry g;
  g.mat_length_m = manifest.mat.length_m;
  g.mat_width_m = manifest.mat.width_m;
  g.footprint_length_m = manifest.impactor.footprint_m.x();
  g.footprint_width_m = manifest.impactor.footprint_m.y();
  return g;
}

fitting::FitOptions fit_options(const Manifest& manifest, fitting::ModelKind model) {
  fitting::FitOptions options;
  options.model = model;
  const auto& layers = manifest.mat.layers;
  if (layers.size() >= 2) {
    options.m2_kg = layers.back().mass_kg;
    options.m1_kg = manifest.mat.mass_kg() - options.m2_kg;
  } else if (layers.size() == 1) {
    options.m1_kg = options.m2_kg = layers.front().mass_kg / 2;
  }
  if (model == fitting::ModelKind::Model5) {
    const auto geometry = model5_geometry(manifest);
    options.simulator = [geometry](const fitting::MatParams& p, const fitting::Impact& impact) {
      return fitting::simulate_model5(p, geometry, impact);
    };
  }
  return options;
}

void add_fit_outputs(report::OutputSet& out, const std::string& prefix, const fitting::FitResult& fit,
                     const std::vector<fitting::TrialData>& trials, double impactor_mass_kg) {
  out.add(prefix + "fit.json", report::fit_json(fit, impactor_mass_kg));
  for (const auto& report : fit.trials) {
    for (const auto& data : trials) {
      if (data.id == report.id) out.add(prefix + "series/" + data.id + ".csv", report::fit_series_csv(data, report));
    }
  }
}

report::MatGeometry mat_geometry(const Manifest& manifest) {
  report::MatGeometry geometry;
  geometry.length_m = manifest.mat.length_m;
  geometry.width_m = manifest.mat.width_m;
  const auto& layers = manifest.mat.layers;
  if (layers.size() >= 2) {
    geometry.bottom_thickness_m = layers.back().thickness_m;
    geometry.top_thickness_m = manifest.mat.thickness_m() - layers.back().thickness_m;
  }
  return geometry;
}

RunSummary run_session(const std::string& session_dir, const RunOptions& options, report::OutputSet& out,
                       Progress* progress) {
  auto say = [&](const std::string& stage, const std::string& detail = "") {
    if (progress) progress->update(stage, detail);
  };
  say("reading", session_dir);
  const Session session = capture::read_session(session_dir);
  RunSummary summary;
  summary.session = session.manifest.name.empty() ? session_dir : session.manifest.name;

  say(summary.session, "calibrating");
  const auto calibration = calibrate_session(session);
  add_calibration_outputs(out, calibration);
  const auto cameras = cameras_of(calibration);

  std::vector<trial::TrialResult> results;
  std::vector<fitting::TrialData> fit_data;
  for (size_t i = 0; i < session.trials.size(); ++i) {
    const auto& trial = session.trials[i];
    say(summary.session, fmt::format("trial {} ({}/{})", trial.spec.id, i + 1, session.trials.size()));
    auto outcome = process_trial(session.manifest, trial, cameras);
    add_trial_outputs(out, outcome);
    fit_data.push_back(fitting_trial(session.manifest, outcome.result));
    summary.accepted += outcome.result.accepted ? 1 : 0;
    results.push_back(std::move(outcome.result));
  }
  summary.trials = static_cast<int>(results.size());
  out.add("summary.csv", report::summary_csv(results));

  report::SessionReport rep;
  rep.session_name = summary.session;
  rep.session_path = session_dir;
  rep.calibration = &calibration;
  rep.trials = results;
  rep.fit_data = fit_data;

  if (summary.accepted == 0) {
    summary.notes.push_back("no accepted trial: nothing to fit");
  } else {
    std::vector<std::optional<fitting::FitResult>> fits(options.models.size());
    std::vector<std::string> errors(options.models.size());
    auto fit_one = [&](size_t k, const fitting::FitOptions& fit_opts) {
      say(summary.session, "fitting " + fitting::model_name(options.models[k]));
      try {
        fits[k] = fitting::fit(fit_data, fit_opts);
      } catch (const std::exception& e) {
        errors[k] = e.what();
      }
    };
    // The point-mass models first, in parallel; then Model 5, whose numeric
    // derivatives make each start cost ~100 Model 4 fits, from Model 4's
    // optimum (its parameters mean the same thing) with one start.
    std::vector<size_t> first, last;
    for (size_t k = 0; k < options.models.size(); ++k) {
      (options.models[k] == fitting::ModelKind::Model5 ? last : first).push_back(k);
    }
    std::vector<std::thread> workers;
    std::atomic<size_t> next{0};
    const int threads = std::max(1, std::min<int>(options.threads, static_cast<int>(first.size())));
    for (int w = 0; w < threads; ++w) {
      workers.emplace_back([&] {
        for (size_t i; (i = next++) < first.size();) {
          fit_one(first[i], fit_options(session.manifest, options.models[first[i]]));
        }
      });
    }
    for (auto& w : workers) w.join();
    for (size_t k : last) {
      auto fit_opts = fit_options(session.manifest, options.models[k]);
      for (size_t j = 0; j < options.models.size(); ++j) {
        if (options.models[j] == fitting::ModelKind::Model4 && fits[j]) {
          fit_opts.initial = fits[j]->params;
          fit_opts.starts = 1;
        }
      }
      fit_one(k, fit_opts);
    }
    for (size_t k = 0; k < options.models.size(); ++k) {
      const auto name = fitting::model_name(options.models[k]);
      if (!fits[k]) {
        summary.notes.push_back(fmt::format("{} fit failed: {}", name, errors[k]));
        continue;
      }
      add_fit_outputs(out, "fits/" + name + "/", *fits[k], fit_data, session.manifest.impactor.mass_kg);
      if (options.models[k] == fitting::ModelKind::Model4) {
        add_fit_outputs(out, "", *fits[k], fit_data, session.manifest.impactor.mass_kg);
      }
      if (options.models[k] == fitting::ModelKind::Model3 || options.models[k] == fitting::ModelKind::Model4) {
        out.add("mat_" + name + ".mjcf.xml",
                report::mjcf_xml(options.models[k], fits[k]->params, mat_geometry(session.manifest)));
      }
      for (const auto& w : fits[k]->warnings) summary.notes.push_back(name + ": " + w);
      rep.fits.push_back(std::move(*fits[k]));
    }
  }

  if (options.diagnose) {
    say(summary.session, "closing the loop");
    try {
      const diagnosis::DiagnosisResult loop = diagnosis::diagnose(session);
      out.add("diagnosis.json", diagnosis::diagnosis_json(loop));
      rep.loop_run = true;
      rep.loop_baseline_model = loop.baseline_model;
      rep.loop_unexplained = loop.unexplained;
      for (const auto& e : loop.effects) {
        rep.loop_effects.push_back({e.stage, e.name, e.evidence, e.error_before, e.error_after});
      }
    } catch (const std::exception& e) {
      summary.notes.push_back(fmt::format("closing the loop failed: {}", e.what()));
    }
  }
  for (const auto& r : results) {
    if (!r.accepted) summary.notes.push_back(fmt::format("trial {} rejected: {}", r.id, r.reject_reason));
  }
  rep.notes = summary.notes;
  say(summary.session, "report");
  out.add("report.html", report::session_report_html(rep));
  if (progress) progress->done();
  return summary;
}

fitting::Simulation simulate_fitted(const report::FitFile& fit, const fitting::Impact& impact,
                                    const fitting::Model5Geometry& geometry) {
  if (fit.model == fitting::ModelKind::Model5) return fitting::simulate_model5(fit.params, geometry, impact);
  return fitting::simulate(fit.model, fit.params, impact);
}

}  // namespace dropfit::pipeline
