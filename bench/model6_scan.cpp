// Model 6 (the foam column) on continuum sessions: a one-off scan (not a
// test, not run by CTest) of its held-out errors against the truth, trained
// as the pipeline trains it (the accepted trial with the median impact
// velocity) and predicting every other trial.
//
//   model6_scan SESSION...
//       SESSION: a generator foam-world seed (`2401`: the session
//       synth::foam_world_options(seed) makes) or a session folder with a
//       truth.json beside it (../shared/validation-continuum/c1-foam).
//
// Environment: M6_ELEMENTS=n_top,n_base,max_step_s fits another column
// than the pipeline's; M6_HELD_EXPONENT=1 keeps the densification exponent
// held (never freed); M6_NO_SCREEN=1 starts from the generic start alone
// (no screening of the base foam's stiffness); M6_DUMP=1 prints each training trial's measured and
// fitted force and travel.
//
// Prints per trial the peak force's error (% of the truth), the maximum
// face travel's (mm), the clock offset's (ms; the trial stage's offset less
// Model 6's fitted contact shift, against the truth) with its stated SE,
// the measured travel's and impact velocity's own errors, and per session
// the training residual (noise SDs), the fit's time, the strains the fitted
// column reaches, its elastic laws against the generator's, and the
// largest held-out errors, and the held-out trials the fit flags as
// extrapolations of a foam's law (fitting/model6_fit.h). The prediction
// intervals: per trial the errors of the peak force, time to peak and
// largest travel in SEs as stated (calibrated), uncalibrated (the training
// misfit times its growth) and without the model's discrepancy; per trial an
// `OFF id offset truth se_before se_after` line (ms: the clock offset's SE
// as fitted and as calibrated, fitting/model6_calibration.h); a
// machine-readable `ROW id train growth` line (per quantity: value, truth,
// the parameters' and velocity's SE, the discrepancy's SD) and the time
// the intervals take; at the end their coverage over all sessions (the
// truth inside [low, high]: Student's t where the discrepancy was scaled).
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "capture/io.h"
#include "fitting/model6_calibration.h"
#include "fitting/model6_fit.h"
#include "pipeline/model6_stage.h"
#include "pipeline/pipeline.h"
#include "samples/generator/synth.h"

namespace {

using namespace dropfit;
namespace fs = std::filesystem;

struct TruthTrial {
  std::string id;
  double peak_n = 0.0, max_deformation_m = 0.0, offset_s = 0.0, velocity_m_s = 0.0, time_to_peak_s = 0.0;
};

// Coverage tallies of the 95 % prediction intervals: [held out, training]
// x [with the model's discrepancy, parameters and velocity alone] x
// [peak force, time to peak, largest travel]; n per [held out, training].
// [held out, training] x [calibrated, uncalibrated discrepancy,
// parameters and velocity alone] x [peak force, time to peak, largest
// travel]; the clock offsets' [before, after] their calibration.
struct Coverage {
  int hit[2][3][3] = {};
  int n[2] = {};
  double z2[2][3][3] = {};
  int offset_hit[2] = {}, offset_n = 0;
  double offset_z2[2] = {};
};
Coverage g_coverage;

// Scores each trial's prediction intervals (as fitted, and again without
// the discrepancy) against the truth; prints each trial's errors in SEs.
void score_intervals(const fitting::Model6FitResult& fit, const std::vector<fitting::TrialData>& data,
                     const fitting::Model6FitOptions& o, const std::vector<TruthTrial>& truth) {
  fitting::Model6FitResult bare = fit, raw = fit;
  fitting::Model6FitOptions bo = o, ro = o;
  bo.model_discrepancy = false;
  ro.cross_validate_discrepancy = false;
  fitting::add_model6_prediction_intervals(data, ro, raw);
  const auto t0 = std::chrono::steady_clock::now();
  const std::clock_t c0 = std::clock();
  fitting::add_model6_prediction_intervals(data, bo, bare);
  std::printf("  prediction intervals: %.3f s wall, %.3f s CPU (of the fit's %.2f s)\n",
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
              static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC, fit.seconds);
  for (const TruthTrial& t : truth) {
    for (size_t k = 0; k < fit.trials.size(); ++k) {
      if (fit.trials[k].id != t.id) continue;
      const int tr = fit.trials[k].train ? 1 : 0;
      const double g = k < fit.discrepancy.size() ? fit.discrepancy[k].growth : 1.0;
      std::printf("    %s%s growth %.2f:", t.id.c_str(), tr ? "*" : " ", g);
      ++g_coverage.n[tr];
      for (int w = 0; w < 3; ++w) {
        const fitting::Prediction& p = (w == 0 ? fit : w == 1 ? raw : bare).trials[k].prediction;
        const fitting::PredictionInterval* iv[3] = {&p.peak_force_n, &p.time_to_peak_s, &p.max_deformation_m};
        const double tv[3] = {t.peak_n, t.time_to_peak_s, t.max_deformation_m};
        for (int q = 0; q < 3; ++q) {
          const double z = (iv[q]->value - tv[q]) / iv[q]->se;
          g_coverage.hit[tr][w][q] += tv[q] >= iv[q]->low && tv[q] <= iv[q]->high ? 1 : 0;
          g_coverage.z2[tr][w][q] += std::isfinite(z) ? z * z : 1e4;
          std::printf(" %s %+6.2f", q > 0 ? "" : w == 0 ? "z(peak,tpk,travel)" : w == 1 ? " | uncalibrated" : " | bare", z);
        }
      }
      const fitting::Prediction& p = fit.trials[k].prediction;
      const fitting::Prediction& b = bare.trials[k].prediction;
      const fitting::Model6Discrepancy d = k < fit.discrepancy.size() ? fit.discrepancy[k] : fitting::Model6Discrepancy{};
      // One machine-readable row per trial: per quantity value, truth, the
      // parameters' and velocity's SE and the discrepancy's SD.
      std::printf("\nROW %s %d %.4f %.8g %.8g %.6g %.6g %.8g %.8g %.6g %.6g %.8g %.8g %.6g %.6g", t.id.c_str(), tr, g,
                  p.peak_force_n.value, t.peak_n, b.peak_force_n.se, d.peak_force_n, p.time_to_peak_s.value,
                  t.time_to_peak_s, b.time_to_peak_s.se, d.time_to_peak_s, p.max_deformation_m.value,
                  t.max_deformation_m, b.max_deformation_m.se, d.max_deformation_m);
      std::printf("\n   ");
      std::printf(" | se %.2f %% %.3f ms %.2f mm; err %+.2f %% %+.3f ms %+.2f mm\n", 100.0 * p.peak_force_n.se / t.peak_n,
                  1e3 * p.time_to_peak_s.se, 1e3 * p.max_deformation_m.se,
                  100.0 * (p.peak_force_n.value / t.peak_n - 1.0), 1e3 * (p.time_to_peak_s.value - t.time_to_peak_s),
                  1e3 * (p.max_deformation_m.value - t.max_deformation_m));
    }
  }
}

void print_coverage() {
  const char* q[3] = {"peak force", "time to peak", "max deformation"};
  const char* what[3] = {"calibrated", "uncalibrated discrepancy", "parameters + velocity"};
  for (int tr = 0; tr < 2; ++tr)
    for (int w = 0; w < 3; ++w) {
      std::printf("coverage %s, %s (n %d):", tr ? "training" : "held out", what[w],
                  g_coverage.n[tr]);
      for (int k = 0; k < 3; ++k)
        std::printf(" %s %.1f %% (RMS z %.2f)", q[k], 100.0 * g_coverage.hit[tr][w][k] / std::max(1, g_coverage.n[tr]),
                    std::sqrt(g_coverage.z2[tr][w][k] / std::max(1, g_coverage.n[tr])));
      std::printf("\n");
    }
  for (int a = 0; a < 2; ++a)
    std::printf("coverage clock offsets, %s (n %d): %.1f %% (RMS z %.2f)\n", a ? "calibrated" : "uncalibrated",
                g_coverage.offset_n, 100.0 * g_coverage.offset_hit[a] / std::max(1, g_coverage.offset_n),
                std::sqrt(g_coverage.offset_z2[a] / std::max(1, g_coverage.offset_n)));
}

struct Worst {
  double peak = 0.0, travel_m = 0.0, offset_s = 0.0, z = 0.0;
};

// The fitted elastic laws against the generator's (when known), and the
// strains the fitted column reaches in each trial.
void compare_laws(const fitting::Model6FitResult& fit, const fitting::Model6FitOptions& o,
                  const std::vector<fitting::TrialData>& data, const synth::FoamColumn* truth) {
  for (const auto& d : data) {
    fitting::Impact imp;
    imp.mass_kg = d.impactor_mass_kg;
    imp.velocity_m_s = d.impact_velocity_m_s;
    imp.duration_s = 0.12;
    imp.output_dt_s = 2.5e-4;
    const fitting::Model6Result r = fitting::simulate_model6_detailed(fit.params, o.geometry, imp);
    std::printf("    %s v %.2f: max strain top %.3f base %.3f\n", d.id.c_str(), d.impact_velocity_m_s,
                r.max_top_strain, r.max_base_strain);
  }
  if (!truth) return;
  for (int layer = 0; layer < 2; ++layer) {
    std::printf("    %s stress kPa fit/truth:", layer == 0 ? "top " : "base");
    for (double e = 0.1; e < 0.86; e += 0.05) {
      const double f = fitting::foam_elastic_stress_pa(layer == 0 ? fit.params.top : fit.params.base, e);
      const double t = synth::foam_stress_pa(layer == 0 ? truth->top : truth->base, e);
      std::printf(" %.2f:%.1f/%.1f", e, 1e-3 * f, 1e-3 * t);
    }
    std::printf("\n");
  }
}

Worst scan(const std::string& label, const Session& session, const std::vector<TruthTrial>& truth,
           const synth::FoamColumn* column = nullptr) {
  const pipeline::SessionState state = pipeline::build(session, {.upto = pipeline::Stage::Trials});
  fitting::Model6FitOptions o = pipeline::model6_options(session.manifest);
  if (const char* e = std::getenv("M6_ELEMENTS")) std::sscanf(e, "%d,%d,%lf", &o.geometry.n_top, &o.geometry.n_base,
                                                               &o.geometry.max_step_s);
  if (const char* e = std::getenv("M6_HELD_EXPONENT"); e && *e == '1') o.free_exponent_cost_ratio = 0.0;
  if (const char* e = std::getenv("M6_NO_SCREEN"); e && *e == '1') o.start_base_scales = {1.0};
  std::vector<fitting::TrialData> data;
  for (const auto& d : state.fit_data)
    if (d.accepted) data.push_back(d);
  const fitting::Model6FitResult fit = fitting::fit_model6(data, o);
  std::printf("%s: fit %.2f s, %ld iterations, training RMS force %.2f, travel %.2f noise SDs\n", label.c_str(),
              fit.seconds, fit.iterations, fit.force_rms_sigma, fit.impactor_rms_sigma);
  Worst w;
  std::vector<double> offsets, offset_ses, offset_truth;
  std::vector<std::string> offset_ids;
  for (const TruthTrial& t : truth) {
    const auto rep = std::find_if(fit.trials.begin(), fit.trials.end(), [&](const auto& r) { return r.id == t.id; });
    const auto st = std::find_if(state.trials.begin(), state.trials.end(),
                                 [&](const auto& s) { return s.result.id == t.id; });
    if (rep == fit.trials.end() || st == state.trials.end()) {
      std::printf("  %s: not fitted (rejected?)\n", t.id.c_str());
      continue;
    }
    double peak = 0.0, travel = 0.0;
    for (Eigen::Index i = 0; i < rep->simulation.t_s.size(); ++i) {
      if (rep->simulation.t_s[i] > rep->window_end_s) break;
      peak = std::max(peak, rep->simulation.grf_n[i]);
      if (rep->simulation.t_s[i] >= 0.0) travel = std::max(travel, rep->simulation.impactor_m[i]);
    }
    const double dp = peak / t.peak_n - 1.0, dd = travel - t.max_deformation_m;
    const double doff = st->result.video_offset_s - rep->contact_shift_s - t.offset_s;
    const double z = doff / rep->contact_shift_se_s;
    // The offset and its SE as the pipeline states them
    // (pipeline::apply_model6_offsets), calibrated below.
    offsets.push_back(st->result.video_offset_s - rep->contact_shift_s);
    offset_ses.push_back(std::isfinite(st->result.video_contact_time_se_s)
                             ? std::hypot(rep->contact_shift_se_s, st->result.video_contact_time_se_s)
                             : rep->contact_shift_se_s);
    offset_truth.push_back(t.offset_s);
    offset_ids.push_back(t.id);
    std::printf("  %s%s v %.2f: peak %+6.2f %%, travel %+5.2f mm, offset %+6.3f ms (SE %.3f, z %+5.1f); measured "
                "travel %+5.2f mm, velocity %+.3f m/s\n",
                t.id.c_str(), rep->train ? "*" : " ", rep->impact_velocity_m_s, 100.0 * dp, 1e3 * dd, 1e3 * doff,
                1e3 * rep->contact_shift_se_s, z, 1e3 * (st->result.max_deformation_m - t.max_deformation_m),
                t.velocity_m_s > 0.0 ? rep->impact_velocity_m_s - t.velocity_m_s : 0.0);
    if (rep->train) continue;
    w.peak = std::max(w.peak, std::abs(dp));
    w.travel_m = std::max(w.travel_m, std::abs(dd));
    w.offset_s = std::max(w.offset_s, std::abs(doff));
    w.z = std::max(w.z, std::abs(z));
  }
  const std::vector<double> calibrated =
      fitting::calibrated_offset_ses(offsets, offset_ses, fit.timing_discrepancy_s);
  for (size_t i = 0; i < offsets.size(); ++i) {
    const double e = offsets[i] - offset_truth[i], se[2] = {offset_ses[i], calibrated[i]};
    ++g_coverage.offset_n;
    for (int a = 0; a < 2; ++a) {
      g_coverage.offset_hit[a] += std::abs(e / se[a]) <= 1.959964 ? 1 : 0;
      g_coverage.offset_z2[a] += std::pow(e / se[a], 2);
    }
    std::printf("OFF %s %.6f %.6f %.6f %.6f\n", offset_ids[i].c_str(), 1e3 * offsets[i], 1e3 * offset_truth[i],
                1e3 * se[0], 1e3 * se[1]);
  }
  std::printf("  offsets: Birge ratio %.2f, timing discrepancy %.3f ms\n", fitting::birge_ratio(offsets, offset_ses),
              1e3 * fit.timing_discrepancy_s);
  score_intervals(fit, data, o, truth);
  compare_laws(fit, o, data, column);
  for (const auto& r : fit.reach)
    if (r.extrapolated) std::printf("  extrapolated: %s (top %.3f, base %.3f)\n", r.id.c_str(), r.max_top_strain, r.max_base_strain);
  if (std::getenv("M6_DUMP"))
    for (const auto& rep : fit.trials) {
      if (!rep.train) continue;
      const auto d = std::find_if(data.begin(), data.end(), [&](const auto& x) { return x.id == rep.id; });
      for (Eigen::Index i = 0; i < d->t_s.size(); i += 2)
        if (d->t_s[i] > -0.002 && d->t_s[i] < rep.window_end_s)
          std::printf("      t %7.2f ms F %8.1f sim %8.1f  x %6.2f sim %6.2f mm\n", 1e3 * d->t_s[i], d->grf_n[i],
                      rep.simulation.grf_n[i], 1e3 * d->impactor_m[i], 1e3 * rep.simulation.impactor_m[i]);
    }
  std::printf("  held out within: peak %.2f %%, travel %.2f mm, offset %.3f ms, |z| %.1f\n", 100.0 * w.peak,
              1e3 * w.travel_m, 1e3 * w.offset_s, w.z);
  for (const auto& e : fit.estimates) std::printf("    %-22s %.4g%s\n", e.name.c_str(), e.value, e.at_bound ? " (bound)" : "");
  return w;
}

Worst scan_arg(const std::string& arg) {
  if (!arg.empty() && std::all_of(arg.begin(), arg.end(), [](char c) { return c >= '0' && c <= '9'; })) {
    const synth::SynthOptions so = synth::foam_world_options(std::stoull(arg));
    for (const synth::FoamLayer* l : {&so.foam->top, &so.foam->base})
      std::printf("truth layer: s_p %.4g E %.4g H %.4g D %.4g e_d %.3f n %.2f\n", l->plateau_pa, l->modulus_pa,
                  l->hardening_pa, l->densification_pa, l->densification_strain, l->densification_exponent);
    std::printf("truth memory: g1 %.3f tau1 %.4f g2 %.3f tau2 %.4f eta %.1f\n", so.foam->g1, so.foam->tau1_s, so.foam->g2,
                so.foam->tau2_s, so.foam->viscosity_pa_s);
    const synth::SyntheticSession s = synth::make_session(so);
    std::vector<TruthTrial> tt;
    for (const auto& t : s.truth.trials) tt.push_back({t.id, t.peak_force_n, t.max_deformation_m, t.video_offset_s, t.impact_velocity_m_s, t.time_to_peak_s});
    return scan("seed " + arg, s.session, tt, &*so.foam);
  }
  const fs::path dir(arg);
  std::ifstream in(dir / "truth.json");
  const nlohmann::json truth = nlohmann::json::parse(in);
  std::vector<TruthTrial> tt;
  for (const auto& t : truth["trials"])
    tt.push_back({t["id"], t["peak_force_n"], t["max_deformation_m"], t["video_offset_s"], 0.0, t["time_to_peak_s"]});
  return scan(dir.filename().string(), capture::read_session((dir / "session").string()), tt);
}

}  // namespace

int main(int argc, char** argv) {
  Worst all;
  for (int i = 1; i < argc; ++i) {
    try {
      const Worst w = scan_arg(argv[i]);
      all.peak = std::max(all.peak, w.peak);
      all.travel_m = std::max(all.travel_m, w.travel_m);
      all.offset_s = std::max(all.offset_s, w.offset_s);
      all.z = std::max(all.z, w.z);
    } catch (const std::exception& e) {
      std::printf("%s: %s\n", argv[i], e.what());
    }
    std::fflush(stdout);
  }
  print_coverage();
  std::printf("all held out within: peak %.2f %%, travel %.2f mm, offset %.3f ms, |z| %.1f\n", 100.0 * all.peak,
              1e3 * all.travel_m, 1e3 * all.offset_s, all.z);
  return 0;
}
