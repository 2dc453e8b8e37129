// The mat stage of the loop: which effect the fitted mat model lacks, judged
// on what the instruments measure (see diagnosis.h).
//
// Forward selection over the library, each candidate REFITTED (multi-start,
// the fitter's own objective: plate force and impactor travel, each over its
// measured noise, clock shifts fitted), then judged on the held-out trials:
//   - the residual is worth explaining only while a held-out channel's RMS
//     stands above the noise floor (gate_noise_sd noise SDs);
//   - a candidate is kept when it brings a structured channel's held-out
//     error down by at least min_relative (paired over the held-out trials,
//     t_critical), leaves the other channel no worse than noise allows, and
//     the information criterion on the training residuals (AR(1) effective
//     N) supports the extra parameters;
//   - of the candidates that pass, the one with the lowest held-out error is
//     added, and the search repeats from it.
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>

#include "core/error.h"
#include "core/parallel.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/model_choice.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

using fitting::MatParams;

// One library candidate: the results-format name, what it frees, how its
// refit starts, and how its estimate is described.
struct EffectCandidate {
  std::string name;     // results-format effect name
  std::string variant;  // what exactly (for the evidence)
  std::vector<std::string> free;
  bool masses = false;
};

std::vector<EffectCandidate> library(const std::vector<std::string>& wanted) {
  const std::vector<EffectCandidate> all{
      {"stiffness_nonlinearity", "cubic stiffening of the top element (k1_cubic x^3)", {"k1_cubic_n_m3"}, false},
      {"hysteresis", "lower elastic force while unloading (k1_unload_ratio)", {"k1_unload_ratio"}, false},
      {"hysteresis", "higher damping while unloading (r1_unload_n_s_m)", {"r1_unload_n_s_m"}, false},
      {"rate_dependence", "a Maxwell arm beside the top element (maxwell_k_n_m, maxwell_tau_s)",
       {"maxwell_k_n_m", "maxwell_tau_s"}, false},
      {"layer_mass", "the layer masses redistributed (total fixed)", {}, true},
  };
  std::vector<EffectCandidate> out;
  for (const auto& c : all)
    if (std::find(wanted.begin(), wanted.end(), c.name) != wanted.end()) out.push_back(c);
  return out;
}

// Starting values of an effect's parameters for its refit (its own multi-
// start covers the rest): small but not zero, so the derivative is alive.
void seed_effect(MatParams& p, const EffectCandidate& c) {
  for (const auto& f : c.free) {
    // Only where absent: a start that already holds the effect keeps it.
    if (f == "k1_cubic_n_m3" && p.k1_cubic_n_m3 == 0.0) p.k1_cubic_n_m3 = 1e5;
    if (f == "k1_unload_ratio" && p.k1_unload_ratio == 0.0) p.k1_unload_ratio = 0.05;
    if (f == "r1_unload_n_s_m" && p.r1_unload_n_s_m < 0.0) p.r1_unload_n_s_m = std::max(p.r1_n_s_m, 10.0);
    if (f == "maxwell_k_n_m" && p.maxwell_k_n_m <= 0.0) p.maxwell_k_n_m = std::max(0.2 * p.k1_n_m, 1e3);
    if (f == "maxwell_tau_s" && p.maxwell_tau_s <= 0.0) p.maxwell_tau_s = 0.02;
  }
}

// The held-out error of a fit, per channel, per held-out trial.
struct HeldOutErrors {
  std::vector<std::string> ids;
  Eigen::VectorXd force_sd, impactor_sd;  // RMS over the window in noise SDs
  Eigen::VectorXd force_pct_peak, impactor_mm, peak_pct;
  std::vector<Eigen::VectorXd> force_residual_n;  // for the periodogram
  double dt_s = 1e-3;
  double mean_force_sd() const { return force_sd.size() ? std::sqrt(force_sd.squaredNorm() / force_sd.size()) : 0.0; }
  double mean_impactor_sd() const {
    return impactor_sd.size() ? std::sqrt(impactor_sd.squaredNorm() / impactor_sd.size()) : 0.0;
  }
  double combined() const { return mean_force_sd() * mean_force_sd() + mean_impactor_sd() * mean_impactor_sd(); }
};

double noise_of(double measured, double fallback, double floor) {
  return std::max(std::isfinite(measured) ? measured : fallback, floor);
}

// Per held-out trial (train = false in `reports`), both channels over the
// trials' measured noise (`o`'s fallbacks and floors).
HeldOutErrors held_out_errors(const std::vector<fitting::TrialReport>& reports,
                              const std::vector<fitting::TrialData>& trials, const fitting::FitOptions& o) {
  HeldOutErrors e;
  std::vector<double> f, k, fp, km, pk;
  for (const auto& rep : reports) {
    if (rep.train) continue;
    const auto it = std::find_if(trials.begin(), trials.end(), [&](const auto& t) { return t.id == rep.id; });
    if (it == trials.end() || !it->accepted) continue;
    const fitting::TrialData& tr = *it;
    const double sf = noise_of(tr.force_noise_n, o.force_noise_n, o.min_force_noise_n);
    const double sk = noise_of(tr.marker_noise_m, o.marker_noise_m, o.min_marker_noise_m);
    double ss = 0.0;
    int n = 0;
    std::vector<double> res;
    for (Eigen::Index i = 0; i < tr.t_s.size() && i < rep.simulation.grf_n.size(); ++i) {
      const double t = tr.t_s[i] - rep.contact_shift_s;
      if (t < 0.0 || t > rep.window_end_s || !std::isfinite(tr.grf_n[i])) continue;
      const double d = tr.grf_n[i] - rep.simulation.grf_n[i];
      ss += d * d;
      ++n;
      res.push_back(d);
    }
    if (n < 8) continue;
    e.ids.push_back(rep.id);
    f.push_back(std::sqrt(ss / n) / sf);
    fp.push_back(rep.comparison.rms_force_pct_peak);
    pk.push_back(std::abs(rep.comparison.peak_force_pct_diff));
    const double km_mm = std::isfinite(rep.rms_impactor_mm) ? rep.rms_impactor_mm : 0.0;
    km.push_back(km_mm);
    k.push_back(km_mm * 1e-3 / sk);
    e.force_residual_n.push_back(detail::to_vector(res));
    if (tr.t_s.size() > 1) e.dt_s = tr.t_s[1] - tr.t_s[0];
  }
  e.force_sd = detail::to_vector(f);
  e.impactor_sd = detail::to_vector(k);
  e.force_pct_peak = detail::to_vector(fp);
  e.impactor_mm = detail::to_vector(km);
  e.peak_pct = detail::to_vector(pk);
  return e;
}

HeldOutErrors held_out_errors(const fitting::FitResult& fit, const std::vector<fitting::TrialData>& trials,
                              const fitting::FitOptions& o) {
  return held_out_errors(fit.trials, trials, o);
}

ErrorSet error_set(const HeldOutErrors& e) {
  auto mean = [](const Eigen::VectorXd& v) { return v.size() ? v.mean() : kNaN; };
  return {{"heldout_force_rms_noise_sd", e.mean_force_sd()},
          {"heldout_impactor_rms_noise_sd", e.mean_impactor_sd()},
          {"rms_force_pct_peak", mean(e.force_pct_peak)},
          {"heldout_rms_force_pct_peak", mean(e.force_pct_peak)},
          {"heldout_impactor_rms_mm", mean(e.impactor_mm)},
          {"heldout_peak_force_pct_max", e.peak_pct.size() ? e.peak_pct.maxCoeff() : kNaN}};
}

// Training residual sum of squares and lag-1 autocorrelation (noise units).
struct TrainingFit {
  double rss = 0.0, n = 0.0, rho1 = 0.0;
  int k = 0;
};

TrainingFit training_of(const fitting::FitResult& fit) {
  TrainingFit t;
  t.rss = 2.0 * fit.cost;
  t.n = fit.n_residuals;
  for (const auto& e : fit.estimates) t.k += e.free ? 1 : 0;
  double num = 0.0, den = 0.0;
  for (const auto& c : fit.channels) {
    num += c.lag1_autocorrelation * c.n;
    den += c.n;
  }
  t.rho1 = den > 0.0 ? num / den : 0.0;
  return t;
}

// A refit: one or two library candidates added to the current model.
struct Trial {
  std::vector<const EffectCandidate*> adds;
  fitting::FitOptions options;
  std::optional<fitting::FitResult> fit;
  HeldOutErrors errors;
  std::string failure;
  std::string names() const {
    std::string s;
    for (const auto* c : adds) s += (s.empty() ? "" : " + ") + c->name;
    return s;
  }
  std::string variants() const {
    std::string s;
    for (const auto* c : adds) s += (s.empty() ? "" : "; ") + c->variant;
    return s;
  }
};

// The current model with `adds` freed, started from the current optimum
// (the effects seeded small) plus `starts` screened starts.
Trial make_trial(const fitting::FitOptions& current_options, const fitting::FitResult& current,
                 std::vector<const EffectCandidate*> adds, int starts) {
  Trial t;
  t.adds = std::move(adds);
  t.options = current_options;
  for (const auto* c : t.adds) {
    for (const auto& f : c->free) t.options.free_effects.push_back(f);
    if (c->masses) t.options.masses_free = true;
  }
  // The fitter's own full multi-start (see MatStageOptions::refit_starts),
  // plus the current optimum with the new terms seeded small, run to
  // convergence beside it without cutting the others (protect_initial).
  t.options.initial = current.params;
  for (const auto* c : t.adds) seed_effect(t.options.initial, *c);
  t.options.protect_initial = true;
  if (starts > 0) {
    t.options.protect_initial = false;
    t.options.starts = starts;
    t.options.every_ordering = false;  // near the current optimum: its ordering and the best screened starts
  }
  // Two threads each, although two refits run at once: when the last one
  // runs alone, its starts take the idle core (seed 800 s018, five
  // repeats: 1.77-1.89 s against 1.85-1.99 s with one; the same results).
  t.options.threads = 2;
  t.options.train_ids = current.train_ids;
  return t;
}

// Refits every trial, `threads` at a time (each fit on up to two threads).
void run_trials(const std::vector<fitting::TrialData>& acc, std::vector<Trial>& tries, int threads) {
  // Longest first, so that the last refit to start is a short one: those
  // that free the layer masses (a light top layer shortens every step: 0.85
  // s against 0.15-0.4 s for the others on a five-effect session), then by
  // the number of parameters freed.
  std::vector<size_t> order(tries.size());
  std::iota(order.begin(), order.end(), size_t{0});
  auto weight = [&](size_t i) {
    return std::make_pair(tries[i].options.masses_free, tries[i].options.free_effects.size());
  };
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) { return weight(a) > weight(b); });
  parallel_for(tries.size(), threads, [&](size_t j) {
    Trial& t = tries[order[j]];
    try {
      t.fit = fitting::fit(acc, t.options);
      t.errors = held_out_errors(*t.fit, acc, t.options);
    } catch (const std::exception& e) {
      t.failure = e.what();
    }
  });
}

// Per held-out trial, both channels in one number: sqrt(force^2 + travel^2)
// in noise SDs (what a pair is judged on against its members).
Eigen::VectorXd combined_per_trial(const HeldOutErrors& e) {
  if (e.force_sd.size() != e.impactor_sd.size()) return e.force_sd;
  return (e.force_sd.array().square() + e.impactor_sd.array().square()).sqrt();
}

std::string fmt_value(double v) { return fmt::format("{:.4g}", v); }

// The estimate of a kept effect with its standard error.
ErrorSet estimate_of(const fitting::FitResult& fit, const EffectCandidate& c) {
  ErrorSet out;
  std::vector<std::string> names = c.free;
  if (c.masses) names = {"m1_kg", "m2_kg"};
  for (const auto& n : names)
    for (const auto& e : fit.estimates)
      if (e.name == n) {
        out.emplace_back(n, e.value);
        out.emplace_back(n + "_se", e.se);
      }
  return out;
}

std::string estimate_text(const fitting::FitResult& fit, const EffectCandidate& c) {
  std::string s;
  std::vector<std::string> names = c.free;
  if (c.masses) names = {"m1_kg", "m2_kg"};
  for (const auto& n : names)
    for (const auto& e : fit.estimates)
      if (e.name == n)
        s += fmt::format("{}{} = {} (SE {})", s.empty() ? "" : ", ", n, fmt_value(e.value), fmt_value(e.se));
  return s;
}

// The verdict on a refit against the current model (held-out errors
// `before`, training fit `small`): empty when it passes.
std::string verdict(const Trial& t, const HeldOutErrors& before, const TrainingFit& small,
                    const MatStageOptions& options, double declared_m1_kg) {
  const double gate = options.gate_noise_sd;
  if (!t.fit) return "refit failed: " + t.failure;
  const HeldOutErrors& a = t.errors;
  const double f0 = before.mean_force_sd(), k0 = before.mean_impactor_sd();
  const double f1 = a.mean_force_sd(), k1 = a.mean_impactor_sd();
  // Paired over the held-out trials, on the channel(s) above the noise.
  // A candidate that at least halves a channel's held-out error (paired,
  // beyond t_critical) is kept whatever the information criterion says:
  // the criterion counts training residuals, whose structure shrinks the
  // effective N until no extra term can pass, while the held-out trials
  // are the test the criterion only approximates.
  bool falls = false, worse = false, halves = false;
  for (int ch = 0; ch < 2; ++ch) {
    const Eigen::VectorXd& b = ch == 0 ? before.force_sd : before.impactor_sd;
    const Eigen::VectorXd& af = ch == 0 ? a.force_sd : a.impactor_sd;
    const double e0 = ch == 0 ? f0 : k0, e1 = ch == 0 ? f1 : k1;
    if (b.size() != af.size()) continue;
    if (e0 > gate) {
      const PairedImprovement pi =
          paired_improvement(b, af, options.decision.t_critical, options.decision.min_relative, 0.0);
      if (pi.significant) falls = true;
      if (paired_improvement(b, af, options.decision.t_critical, 0.5, 0.0).significant) halves = true;
    }
    if (e1 > std::max(gate, e0 * (1.0 + options.decision.min_relative))) worse = true;
  }
  const TrainingFit large = training_of(*t.fit);
  const ModelComparison mc = compare_models(small.rss, small.k, large.rss, large.k, large.n, large.rho1,
                                            options.criterion, options.decision.ic_min_drop);
  const std::string numbers = fmt::format(
      "held-out force {:.2f} -> {:.2f} noise SDs, impactor travel {:.2f} -> {:.2f} noise SDs; {} change {:+.1f} "
      "on N_eff = {:.0f}",
      f0, f1, k0, k1, criterion_name(options.criterion), mc.delta, mc.n_eff);
  // Wald: the layer masses must stand beyond wald_sd SE from the declared
  // split (the other effects' SEs, scaled by a residual the candidate may
  // only partly explain, are not a test).
  std::string wald;
  for (const auto* c : t.adds) {
    if (!c->masses) continue;
    for (const auto& e : t.fit->estimates) {
      if (e.name != "m1_kg") continue;
      if (!(std::abs(e.value - declared_m1_kg) > options.wald_sd * e.se))
        wald = fmt::format("{} = {} is within {} SE ({}) of {} (absent)", e.name, fmt_value(e.value),
                           options.wald_sd, fmt_value(e.se), fmt_value(declared_m1_kg));
    }
  }
  // The effect's own parameters must be set by the data, not by the box;
  // and a Maxwell arm relaxing within two plate samples cannot be told
  // from element 1's own damping (it acts as a dashpot of k tau).
  std::string own;
  for (const auto* c : t.adds)
    for (const auto& e : t.fit->estimates) {
      if (std::find(c->free.begin(), c->free.end(), e.name) == c->free.end()) continue;
      if (e.at_bound) own = fmt::format("{} = {} sits at its bound: the box, not the data, sets it", e.name,
                                      fmt_value(e.value));
      if (e.name == "maxwell_tau_s" && e.value < 2.0 * a.dt_s)
        own = fmt::format("maxwell_tau_s = {} ms relaxes within two plate samples ({} ms): a dashpot, not a "
                          "separate rate dependence",
                          fmt_value(1e3 * e.value), fmt_value(2e3 * a.dt_s));
    }
  if (!falls) return "held-out error does not fall beyond noise (" + numbers + ")";
  if (!own.empty()) return own;
  if (!wald.empty()) return wald;
  if (worse) return "the other channel gets worse (" + numbers + ")";
  if (!mc.larger_supported && !halves) return "not supported by the information criterion (" + numbers + ")";
  return "";
}

// No single effect passes: two effects present together can each move
// one channel the wrong way on its own (a lower unloading stiffness
// shortens the rebound the Maxwell arm lengthens). Pairs are tried with
// the singles that brought the most down, and a pair is kept only when
// it passes the same test and beats each of its members alone. Each pair
// starts from its lead's optimum (the lead's own full refit searched every
// basin) with the partner's term seeded small, plus the best screened
// starts (MatStageOptions::pair_starts); the pair kept is refitted with the
// full multi-start before the next round builds on it (diagnose_mat).
// Returns the index of the best passing pair in `pairs`, or -1.
int refit_pairs(const std::vector<fitting::TrialData>& acc, const std::vector<EffectCandidate>& cands,
                const std::vector<bool>& used, const std::vector<Trial>& tries, const HeldOutErrors& before,
                const TrainingFit& small, const fitting::FitOptions& current_options,
                const fitting::FitResult& current, const MatStageOptions& options, double declared_m1_kg,
                std::vector<Trial>& pairs, std::vector<Rejected>& rejected) {
  int best = -1;
  std::vector<size_t> order;
  for (size_t i = 0; i < tries.size(); ++i)
    if (tries[i].fit && tries[i].errors.combined() < before.combined()) order.push_back(i);
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b) { return tries[a].errors.combined() < tries[b].errors.combined(); });
  if (order.size() > static_cast<size_t>(options.pairs)) order.resize(options.pairs);
  std::vector<std::pair<const EffectCandidate*, const EffectCandidate*>> seen;
  for (size_t lead : order) {
    const EffectCandidate* a = tries[lead].adds.front();
    for (size_t c = 0; c < cands.size(); ++c) {
      const EffectCandidate* b = &cands[c];
      if (used[c] || b->name == a->name) continue;
      const bool dup = std::any_of(seen.begin(), seen.end(), [&](const auto& p) {
        return (p.first == a && p.second == b) || (p.first == b && p.second == a);
      });
      if (dup) continue;
      seen.emplace_back(a, b);
      pairs.push_back(make_trial(current_options, tries[lead].fit ? *tries[lead].fit : current, {a, b},
                                 options.pair_starts));
    }
  }
  run_trials(acc, pairs, options.threads);
  for (size_t i = 0; i < pairs.size(); ++i) {
    Trial& t = pairs[i];
    std::string why = verdict(t, before, small, options, declared_m1_kg);
    if (why.empty()) {
      // Each member must matter: the pair against each member alone.
      for (const auto* m : t.adds) {
        const auto it = std::find_if(tries.begin(), tries.end(),
                                     [&](const Trial& s) { return s.adds.front() == m; });
        if (it == tries.end() || !it->fit) continue;
        const Eigen::VectorXd alone = combined_per_trial(it->errors), both = combined_per_trial(t.errors);
        if (alone.size() != both.size()) continue;
        const PairedImprovement pi =
            paired_improvement(alone, both, options.decision.t_critical, options.decision.min_relative, 0.0);
        if (!pi.significant)
          why = fmt::format("no better than {} alone (held-out {:.2f} -> {:.2f} noise SDs)", m->name,
                            pi.mean_before, pi.mean_after);
      }
    }
    if (!why.empty()) {
      rejected.push_back({"mat", t.names(), "together: " + t.variants() + ": " + why});
      continue;
    }
    if (best < 0 || t.errors.combined() < pairs[best].errors.combined()) best = static_cast<int>(i);
  }
  return best;
}

// The kept model refitted with the fitter's full multi-start (every spring
// ordering) after a screened refit; taken where it fits better. A single's
// screened refit started near a model that lacked the effect, and the full
// one is not warm-started (a start already near the screened optimum cuts
// the other basins' runs after the fitter's first stage); a pair's started
// at its lead's optimum, and the full one keeps that start, run to
// convergence beside the others (protect_initial), as a pair refitted in
// full from the first would be, and is taken at an equal cost too.
void refit_in_full(const std::vector<fitting::TrialData>& acc, const fitting::FitOptions& base,
                   const MatStageOptions& options, bool pair, Trial& kept, MatDiagnosis& out) {
  fitting::FitOptions full = kept.options;
  if (pair) {
    full.protect_initial = true;
  } else {
    full.initial = MatParams{};
  }
  full.starts = base.starts;
  full.every_ordering = base.every_ordering;
  full.threads = std::max(1, options.threads);
  try {
    fitting::FitResult polished = fitting::fit(acc, full);
    if (polished.cost < kept.fit->cost || (pair && polished.cost <= kept.fit->cost)) {
      kept.errors = held_out_errors(polished, acc, full);
      kept.fit = std::move(polished);
    }
  } catch (const std::exception& e) {
    out.notes.push_back(std::string("mat: the multi-start refit of the kept model failed (") + e.what() +
                        "); the screened refit is kept");
  }
}

// Structure left beyond the noise after the library: unexplained, with its
// frequency (the period the held-out trials share: one contact is too
// short to place a period within its 16-18 Hz bins).
void add_remaining(MatDiagnosis& out, const HeldOutErrors& before, const MatStageOptions& options) {
  const double f_end = before.mean_force_sd(), k_end = before.mean_impactor_sd();
  if (f_end > options.unexplained_noise_sd || k_end > options.unexplained_noise_sd) {
    const PeriodicPeak peak =
        common_periodic_peak(before.force_residual_n, before.dt_s, options.decision.alpha, 5.0);
    Remaining r;
    r.stage = "mat";
    r.name = peak.significant ? "periodic_oscillation" : "unexplained_structure";
    r.description = fmt::format(
        "held-out residual stays above the noise (force {:.2f}, impactor travel {:.2f} noise SDs) after the "
        "library's effects{}",
        f_end, k_end,
        peak.significant ? fmt::format("; its strongest period is {:.1f} Hz ({:.0f} % of the force residual's variance)",
                                       peak.frequency_hz, 100.0 * peak.share)
                         : "");
    if (peak.significant) r.frequency_hz = peak.frequency_hz;
    out.remaining.push_back(r);
  }
}

// The kept refit's effects into the result; their other variants marked used.
void name_effects(MatDiagnosis& out, const Trial& kept, const HeldOutErrors& before,
                  const std::vector<EffectCandidate>& cands, std::vector<bool>& used) {
  for (const auto* c : kept.adds) {
    Effect eff;
    eff.stage = "mat";
    eff.name = c->name;
    eff.error_before = error_set(before);
    eff.error_after = error_set(kept.errors);
    eff.estimate = estimate_of(*kept.fit, *c);
    eff.evidence = fmt::format(
        "{}: {}{}; held-out force RMS {:.2f} -> {:.2f} noise SDs ({:.2f} -> {:.2f} % of peak), impactor travel "
        "{:.2f} -> {:.2f} noise SDs ({:.2f} -> {:.2f} mm) over {} held-out trials",
        c->variant, estimate_text(*kept.fit, *c),
        kept.adds.size() > 1 ? "; added together with " + kept.names() + " (neither passes alone)" : "",
        before.mean_force_sd(), kept.errors.mean_force_sd(), before.force_pct_peak.mean(),
        kept.errors.force_pct_peak.mean(), before.mean_impactor_sd(), kept.errors.mean_impactor_sd(),
        before.impactor_mm.mean(), kept.errors.impactor_mm.mean(), kept.errors.ids.size());
    out.effects.push_back(eff);
    // The other variants of a kept name are done with; later rounds
    // re-judge what remains.
    for (size_t c2 = 0; c2 < cands.size(); ++c2)
      if (&cands[c2] == c || cands[c2].name == c->name) used[c2] = true;
  }
}

// One Levenberg-Marquardt run of `model` from `start` alone (no multi-
// start), on one thread; empty when the fit fails. What the loop's two
// nested-model checks below refit with.
std::optional<fitting::FitResult> warm_refit(const std::vector<fitting::TrialData>& acc,
                                             const fitting::FitOptions& model, const MatParams& start) {
  fitting::FitOptions o = model;
  o.initial = start;
  o.starts = 1;
  o.protect_initial = false;
  o.threads = 1;
  try {
    return fitting::fit(acc, o);
  } catch (const std::exception&) {
    return std::nullopt;
  }
}

// The current model refitted from a candidate's optimum with the
// candidate's own terms taken out (one Levenberg-Marquardt run). When the
// effect-free model fits better from there than from its own multi-start,
// the candidate's gain was the basin, not the effect: returns that fit.
std::optional<fitting::FitResult> better_baseline(const std::vector<fitting::TrialData>& acc,
                                                  const fitting::FitOptions& current_options,
                                                  const fitting::FitResult& current, const std::vector<Trial>& tries,
                                                  int threads) {
  // The refits first, `threads` at a time (each on one thread); then the
  // same choice in the candidates' order as when they ran one by one.
  std::vector<std::optional<fitting::FitResult>> refits(tries.size());
  parallel_for(tries.size(), threads, [&](size_t i) {
    const Trial& t = tries[i];
    if (!t.fit) return;
    MatParams p = t.fit->params;
    // Back to the current model's own effects and masses.
    const MatParams& c = current.params;
    p.k1_cubic_n_m3 = c.k1_cubic_n_m3;
    p.r1_unload_n_s_m = c.r1_unload_n_s_m;
    p.maxwell_k_n_m = c.maxwell_k_n_m;
    p.maxwell_tau_s = c.maxwell_tau_s;
    p.k1_unload_ratio = c.k1_unload_ratio;
    p.m1_kg = c.m1_kg;
    p.m2_kg = c.m2_kg;
    refits[i] = warm_refit(acc, current_options, p);  // catches inside
  });
  std::optional<fitting::FitResult> best;
  for (auto& r : refits) {
    // Beyond chance: twice the cost drop (noise units) above chi-square(1)'s 95 % point.
    const double ref = best ? best->cost : current.cost;
    if (r && 2.0 * (ref - r->cost) > 3.84) best = std::move(r);
  }
  return best;
}

// The backward step of the selection: with two or more effects named, an
// earlier one that later ones made redundant is taken out again. Each is
// judged as if it were added to the model without it (the same verdict as
// a candidate). The model without it is refitted from the current optimum
// with its term removed (one Levenberg-Marquardt run: conservative, since a
// poorer local optimum keeps the effect). An unloading damping that stood
// in for stiffening and a Maxwell arm, before the pair that explains both
// was found, was left named.
void drop_redundant(const std::vector<fitting::TrialData>& acc, std::vector<const EffectCandidate*>& named,
                    fitting::FitResult& current, fitting::FitOptions& current_options, HeldOutErrors& before,
                    const MatStageOptions& options, double declared_m1_kg, MatDiagnosis& out) {
  if (named.size() < 2) return;
  for (size_t i = 0; i < named.size() && named.size() >= 2;) {
    const EffectCandidate* c = named[i];
    fitting::FitOptions o = current_options;
    std::vector<std::string> keep;
    for (const auto& f : o.free_effects)
      if (std::find(c->free.begin(), c->free.end(), f) == c->free.end()) keep.push_back(f);
    o.free_effects = keep;
    MatParams p = current.params;
    for (const auto& f : c->free) {
      if (f == "k1_cubic_n_m3") p.k1_cubic_n_m3 = 0.0;
      if (f == "r1_unload_n_s_m") p.r1_unload_n_s_m = -1.0;
      if (f == "k1_unload_ratio") p.k1_unload_ratio = 0.0;
      if (f == "maxwell_k_n_m" || f == "maxwell_tau_s") p.maxwell_k_n_m = p.maxwell_tau_s = 0.0;
    }
    if (c->masses) {
      o.masses_free = false;
      p.m1_kg = o.m1_kg;
      p.m2_kg = o.m2_kg;
    }
    std::optional<fitting::FitResult> without = warm_refit(acc, o, p);
    if (!without) { ++i; continue; }
    const HeldOutErrors e_without = held_out_errors(*without, acc, o);
    Trial t;
    t.adds = {c};
    t.fit = current;
    t.errors = before;
    const std::string why = verdict(t, e_without, training_of(*without), options, declared_m1_kg);
    if (why.empty()) { ++i; continue; }
    // Not supported beside the others: out.
    const auto it = std::find_if(out.effects.begin(), out.effects.end(),
                                 [&](const Effect& e) { return e.stage == "mat" && e.name == c->name; });
    if (it != out.effects.end()) out.effects.erase(it);
    out.rejected.push_back({"mat", c->name,
                            c->variant + ": named in an earlier round, then made redundant by the later effects; "
                                         "added back to the model without it: " + why});
    current = std::move(*without);
    current_options = o;  // the model without it, its search options as before
    before = e_without;
    named.erase(named.begin() + static_cast<std::ptrdiff_t>(i));
  }
}

}  // namespace

MatDiagnosis diagnose_mat(const std::vector<fitting::TrialData>& trials, const MatStageOptions& options) {
  MatDiagnosis out;
  std::vector<fitting::TrialData> acc;
  for (const auto& t : trials)
    if (t.accepted) acc.push_back(t);
  if (acc.size() < 2) {
    out.notes.push_back("mat: needs at least two accepted trials (one to train, one held out); not assessed");
    return out;
  }
  fitting::FitOptions base = options.fit;
  base.sensitivity = false;
  base.leave_one_out = false;
  if (options.held_out == HeldOut::LeaveOneOut)
    out.notes.push_back("mat: held-out errors from the trials not trained on (train on one, predict the others)");

  fitting::FitResult current = options.baseline ? *options.baseline : fitting::fit(acc, base);
  fitting::FitOptions current_options = base;
  HeldOutErrors before = held_out_errors(current, acc, base);
  if (before.ids.empty()) {
    out.notes.push_back("mat: no held-out trial with a usable window; not assessed");
    return out;
  }
  out.params_before = current.params;
  out.error_before = error_set(before);
  const double gate = options.gate_noise_sd;
  const auto cands = library(options.candidates);
  std::vector<bool> used(cands.size(), false);

  std::vector<const EffectCandidate*> named;  // the candidates behind out.effects, in order
  for (int round = 0; round < options.max_effects; ++round) {
    const double f0 = before.mean_force_sd(), k0 = before.mean_impactor_sd();
    if (f0 <= gate && k0 <= gate) break;  // at the noise floor: nothing left to explain

    // Refit every candidate not yet added.
    std::vector<Trial> tries;
    for (size_t c = 0; c < cands.size(); ++c)
      if (!used[c]) tries.push_back(make_trial(current_options, current, {&cands[c]}, options.refit_starts));
    run_trials(acc, tries, options.threads);

    // A candidate that reached a basin the current model's own search
    // missed: the current model moves there, and the candidates are judged
    // against it (their refits are the same: each is its own multi-start).
    if (auto better = better_baseline(acc, current_options, current, tries, options.threads)) {
      out.notes.push_back(fmt::format(
          "mat: the model without the candidate's term, refitted from a candidate's optimum, fits better than its "
          "own multi-start did (cost {:.1f} -> {:.1f}): it replaces the {} the candidates are judged against",
          current.cost, better->cost, out.effects.empty() ? "baseline" : "current model"));
      current = std::move(*better);
      before = held_out_errors(current, acc, base);
      if (out.effects.empty()) {
        out.params_before = current.params;
        out.error_before = error_set(before);
      }
    }

    const TrainingFit small = training_of(current);
    int best = -1;
    for (size_t i = 0; i < tries.size(); ++i) {
      const std::string why = verdict(tries[i], before, small, options, base.m1_kg);
      if (!why.empty()) {
        out.rejected.push_back({"mat", tries[i].names(), tries[i].variants() + ": " + why});
        continue;
      }
      if (best < 0 || tries[i].errors.combined() < tries[best].errors.combined()) best = static_cast<int>(i);
    }

    // No single effect passes: pairs (refit_pairs).
    std::vector<Trial> pairs;
    if (best < 0 && options.pairs > 0)
      best = refit_pairs(acc, cands, used, tries, before, small, current_options, current, options, base.m1_kg, pairs,
                         out.rejected);
    if (best < 0) break;
    Trial& kept = pairs.empty() ? tries[best] : pairs[best];

    // The kept model from the fitter's full multi-start when the refit
    // above was a screened one: the next round builds on this optimum.
    const bool pair_screened = !pairs.empty() && options.pair_starts > 0;
    if (options.refit_starts > 0 || pair_screened) refit_in_full(acc, base, options, pair_screened, kept, out);

    name_effects(out, kept, before, cands, used);
    for (const auto* c : kept.adds) named.push_back(c);
    current = std::move(*kept.fit);
    current_options = kept.options;
    current_options.initial = MatParams{};
    current_options.starts = base.starts;
    current_options.every_ordering = base.every_ordering;
    current_options.threads = base.threads;
    before = kept.errors;
    if (options.after_round) options.after_round(current, before.mean_force_sd(), before.mean_impactor_sd());
  }

  drop_redundant(acc, named, current, current_options, before, options, base.m1_kg, out);

  out.params_after = current.params;
  out.options_after = current_options;
  out.error_after = error_set(before);
  out.fit_after = current;
  add_remaining(out, before, options);
  return out;
}

namespace {

// The paired drop from a to b (per trial, in noise SDs) beyond noise: the
// differences' t, or the logarithms' (every trial's error divided by a like
// factor; at least 3 trials), at least t_critical, with the mean drop at
// least min_relative of a's mean. Errors in noise SDs are a scale, and the
// differences' t misses a like factor when one trial carries most of the
// error.
struct Drop {
  double t = 0.0, t_log = 0.0;
  bool beyond_noise = false;
};
Drop paired_drop(const std::vector<double>& a, const std::vector<double>& b, const MatStageOptions& options) {
  const PairedImprovement pi = paired_improvement(detail::to_vector(a), detail::to_vector(b),
                                                  options.decision.t_critical, options.decision.min_relative, 0.0);
  Drop d;
  d.t = pi.t;
  d.t_log = log_paired_t(a, b);
  d.beyond_noise = pi.significant || (d.t_log >= options.decision.t_critical && pi.mean_drop > 0.0 &&
                                      pi.mean_drop >= options.decision.min_relative * std::abs(pi.mean_before));
  return d;
}

std::string t_text(const Drop& d) {
  return std::isfinite(d.t_log) ? fmt::format("paired t = {:.1f}, on the logarithms {:.1f}", d.t, d.t_log)
                                : fmt::format("paired t = {:.1f}", d.t);
}

}  // namespace

HeldOutChoice choose_by_held_out(const std::vector<fitting::TrialData>& trials, const std::string& name_a,
                                 const std::vector<fitting::TrialReport>& a, const std::string& name_b,
                                 const std::vector<fitting::TrialReport>& b, const MatStageOptions& options) {
  HeldOutChoice c;
  c.chosen = name_a;
  const HeldOutErrors ea = held_out_errors(a, trials, options.fit), eb = held_out_errors(b, trials, options.fit);
  c.force_a_sd = ea.mean_force_sd();
  c.force_b_sd = eb.mean_force_sd();
  c.impactor_a_sd = ea.mean_impactor_sd();
  c.impactor_b_sd = eb.mean_impactor_sd();
  c.peak_a_pct_max = ea.peak_pct.size() ? ea.peak_pct.maxCoeff() : kNaN;
  c.peak_b_pct_max = eb.peak_pct.size() ? eb.peak_pct.maxCoeff() : kNaN;
  // Paired over the held-out trials both predict: both channels in one
  // number, and each channel alone.
  std::vector<double> pa, pb, fa, fb, ka, kb;
  for (size_t i = 0; i < ea.ids.size(); ++i)
    for (size_t j = 0; j < eb.ids.size(); ++j)
      if (ea.ids[i] == eb.ids[j]) {
        pa.push_back(std::hypot(ea.force_sd[i], ea.impactor_sd[i]));
        pb.push_back(std::hypot(eb.force_sd[j], eb.impactor_sd[j]));
        fa.push_back(ea.force_sd[i]), fb.push_back(eb.force_sd[j]);
        ka.push_back(ea.impactor_sd[i]), kb.push_back(eb.impactor_sd[j]);
      }
  c.n = static_cast<int>(pa.size());
  const std::string numbers = fmt::format(
      "held-out force {:.2f} ({}) against {:.2f} ({}) noise SDs, impactor travel {:.2f} against {:.2f}, largest peak "
      "error {:.2f} against {:.2f} % over {} trials",
      c.force_a_sd, name_a, c.force_b_sd, name_b, c.impactor_a_sd, c.impactor_b_sd, c.peak_a_pct_max, c.peak_b_pct_max,
      c.n);
  if (c.n < 2) {
    c.evidence = "fewer than two held-out trials predicted by both: " + name_a + " kept (" + numbers + ")";
    return c;
  }
  // Both channels in one number; or, as the mat stage keeps an effect, one
  // channel above the noise gate falling beyond noise while neither gets
  // worse (above the gate and beyond min_relative over A's): the combined
  // number weighs the channels by their noise, so a force error of hundreds
  // of noise SDs can hide a travel error cut tenfold in every trial.
  const Drop both = paired_drop(pa, pb, options);
  c.t = both.t;
  c.t_log = both.t_log;
  const double gate = options.gate_noise_sd;
  std::string alone;
  bool worse = false;
  for (int ch = 0; ch < 2; ++ch) {
    const std::vector<double>& va = ch == 0 ? fa : ka;
    const std::vector<double>& vb = ch == 0 ? fb : kb;
    const double e0 = detail::rms(detail::to_vector(va)), e1 = detail::rms(detail::to_vector(vb));
    if (e1 > std::max(gate, e0 * (1.0 + options.decision.min_relative))) worse = true;
    if (e0 <= gate || !alone.empty()) continue;
    const Drop d = paired_drop(va, vb, options);
    if (d.beyond_noise) alone = fmt::format("{} alone: {}", ch == 0 ? "force" : "impactor travel", t_text(d));
  }
  const bool by_channel = !alone.empty() && !worse;
  if (both.beyond_noise || by_channel) {
    c.chosen = name_b;
    c.evidence = fmt::format("{} predicts the held-out trials better ({}{}): {}", name_b, t_text(both),
                             both.beyond_noise ? "" : "; " + alone + ", the other channel not worse", numbers);
  } else {
    c.evidence = fmt::format("{} does not predict the held-out trials better beyond noise ({}): {} kept; {}", name_b,
                             t_text(both), name_a, numbers);
  }
  return c;
}

}  // namespace dropfit::diagnosis
