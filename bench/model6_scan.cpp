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
// extrapolations of a foam's law (fitting/model6_fit.h).
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "capture/io.h"
#include "fitting/model6_fit.h"
#include "pipeline/model6_stage.h"
#include "pipeline/pipeline.h"
#include "samples/generator/synth.h"

namespace {

using namespace dropfit;
namespace fs = std::filesystem;

struct TruthTrial {
  std::string id;
  double peak_n = 0.0, max_deformation_m = 0.0, offset_s = 0.0, velocity_m_s = 0.0;
};

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
    for (const auto& t : s.truth.trials) tt.push_back({t.id, t.peak_force_n, t.max_deformation_m, t.video_offset_s, t.impact_velocity_m_s});
    return scan("seed " + arg, s.session, tt, &*so.foam);
  }
  const fs::path dir(arg);
  std::ifstream in(dir / "truth.json");
  const nlohmann::json truth = nlohmann::json::parse(in);
  std::vector<TruthTrial> tt;
  for (const auto& t : truth["trials"])
    tt.push_back({t["id"], t["peak_force_n"], t["max_deformation_m"], t["video_offset_s"]});
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
  std::printf("all held out within: peak %.2f %%, travel %.2f mm, offset %.3f ms, |z| %.1f\n", 100.0 * all.peak,
              1e3 * all.travel_m, 1e3 * all.offset_s, all.z);
  return 0;
}
