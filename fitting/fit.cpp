// Fitting the mat models to drop-test trials: the public API (fit, predict,
// residuals, residual_jacobian) over the parameter space (space.cpp), the
// objective (objective.cpp), the starts (starts.cpp), the search
// (search.cpp) and the uncertainty (uncertainty.cpp). See fit.h for the
// method.
#include "fitting/fit.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <exception>
#include <sstream>
#include <utility>

#include "core/error.h"
#include "core/parallel.h"
#include "fitting/detail/identify.h"
#include "fitting/detail/objective.h"
#include "fitting/detail/search.h"
#include "fitting/detail/space.h"
#include "fitting/detail/uncertainty.h"

namespace dropfit::fitting {

using namespace internal;

namespace {

std::vector<const TrialData*> choose_train(const std::vector<TrialData>& trials, const std::vector<std::string>& ids) {
  std::vector<const TrialData*> out;
  if (!ids.empty()) {
    for (const auto& id : ids) {
      auto it = std::find_if(trials.begin(), trials.end(), [&](const TrialData& t) { return t.id == id; });
      if (it == trials.end()) throw Error(fmt::format("fit: training trial '{}' not found", id));
      out.push_back(&*it);
    }
    return out;
  }
  std::vector<const TrialData*> acc;
  for (const auto& t : trials)
    if (t.accepted) acc.push_back(&t);
  if (acc.empty()) throw Error("fit: no accepted trial to train on");
  std::sort(acc.begin(), acc.end(), [](const TrialData* a, const TrialData* b) {
    return a->impact_velocity_m_s < b->impact_velocity_m_s;
  });
  out.push_back(acc[(acc.size() - 1) / 2]);
  return out;
}

void check_options(const FitOptions& o) {
  if (!(o.force_noise_n > 0.0) || !(o.marker_noise_m > 0.0))
    throw Error("fit: force_noise_n and marker_noise_m must be positive");
  if (!(o.m1_kg >= 0.0) || !(o.m2_kg >= 0.0)) throw Error("fit: layer masses must be >= 0");
  if (!(o.force_lowpass_hz >= 0.0)) throw Error("fit: force_lowpass_hz must be >= 0 (0: none)");
  if (o.starts < 1) throw Error("fit: starts must be at least 1");
  if (!(o.contact_shift_min_s <= 0.0) || !(o.contact_shift_max_s >= 0.0) || !(o.contact_search_s >= 0.0) ||
      !(o.contact_search_s >= -o.contact_shift_min_s))
    throw Error("fit: contact_shift_min_s must be <= 0, contact_shift_max_s >= 0 and contact_search_s >= "
                "-contact_shift_min_s");
  if (o.oversample < 1 || o.oversample > 64) throw Error("fit: oversample must be in [1, 64]");
  if (!(o.k_min_n_m > 0.0) || !(o.k_max_n_m > o.k_min_n_m) || !(o.r_min_n_s_m > 0.0) ||
      !(o.r_max_n_s_m > o.r_min_n_s_m))
    throw Error("fit: stiffness and damping bounds must be positive and increasing");
}

// A fit from scratch (not a refit near a known optimum: the loop's
// candidates, a warm start) also looks for Model 4's conjugate basin and
// the intervals beyond the linearisation (fitting/detail/identify.h).
bool searches_identifiability(const FitOptions& o) {
  if (o.optimizer != Optimizer::Ceres || o.protect_initial) return false;
  return o.search_identifiability || (o.every_ordering && !(o.initial.k1_n_m > 0.0 && o.starts == 1));
}

struct FitCore {
  MatParams params;
  Search search;
  ParamSpace space;
  std::vector<Prepared> preps;
  std::string used;
};

FitCore fit_core(const std::vector<const TrialData*>& train, const FitOptions& o, std::atomic<long>* evals,
                 std::vector<std::string>* warnings) {
  FitCore fc;
  for (const TrialData* t : train) fc.preps.push_back(prepare(*t, o));
  const double k_eff = effective_stiffness(fc.preps);
  fc.space = make_space(o, k_eff);
  fc.search = optimise(fc.preps, fc.space, o, k_eff, evals, warnings, &fc.used);
  if (searches_identifiability(o)) search_conjugate(fc.preps, fc.space, o, evals, &fc.search);
  fc.params = fc.space.to_mat(fc.search.best.u.data());
  return fc;
}

// The fixed parameters' estimates (for completeness), after the free ones;
// with the masses free, m2 follows m1 (their total fixed).
void add_fixed_estimates(const FitOptions& options, FitResult* res_ptr) {
  FitResult& res = *res_ptr;
  const ModelKind shape = options.model == ModelKind::Model5 ? ModelKind::Model4 : options.model;
  for (const auto& name : parameter_names(shape, true)) {
    const bool is_free = std::any_of(res.estimates.begin(), res.estimates.end(),
                                     [&](const ParameterEstimate& e) { return e.name == name; });
    if (is_free) continue;
    ParameterEstimate e;
    e.name = name;
    e.value = get_parameter(res.params, name);
    e.free = false;
    e.se = 0.0;
    e.rel_se = 0.0;
    res.estimates.push_back(e);
  }
  if (options.masses_free && (shape == ModelKind::Model3 || shape == ModelKind::Model4)) {
    for (auto& e : res.estimates)
      if (e.name == "m2_kg") {
        e.free = true;  // follows m1 (total fixed)
        for (const auto& f : res.estimates)
          if (f.name == "m1_kg") { e.se = f.se; e.rel_se = f.se / std::max(e.value, 1e-12); }
      }
  }
}

// Every trial predicted (each its own simulation: in parallel, over
// `threads`); the training trials' clock shifts from the joint optimum. A
// rejected trial whose data cannot be predicted (a force record without a
// contact) is left out with a warning: it never sinks the fit of the
// accepted ones.
void predict_trials(const std::vector<TrialData>& trials, const FitOptions& options, const FitCore& fc,
                    const std::vector<double>& shift_se, FitResult* res_ptr) {
  FitResult& res = *res_ptr;
  const Optimum& best = fc.search.best;
  std::vector<TrialReport> predicted(trials.size());
  std::vector<std::string> unpredicted(trials.size());
  {
    std::vector<std::exception_ptr> failures(trials.size());
    // (A custom simulator is not assumed thread-safe.)
    parallel_for(trials.size(), options.simulator ? 1 : options.threads, [&](size_t q) {
      try {
        predicted[q] = predict(trials[q], res.params, options);
      } catch (const std::exception& e) {
        if (trials[q].accepted) failures[q] = std::current_exception();
        else unpredicted[q] = e.what();
      } catch (...) {
        failures[q] = std::current_exception();
      }
    });
    for (const auto& f : failures)
      if (f) std::rethrow_exception(f);
  }
  for (size_t q = 0; q < trials.size(); ++q) {
    const TrialData& t = trials[q];
    if (!unpredicted[q].empty()) {
      res.warnings.push_back(fmt::format("rejected trial {} not predicted: {}", t.id, unpredicted[q]));
      continue;
    }
    TrialReport rep = std::move(predicted[q]);
    rep.train = std::find(res.train_ids.begin(), res.train_ids.end(), t.id) != res.train_ids.end();
    if (rep.train) {
      // The training trials' shifts come from the joint optimum, with the
      // joint (unconditional) standard error.
      size_t k = 0, b = 0;
      for (; k < fc.preps.size(); ++k) {
        if (fc.preps[k].data->id == t.id) break;
        if (fc.preps[k].shifted()) ++b;
      }
      if (k < fc.preps.size() && fc.preps[k].shifted()) {
        rep.contact_shift_s = best.shifts[k];
        if (b < shift_se.size()) rep.contact_shift_se_s = shift_se[b];
      }
    }
    res.trials.push_back(std::move(rep));
  }
}

// Each accepted trial left out: refitted from the full fit's optimum
// (multi-start still runs) and predicted.
void leave_each_out(const std::vector<TrialData>& trials, const FitOptions& options, std::atomic<long>* evals,
                    FitResult* res_ptr) {
  FitResult& res = *res_ptr;
  std::vector<const TrialData*> acc;
  for (const auto& t : trials)
    if (t.accepted) acc.push_back(&t);
  if (acc.size() < 2) {
    res.warnings.push_back("leave-one-trial-out needs at least two accepted trials");
  } else {
    for (const TrialData* held : acc) {
      std::vector<const TrialData*> tr;
      for (const TrialData* t : acc)
        if (t != held) tr.push_back(t);
      FitOptions o = options;
      o.initial = res.params;  // start near the full fit; multi-start still runs
      std::vector<std::string> w;
      FitCore c = fit_core(tr, o, evals, &w);
      LeaveOneOutEntry e;
      e.held_out = held->id;
      e.params = c.params;
      e.comparison = predict(*held, c.params, options).comparison;
      res.leave_one_out.push_back(e);
    }
  }
}

// The standard error of a trial's clock shift with the parameters held:
// the force residuals' derivative g with respect to the shift against
// their noise as it is, an AR(1) process fitted to the residuals at the
// optimum (variance s^2, lag-1 correlation phi; the slow structure of a
// misfit keeps phi near 1 and so widens the interval):
//   var = s^2 sum_l phi^|l| sum_i g_i g_(i+l) / (sum_i g_i^2)^2.
double conditional_shift_se(const Prepared& p, const std::vector<double>& grf, double shift) {
  using J1 = ceres::Jet<double, 1>;
  const size_t m = p.f_idx.size();
  std::vector<double> g(m), d(m);
  double gg = 0.0, rss = 0.0, lag1 = 0.0;
  for (size_t k = 0; k < m; ++k) {
    const int i = p.f_idx[k];
    const J1 f = on_grid(grf, J1(p.data->t_s[i]) - J1(shift, 0), p.h, 0.0);
    d[k] = (f.a - p.data->grf_n[i]) * p.f_w[k];
    g[k] = f.v[0] * p.f_w[k];
    rss += d[k] * d[k];
    gg += g[k] * g[k];
    if (k > 0) lag1 += d[k] * d[k - 1];
  }
  if (!(gg > 0.0) || m < 3) return kNaN;
  const double s2 = rss / static_cast<double>(m - 1);
  const double phi = rss > 0.0 ? std::clamp(lag1 / rss, -0.5, 0.98) : 0.0;
  double meat = gg, w = 1.0;
  for (size_t lag = 1; lag < m; ++lag) {
    w *= phi;
    if (std::abs(w) < 1e-4) break;
    double c = 0.0;
    for (size_t k = 0; k + lag < m; ++k) c += g[k] * g[k + lag];
    meat += 2.0 * w * c;
  }
  return std::sqrt(s2 * std::max(meat, 0.0)) / gg;
}

}  // namespace

// ---------------------------------------------------------------------------

TrialReport predict(const TrialData& trial, const MatParams& params, const FitOptions& options) {
  const Prepared p = prepare(trial, options, true);
  TrialReport rep;
  rep.id = trial.id;
  rep.impact_velocity_m_s = trial.impact_velocity_m_s;
  rep.window_end_s = p.window_end_s;
  const ParamSpace space = make_space(options, kNaN);
  const detail::Trace<double> s = simulate_window(p, space, options, params, nullptr);
  const double shift = profile_shift(p, s.grf);
  rep.contact_shift_s = shift;
  if (p.shifted()) rep.contact_shift_se_s = conditional_shift_se(p, s.grf, shift);

  // The simulation on the trial's own samples: force on the shifted clock,
  // travel on the video's (free fall before contact).
  const Eigen::Index n = trial.t_s.size();
  Simulation& sim = rep.simulation;
  sim.t_s = trial.t_s;
  sim.grf_n.resize(n);
  sim.impactor_m.resize(n);
  sim.surface_m.resize(n);
  sim.layer1_m.resize(n);
  sim.layer2_m.resize(n);
  const double v0 = trial.impact_velocity_m_s, g = trial.gravity_m_s2;
  // The force exactly on the shifted samples (one more simulation, so that
  // `dropfit simulate --first-output` reproduces the reported curve): from
  // the first sample at or after the fitted contact. A force-channel
  // low-pass keeps the grid's filtered values.
  Eigen::Index i_c = 0;
  while (i_c < n && trial.t_s[i_c] - shift < 0.0) ++i_c;
  Eigen::VectorXd exact_grf;
  if (i_c < n && !(options.force_lowpass_hz > 0.0)) {
    Impact imp = p.impact;
    imp.output_dt_s = p.dt;
    imp.first_output_s = std::clamp(trial.t_s[i_c] - shift, 0.0, p.dt * (1.0 - 1e-12));
    imp.duration_s = imp.first_output_s + static_cast<double>(n - 1 - i_c) * p.dt + 0.5 * p.dt;
    try {
      const Simulation ex = simulate_model(options, params, imp);
      // A simulator that samples elsewhere than asked keeps the grid's
      // interpolated values.
      const double tol = 1e-9 * p.dt + 1e-12;
      const bool on_samples = ex.t_s.size() == 0 || (std::abs(ex.t_s[0] - imp.first_output_s) < tol &&
                                                     (ex.t_s.size() < 2 || std::abs(ex.t_s[1] - ex.t_s[0] - p.dt) < 1e3 * tol));
      if (on_samples) exact_grf = ex.grf_n;
    } catch (const Error&) {
      exact_grf.resize(0);
    }
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    const double t = trial.t_s[i];
    const Eigen::Index k = i - i_c;
    sim.grf_n[i] = k >= 0 && k < exact_grf.size() ? exact_grf[k] : on_grid(s.grf, t - shift, p.h, 0.0);
    sim.impactor_m[i] = t < 0.0 ? v0 * t + 0.5 * g * t * t : on_grid(s.impactor, t, p.h, 0.0);
    sim.surface_m[i] = t < 0.0 ? 0.0 : on_grid(s.surface, t, p.h, 0.0);
    sim.layer1_m[i] = t < 0.0 ? 0.0 : on_grid(s.layer1, t, p.h, 0.0);
    sim.layer2_m[i] = t < 0.0 ? 0.0 : on_grid(s.layer2, t, p.h, 0.0);
  }

  // Force compared from the fitted contact on, over the window.
  std::vector<double> tv, fmv, fsv;
  for (int i : p.f_idx) {
    const double tc = trial.t_s[i] - shift;
    if (tc < 0.0) continue;
    tv.push_back(tc);
    fmv.push_back(trial.grf_n[i]);
    fsv.push_back(sim.grf_n[i]);
  }
  const Eigen::Index nw = static_cast<Eigen::Index>(tv.size());
  const Eigen::VectorXd t = Eigen::Map<Eigen::VectorXd>(tv.data(), nw);
  const Eigen::VectorXd fm = Eigen::Map<Eigen::VectorXd>(fmv.data(), nw);
  const Eigen::VectorXd fs = Eigen::Map<Eigen::VectorXd>(fsv.data(), nw);
  rep.comparison = compare_forces(t, fm, fs);
  if (nw >= 3) {
    rep.measured = characteristics(t, fm, options.characteristics);
    rep.simulated = characteristics(t, fs, options.characteristics);
  }
  if (!p.k_idx.empty()) {
    double mm = -1e300, ms = -1e300, ss = 0.0;
    for (int i : p.k_idx) {
      const double y = trial.impactor_m[i];
      mm = std::max(mm, y);
      const double d = sim.impactor_m[i] - y;
      ss += d * d;
    }
    for (Eigen::Index i = 0; i < n; ++i)
      if (trial.t_s[i] >= 0.0 && trial.t_s[i] <= p.window_end_s) ms = std::max(ms, sim.impactor_m[i]);
    rep.max_deformation_mm_diff = 1000.0 * (ms - mm);
    rep.rms_impactor_mm = 1000.0 * std::sqrt(ss / static_cast<double>(p.k_idx.size()));
  }
  return rep;
}

Eigen::VectorXd residuals(const std::vector<TrialData>& trials, const MatParams& params, const FitOptions& options) {
  check_options(options);
  const ParamSpace space = make_space(options, kNaN);
  std::vector<Prepared> preps;
  for (const auto& t : trials) preps.push_back(prepare(t, options));
  return residual_vector(preps, space, options, params, nullptr);
}

Eigen::MatrixXd residual_jacobian(const std::vector<TrialData>& trials, const MatParams& params,
                                  const FitOptions& options, std::vector<std::string>* names) {
  check_options(options);
  const ParamSpace space = make_space(options, kNaN);
  std::vector<Prepared> preps;
  for (const auto& t : trials) preps.push_back(prepare(t, options));
  std::vector<double> shifts;
  residual_vector(preps, space, options, params, nullptr, &shifts);
  Eigen::VectorXd u = space.from_mat(params);
  std::vector<double*> blocks;
  auto problem = make_problem(preps, space, options, u.data(), shifts, nullptr, &blocks);
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = {u.data()};
  double cost = 0.0;
  ceres::CRSMatrix crs;
  if (!problem->Evaluate(eo, &cost, nullptr, nullptr, &crs))
    throw Error("residual_jacobian: the model did not run at these parameters");
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
  for (int r = 0; r < crs.num_rows; ++r)
    for (int k = crs.rows[r]; k < crs.rows[r + 1]; ++k) J(r, crs.cols[k]) = crs.values[k];
  if (names) {
    names->clear();
    for (const auto& f : space.free) names->push_back(param_display(f));
  }
  return J;
}

FitResult fit(const std::vector<TrialData>& trials, const FitOptions& options) {
  const auto t_start = std::chrono::steady_clock::now();
  check_options(options);
  if (trials.empty()) throw Error("fit: no trials");
  FitResult res;
  res.model = options.model;
  const auto train = choose_train(trials, options.train_ids);
  for (const TrialData* t : train) res.train_ids.push_back(t->id);

  std::atomic<long> evals{0};
  FitCore fc = fit_core(train, options, &evals, &res.warnings);
  const Optimum& best = fc.search.best;
  res.params = fc.params;
  res.optimizer = fc.used;
  res.force_lowpass_hz = options.force_lowpass_hz;
  res.cost = best.cost;
  res.n_residuals = static_cast<int>(best.residuals.size());

  // Estimates (free parameters, then the fixed ones for completeness).
  for (const auto& f : fc.space.free) {
    ParameterEstimate e;
    e.name = param_display(f);
    e.value = f.transform == Transform::Fraction ? res.params.m1_kg : get_parameter(res.params, f.name);
    res.estimates.push_back(e);
  }
  std::vector<double> shift_se;
  // The error budget: each trial's channels as AR(1) noise, the inputs as
  // nuisance parameters with their priors (fit.h).
  const Nuisances nuisances =
      nuisance_columns(fc.preps, fc.space, options, res.params, best.shifts, best.residuals.size());
  const ErrorBudget budget = budget_at(fc.preps, best, nuisances);
  covariance(best, fc.space, options, res.params, budget, &res.estimates, &shift_se, &res.warnings);
  if (searches_identifiability(options)) refine_intervals(fc.preps, fc.space, options, fc.search, budget, &evals, &res);
  res.channels = channel_shares(fc.preps, best.residuals, &res.warnings);
  mark_model_limited(&res);
  add_fixed_estimates(options, &res);
  predict_trials(trials, options, fc, shift_se, &res);
  add_prediction_intervals(trials, fc.preps, fc.space, options, best.u, budget, nuisances, &res);

  if (options.sensitivity) {
    Impact imp = fc.preps.front().impact;
    imp.output_dt_s = fc.preps.front().dt;
    imp.duration_s = std::max(imp.duration_s, 0.3);
    res.sensitivity = sensitivity_table(options, res.params, imp);
  }

  if (options.leave_one_out) leave_each_out(trials, options, &evals, &res);
  res.evaluations = evals.load();
  res.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return res;
}

std::string FitResult::report() const {
  std::ostringstream os;
  os << fmt::format("{} fitted to {} by {}: cost {:.6g} over {} residuals, {} simulations, {:.2f} s\n",
                    model_name(model), fmt::join(train_ids, ", "), optimizer, cost, n_residuals, evaluations, seconds);
  os << "parameters:\n";
  for (const auto& e : estimates) {
    std::string what = "(fixed)";
    if (e.free && !std::isfinite(e.rel_se)) {
      what = "SE n/a  NOT IDENTIFIED";
    } else if (e.free) {
      what = fmt::format("SE {:.3g} ({:.2g} %)", e.se, 100.0 * e.rel_se);
      if (std::isfinite(e.ci_low)) what += fmt::format("  95 % [{:.4g}, {:.4g}] ({})", e.ci_low, e.ci_high, e.interval);
      if (!e.identifiable) what += "  NOT IDENTIFIED" + (e.note.empty() ? "" : ": " + e.note);
      if (e.model_limited) what += "  model-limited";
    }
    os << fmt::format("  {:<16} {:>12.6g}  {}\n", e.name, e.value, what);
  }
  os << "trials (rms % peak, peak % diff, time to peak ms diff, max deformation mm diff):\n";
  for (const auto& t : trials)
    os << fmt::format("  {:<10} v {:.2f} m/s{} {:7.2f} {:+7.2f} {:+6.1f} {:+6.1f}\n", t.id, t.impact_velocity_m_s,
                      t.train ? " (train)" : "        ", t.comparison.rms_force_pct_peak,
                      t.comparison.peak_force_pct_diff, t.comparison.time_to_peak_ms_diff, t.max_deformation_mm_diff);
  os << "predicted, with 95 % intervals (peak force N, time to peak ms, max deformation mm):\n";
  for (const auto& t : trials) {
    const Prediction& p = t.prediction;
    if (!std::isfinite(p.peak_force_n.se)) continue;
    os << fmt::format("  {:<10} {:.0f} [{:.0f}, {:.0f}]  {:.2f} [{:.2f}, {:.2f}]  {:.1f} [{:.1f}, {:.1f}]\n", t.id,
                      p.peak_force_n.value, p.peak_force_n.low, p.peak_force_n.high, 1e3 * p.time_to_peak_s.value,
                      1e3 * p.time_to_peak_s.low, 1e3 * p.time_to_peak_s.high, 1e3 * p.max_deformation_m.value,
                      1e3 * p.max_deformation_m.low, 1e3 * p.max_deformation_m.high);
  }
  if (!sensitivity.empty()) {
    os << "sensitivity of peak force to -10 % / +10 %:\n";
    for (const auto& s : sensitivity)
      os << fmt::format("  {:<10} {:+6.2f} % / {:+6.2f} %\n", s.name, s.peak_pct_minus10, s.peak_pct_plus10);
  }
  if (!leave_one_out.empty()) {
    os << "leave-one-trial-out (peak % diff of the held-out trial):\n";
    for (const auto& l : leave_one_out)
      os << fmt::format("  {:<10} {:+7.2f} %  rms {:.2f} % peak\n", l.held_out, l.comparison.peak_force_pct_diff,
                        l.comparison.rms_force_pct_peak);
  }
  if (!channels.empty()) {
    os << "channels at the optimum (share of cost, RMS in noise SDs, lag-1 autocorrelation):\n";
    for (const auto& c : channels)
      os << fmt::format("  {:<10} {:5.1f} %  {:6.2f}  {:+.2f}{}\n", c.name, 100.0 * c.share, c.rms_sigma,
                        c.lag1_autocorrelation, c.structured ? "  structured" : "");
  }
  for (const auto& t : trials)
    if (std::isfinite(t.contact_shift_se_s))
      os << fmt::format("  {:<10} contact {:+.3f} ms from its estimate (SE {:.3f} ms)\n", t.id, 1e3 * t.contact_shift_s,
                        1e3 * t.contact_shift_se_s);
  for (const auto& w : warnings) os << "warning: " << w << "\n";
  return os.str();
}

}  // namespace dropfit::fitting
