#include "report/session_report.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <iterator>

#include "report/export.h"
#include "report/html.h"
#include "report/plot.h"

namespace dropfit::report {
namespace {

std::string num(double v, int decimals) {
  if (!std::isfinite(v)) return "-";
  return fmt::format("{:.{}f}", v, decimals);
}

std::vector<double> to_vector(const Eigen::VectorXd& v, double scale = 1.0) {
  std::vector<double> out(static_cast<size_t>(v.size()));
  for (Eigen::Index i = 0; i < v.size(); ++i) out[static_cast<size_t>(i)] = v[i] * scale;
  return out;
}

const char* kModelColours[] = {"#ff7f0e", "#2ca02c", "#9467bd", "#d62728", "#1f77b4"};

void summary_section(HtmlDocument& doc, const SessionReport& r) {
  doc.heading("Session summary");
  std::vector<std::vector<std::string>> rows;
  int accepted = 0;
  for (const auto& t : r.trials) {
    accepted += t.accepted ? 1 : 0;
    rows.push_back({t.id, fmt::format("{} ± {}", num(t.impact_velocity_m_s, 2), num(t.impact_velocity_ci_m_s, 3)),
                    num(t.max_deformation_m, 3), num(t.peak_force_n, 0), num(t.time_to_peak_s * 1e3, 1),
                    num(t.tilt_deg, 1), num(t.video_offset_s * 1e3, 2),
                    t.accepted ? "accepted" : "rejected: " + t.reject_reason});
  }
  doc.paragraph(fmt::format("{} trials, {} accepted. Rejected trials are listed with their reason, never dropped.",
                            r.trials.size(), accepted));
  doc.table({"trial", "impact velocity (m/s, 95 % CI)", "max deformation (m)", "peak force (N)",
             "time to peak (ms)", "tilt (deg)", "video - force clock (ms)", "status"},
            rows, "Vertical drop test results (the shape of the paper's Table 1)", 1);
}

// The headline: the final model's parameters with their standard errors,
// the effects it carries, and its warnings.
void final_model_section(HtmlDocument& doc, const SessionReport& r) {
  if (!r.final_fit) return;
  const fitting::FitResult& fit = *r.final_fit;
  doc.heading("The mat model");
  if (r.final_label == "model6") {
    doc.paragraph(fmt::format(
        "The result of this session is Model 6, the mat as a foam column (an elastic foam law with plateau and "
        "densification per layer, two Prony terms, a viscosity), trained on {}; fit.json holds it. {} Every model's "
        "own fit is under fits/.",
        fmt::join(fit.train_ids, ", "), r.final_note));
  } else {
    doc.paragraph(fmt::format(
        "The result of this session is {} ({}), trained on {}; fit.json and mat.mjcf.xml hold it. {}",
        r.final_label == "closed_loop" ? "the closed loop's model" : "the " + fitting::model_name(fit.model) + " fit",
        r.final_label == "closed_loop" ? fitting::model_name(fit.model) + " with the mat effects the loop kept"
                                       : "no mat effect was needed",
        fmt::join(fit.train_ids, ", "), "Every model's own fit is under fits/."));
  }
  std::vector<std::vector<std::string>> rows;
  for (const auto& e : fit.estimates) {
    std::string note = !e.identifiable ? "not identifiable" : e.at_bound ? "at its bound" : e.free ? "" : "fixed";
    // A note says why a parameter has no interval, or what limits it.
    if (!e.note.empty() && (!e.identifiable || (e.free && !std::isfinite(e.ci_low))))
      note += (note.empty() ? "" : ": ") + e.note;
    const std::string ci = e.free && std::isfinite(e.ci_low)
                               ? fmt::format("[{:.4g}, {:.4g}] ({})", e.ci_low, e.ci_high, e.interval)
                               : "-";
    rows.push_back({e.name, fmt::format("{:.4g}", e.value), e.free && std::isfinite(e.se) ? fmt::format("{:.2g}", e.se) : "-",
                    ci, note});
  }
  doc.table({"parameter", "value", "standard error", "95 % interval", "note"}, rows,
            "The final model's parameters (SI units)", 1);
  for (const auto& w : fit.warnings) doc.note(w);
}

void calibration_section(HtmlDocument& doc, const calibration::CalibrationResult& c) {
  doc.heading("Calibration accuracy");
  std::vector<std::vector<std::string>> cams;
  for (const auto& fit : c.cameras) {
    cams.push_back({fit.camera.name, std::to_string(fit.n_fit_points), num(fit.fit_rms_px, 3),
                    fit.camera.distortion.empty() ? "dlt11" : "dlt16"});
  }
  doc.table({"camera", "fit markers", "reprojection RMS (px)", "model"}, cams, "Cameras", 1);
  doc.paragraph(fmt::format("Check markers (held out of the fit): RMS x {} mm, y {} mm, z {} mm; largest {} mm.",
                            num(c.check_rms_m.x() * 1e3, 2), num(c.check_rms_m.y() * 1e3, 2),
                            num(c.check_rms_m.z() * 1e3, 2), num(c.check_max_m * 1e3, 2)));
  if (!c.check_points.empty()) {
    BarPlot plot{"Check-marker reconstruction error", "error (mm)", {}, {}, 720, 300};
    BarGroup gx{"x", {}, "#1f77b4"}, gy{"y", {}, "#2ca02c"}, gz{"z", {}, "#d62728"};
    for (const auto& p : c.check_points) {
      plot.categories.push_back(p.id);
      gx.values.push_back(p.error_m.x() * 1e3);
      gy.values.push_back(p.error_m.y() * 1e3);
      gz.values.push_back(p.error_m.z() * 1e3);
    }
    plot.groups = {gx, gy, gz};
    doc.figure(svg(plot), "Reconstructed minus known position of each check marker, per lab axis.");
  }
  if (!c.cameras.empty() && !c.cameras.front().residuals_px.empty()) {
    BarPlot plot{"Reprojection residual of the fit markers", "residual (px)", {}, {}, 720, 300};
    for (size_t k = 0; k < c.cameras.size(); ++k) {
      BarGroup g{c.cameras[k].camera.name, {}, ""};
      for (size_t i = 0; i < c.cameras[k].residuals_px.size(); ++i) {
        if (k == 0) plot.categories.push_back(std::to_string(i + 1));
        g.values.push_back(c.cameras[k].residuals_px[i].norm());
      }
      plot.groups.push_back(g);
    }
    doc.figure(svg(plot), "Length of the reprojection residual of each fit marker, per camera.");
  }
  if (!c.leave_one_out.empty()) {
    BarPlot plot{"Leave-one-out residual of the fit markers", "3-D error (mm)", {}, {}, 720, 300};
    BarGroup g{"left out", {}, "#8c564b"};
    for (const auto& l : c.leave_one_out) {
      plot.categories.push_back(l.id);
      g.values.push_back(l.residual_m * 1e3);
    }
    plot.groups = {g};
    doc.figure(svg(plot), "Each fit marker reconstructed by cameras calibrated without it; a mislabelled marker stands out.");
  }
  for (const auto& id : c.outliers) doc.note(fmt::format("Calibration marker {} stands out: check its label and digitising.", id));
}

const fitting::TrialReport* find_report(const fitting::FitResult& fit, const std::string& id) {
  for (const auto& t : fit.trials) {
    if (t.id == id) return &t;
  }
  return nullptr;
}

void trials_section(HtmlDocument& doc, const SessionReport& r) {
  doc.heading("Ground reaction force per trial");
  doc.paragraph("Measured vertical ground reaction force with each fitted model overlaid (the paper's Figures 3 to 7). "
                "Models were trained on the trials marked 'train' and predict the others from their own impact velocity.");
  for (const auto& data : r.fit_data) {
    doc.heading(fmt::format("Trial {} ({} m/s)", data.id, num(data.impact_velocity_m_s, 2)), 3);
    LinePlot force{fmt::format("Trial {}: vertical ground reaction force", data.id), "time from contact (ms)",
                   "force (N)", {}, 720, 360};
    force.series.push_back({"measured", to_vector(data.t_s, 1e3), to_vector(data.grf_n), "#111827", false, false});
    LinePlot travel{fmt::format("Trial {}: impactor travel below the mat top", data.id), "time from contact (ms)",
                    "travel (mm)", {}, 720, 300};
    travel.series.push_back({"measured", to_vector(data.t_s, 1e3), to_vector(data.impactor_m, 1e3), "#111827", false, false});
    std::vector<std::vector<std::string>> rows;
    bool first = true;
    for (const auto& fit : r.fits) {
      const auto* t = find_report(fit, data.id);
      if (!t) continue;
      const auto model = static_cast<int>(fit.model);
      const char* colour = kModelColours[(model - 1) % 5];
      const std::string label = fmt::format("model {}{}", model, t->train ? " (train)" : "");
      force.series.push_back({label, to_vector(t->simulation.t_s, 1e3), to_vector(t->simulation.grf_n), colour, true, false});
      travel.series.push_back(
          {label, to_vector(t->simulation.t_s, 1e3), to_vector(t->simulation.impactor_m, 1e3), colour, true, false});
      if (first) {
        const auto& m = t->measured;
        rows.push_back({"measured", num(m.first_peak_n, 0), num(m.first_peak_s * 1e3, 1), num(m.min_between_n, 0),
                        num(m.min_between_s * 1e3, 1), num(m.second_peak_n, 0), num(m.second_peak_s * 1e3, 1),
                        num(m.max_loading_rate_n_s / 1e3, 0), num(m.peak_force_n, 0), "", ""});
        first = false;
      }
      const auto& s = t->simulated;
      rows.push_back({label, num(s.first_peak_n, 0), num(s.first_peak_s * 1e3, 1), num(s.min_between_n, 0),
                      num(s.min_between_s * 1e3, 1), num(s.second_peak_n, 0), num(s.second_peak_s * 1e3, 1),
                      num(s.max_loading_rate_n_s / 1e3, 0), num(s.peak_force_n, 0),
                      num(t->comparison.rms_force_pct_peak, 1), num(t->comparison.peak_force_pct_diff, 1)});
    }
    doc.figure(svg(force), fmt::format("Trial {}: measured force and the models.", data.id));
    doc.figure(svg(travel), fmt::format("Trial {}: impactor face travel, measured (video) and simulated.", data.id));
    doc.table({"", "1st peak (N)", "at (ms)", "minimum (N)", "at (ms)", "2nd peak (N)", "at (ms)",
               "max loading rate (kN/s)", "peak (N)", "RMS (% peak)", "peak diff (%)"},
              rows, "Key characteristics", 1);
  }
}

// Each trial's predicted quantities with their 95 % intervals (parameters,
// the trial's own velocity and the calibration's scale; Model 6's also the
// model's discrepancy).
void predictions_table(HtmlDocument& doc, const fitting::FitResult& fit, const std::string& caption) {
  std::vector<std::vector<std::string>> rows;
  for (const auto& t : fit.trials) {
    const auto& p = t.prediction;
    if (!std::isfinite(p.peak_force_n.se)) continue;
    auto iv = [](const fitting::PredictionInterval& i, double scale, int digits) {
      return fmt::format("{} [{}, {}]", num(i.value * scale, digits), num(i.low * scale, digits), num(i.high * scale, digits));
    };
    rows.push_back({t.id + (t.train ? " (train)" : ""), iv(p.peak_force_n, 1.0, 0), num(t.measured.peak_force_n, 0),
                    iv(p.time_to_peak_s, 1e3, 1), iv(p.max_deformation_m, 1e3, 1)});
  }
  if (rows.empty()) return;
  doc.table({"trial", "peak force (N)", "measured (N)", "time to peak (ms)", "max deformation (mm)"}, rows, caption, 1);
}

void parameters_section(HtmlDocument& doc, const SessionReport& r) {
  if (r.fits.empty()) return;
  doc.heading("Fitted parameters");
  const std::vector<std::string> names = {"k1_n_m", "k2_n_m", "k3_n_m", "r1_n_s_m", "r2_n_s_m", "r3_n_s_m",
                                          "m_eff_kg", "m1_kg", "m2_kg"};
  std::vector<std::string> header = {"parameter"};
  for (const auto& fit : r.fits) header.push_back(fmt::format("Model {}", static_cast<int>(fit.model)));
  std::vector<std::vector<std::string>> rows;
  for (const auto& name : names) {
    std::vector<std::string> row = {name};
    bool any = false;
    for (const auto& fit : r.fits) {
      std::string cell = "-";
      for (const auto& e : fit.estimates) {
        if (e.name != name) continue;
        any = true;
        cell = std::isfinite(e.se) && e.free ? fmt::format("{:.4g} ± {:.2g}", e.value, e.se) : fmt::format("{:.4g}", e.value);
        if (e.free && std::isfinite(e.ci_low)) cell += fmt::format(" [{:.4g}, {:.4g}]", e.ci_low, e.ci_high);
        if (!e.identifiable) cell += " (not identifiable)";
        if (e.model_limited) cell += " (model-limited)";
      }
      row.push_back(cell);
    }
    if (any) rows.push_back(row);
  }
  doc.table(header, rows,
            "Stiffness (N/m), damping (N s/m) and masses (kg) with standard errors and 95 % intervals (the shape of the "
            "paper's Table 2)",
            1);
  for (const auto& fit : r.fits) {
    for (const auto& w : fit.warnings) doc.note(fmt::format("Model {}: {}", static_cast<int>(fit.model), w));
  }

  doc.heading("Predictions across trials", 3);
  std::vector<std::string> h2 = {"trial"};
  for (const auto& fit : r.fits) {
    h2.push_back(fmt::format("M{} RMS (% peak)", static_cast<int>(fit.model)));
    h2.push_back(fmt::format("M{} peak diff (%)", static_cast<int>(fit.model)));
  }
  std::vector<std::vector<std::string>> rows2;
  for (const auto& data : r.fit_data) {
    std::vector<std::string> row = {data.id};
    for (const auto& fit : r.fits) {
      const auto* t = find_report(fit, data.id);
      row.push_back(t ? num(t->comparison.rms_force_pct_peak, 1) + (t->train ? " (train)" : "") : "-");
      row.push_back(t ? num(t->comparison.peak_force_pct_diff, 1) : "-");
    }
    rows2.push_back(row);
  }
  doc.table(h2, rows2, "Simulated minus measured, each trial predicted from its own impact velocity", 1);

  for (const auto& fit : r.fits)
    predictions_table(doc, fit, fmt::format("Model {} predictions with 95 % intervals", static_cast<int>(fit.model)));
  if (r.final_fit && r.final_label == "model6")
    predictions_table(doc, *r.final_fit,
                      "Model 6 predictions with 95 % intervals (parameters, velocity and the model's discrepancy)");

  for (const auto& fit : r.fits) {
    if (fit.sensitivity.empty()) continue;
    std::vector<std::vector<std::string>> rows3;
    for (const auto& s : fit.sensitivity) rows3.push_back({s.name, num(s.peak_pct_minus10, 2), num(s.peak_pct_plus10, 2)});
    doc.table({"parameter", "-10 % (peak change %)", "+10 % (peak change %)"}, rows3,
              fmt::format("Sensitivity of the peak force, Model {}", static_cast<int>(fit.model)), 1);
  }
}

}  // namespace

void append_loop_section(HtmlDocument& doc, const std::string& baseline_model,
                         const std::vector<LoopEffect>& effects, bool unexplained) {
  doc.heading("Closing the loop");
  doc.paragraph(fmt::format(
      "Each stage's residual was tested for structure and traced to the effect that explains it; an effect is kept "
      "only when the held-out error drops by more than noise would explain. Baseline mat model: {}.",
      baseline_model));
  if (effects.empty()) doc.paragraph("No effect was added: the residuals show no structure the library explains.");
  std::vector<std::vector<std::string>> rows;
  BarPlot plot{"Error before and after each added effect", "error", {}, {}, 720, 320};
  BarGroup before{"before", {}, "#9ca3af"}, after{"after", {}, "#059669"};
  for (const auto& e : effects) {
    std::string b, a;
    for (const auto& [k, v] : e.error_before) b += fmt::format("{} {:.3g}; ", k, v);
    for (const auto& [k, v] : e.error_after) a += fmt::format("{} {:.3g}; ", k, v);
    rows.push_back({e.stage, e.name, e.evidence, b, a});
    if (!e.error_before.empty() && !e.error_after.empty()) {
      plot.categories.push_back(e.name + " (" + e.error_before.front().first + ")");
      before.values.push_back(e.error_before.front().second);
      after.values.push_back(e.error_after.front().second);
    }
  }
  if (!rows.empty()) doc.table({"stage", "effect", "evidence", "error before", "error after"}, rows, "Effects added", 3);
  if (!plot.categories.empty()) {
    plot.groups = {before, after};
    doc.figure(svg(plot), "The first error measure of each effect, before and after it was added.");
  }
  if (unexplained) {
    doc.note("Structured residual remains that no known effect explains (unexplained = true).");
  }
}

namespace {
void loop_section(HtmlDocument& doc, const SessionReport& r) {
  if (r.loop_run) append_loop_section(doc, r.loop_baseline_model, r.loop_effects, r.loop_unexplained);
}

// The held-out residual's map: per axis, each model's binned mean residual.
void residual_form_section(HtmlDocument& doc, const std::vector<ResidualForm>& forms) {
  if (forms.empty()) return;
  doc.heading("The held-out residual's form");
  doc.paragraph(
      "The force residual of the held-out trials (measured minus predicted, in the plate's noise SDs) binned against "
      "the face's deflection (an elastic shape), its rate (a viscous term), the time since contact (a memory) and "
      "each trial's place in the recording (the mat changing between trials). r2 is the share of the residual's "
      "sum of squares the bins explain; the axis that explains most names the term the model lacks.");
  std::vector<std::vector<std::string>> rows;
  for (const auto& f : forms) {
    std::vector<std::string> row{f.model, f.form, f.proposal};
    for (const char* axis : {"deflection_m", "deflection_rate_m_s", "time_since_contact_s", "recording_order"}) {
      const auto a = std::find_if(f.axes.begin(), f.axes.end(), [&](const auto& x) { return x.name == axis; });
      row.push_back(a == f.axes.end() ? "-" : num(a->r2, 2));
    }
    row.push_back(num(f.loading_unloading_r2, 2));
    rows.push_back(std::move(row));
  }
  doc.table({"model", "form", "the term it calls for", "r2 deflection", "r2 rate", "r2 time", "r2 order",
             "r2 loading / unloading"},
            rows, "What explains the held-out residual", 3);
  struct AxisView {
    const char* name;
    const char* label;
    double scale;
  };
  const AxisView views[] = {{"deflection_m", "deflection (mm)", 1e3},
                            {"deflection_rate_m_s", "deflection rate (m/s, + loading)", 1.0},
                            {"time_since_contact_s", "time since contact (ms)", 1e3},
                            {"recording_order", "trial's place in the recording (0 = first)", 1.0}};
  for (const AxisView& v : views) {
    LinePlot plot{fmt::format("Held-out residual against {}", v.label), v.label, "mean residual (noise SDs)", {}, 640, 300};
    for (size_t k = 0; k < forms.size(); ++k)
      for (const auto& a : forms[k].axes) {
        if (a.name != v.name || a.centre.size() < 2) continue;  // a line needs two bins
        LineSeries s{fmt::format("{} (r2 {:.2f})", forms[k].model, a.r2), {}, a.mean_sd,
                     kModelColours[k % std::size(kModelColours)]};
        for (double c : a.centre) s.x.push_back(c * v.scale);
        plot.series.push_back(std::move(s));
      }
    if (!plot.series.empty())
      doc.figure(svg(plot), fmt::format("Binned mean held-out force residual against {}.", v.label));
  }
}
}  // namespace

std::string session_report_html(const SessionReport& r) {
  HtmlDocument doc("dropfit report: " + r.session_name);
  doc.paragraph(fmt::format("Session folder: {}. Drop tests of the impactor on the landing mat, processed from the raw "
                            "files; models after Mills, Pain & Yeadon (2006).",
                            r.session_path));
  for (const auto& n : r.notes) doc.note(n);
  summary_section(doc, r);
  final_model_section(doc, r);
  if (r.calibration) calibration_section(doc, *r.calibration);
  // Where the impact velocity's calibration term comes from when the
  // calibration could not be checked, or why there is none (the trials'
  // own words).
  for (const auto& t : r.trials)
    if (t.calibration_uncertainty.rfind("declared", 0) == 0 || t.calibration_uncertainty.rfind("none", 0) == 0) {
      doc.note(fmt::format("Impact velocity intervals: {}.", t.calibration_uncertainty));
      break;
    }
  trials_section(doc, r);
  parameters_section(doc, r);
  loop_section(doc, r);
  residual_form_section(doc, r.residual_forms);
  return doc.str();
}

}  // namespace dropfit::report
