// The fitter's search (see detail/search.h and fit.h).
#include "fitting/detail/search.h"

#include <ceres/ceres.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <numeric>
#include <utility>

#include "core/error.h"
#include "core/parallel.h"
#include "fitting/anneal.h"
#include "fitting/detail/starts.h"

namespace dropfit::fitting::internal {

// Levenberg-Marquardt from u0 (shifts profiled at u0 to start).
Optimum run_ceres(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                  const Eigen::VectorXd& u0, std::atomic<long>* evals, bool want_jacobian,
                  const std::vector<double>* shifts0, double radius0, int hold) {
  Optimum best;
  std::vector<double> u(u0.data(), u0.data() + u0.size());
  std::vector<double> shifts(preps.size(), 0.0);
  if (shifts0 && shifts0->size() == preps.size()) {
    shifts = *shifts0;
  } else {
    try {
      residual_vector(preps, space, o, space.to_mat(u.data()), evals, &shifts);
    } catch (const Error&) {
      std::fill(shifts.begin(), shifts.end(), 0.0);
    }
  }
  std::vector<double*> blocks;
  auto problem = make_problem(preps, space, o, u.data(), shifts, evals, &blocks);
  if (hold >= 0 && space.size() > 1) problem->SetManifold(u.data(), new ceres::SubsetManifold(space.size(), {hold}));
  else if (hold >= 0) problem->SetParameterBlockConstant(u.data());
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_QR;
  so.max_num_iterations = o.max_iterations;
  so.function_tolerance = 1e-10;
  so.gradient_tolerance = 1e-12;
  so.parameter_tolerance = 1e-10;
  so.logging_type = ceres::SILENT;
  so.minimizer_progress_to_stdout = false;
  so.num_threads = 1;
  // A run continued from a chunk keeps its trust region (a fresh radius
  // spends iterations on rejected steps before it shrinks back).
  if (radius0 > 0.0) so.initial_trust_region_radius = radius0;
  // With bounds, Ceres follows every trust-region step by a projected Armijo
  // line search. With its default cubic interpolation every trial point
  // costs a Jacobian; quadratic interpolation needs only the cost, a
  // simulation in doubles, and finds the same optima. The line search stays
  // on for Models 1-4: without it, refits with an effect freed (a Maxwell
  // arm, unloading damping) end in far worse optima. Model 5 goes without:
  // from its warm start it converges in fewer Jacobians and simulations, at
  // a lower cost (docs/models.md, "Search settings").
  so.line_search_interpolation_type = ceres::QUADRATIC;
  // At most 3 trial points (Ceres' default is 20): when the projected step
  // gives no sufficient decrease the search would shrink it up to 20 times,
  // each a simulation; after 3 the trust region judges the step itself.
  so.max_num_line_search_step_size_iterations = 3;
  if (o.model == ModelKind::Model5) so.max_num_line_search_step_size_iterations = 0;
  ceres::Solver::Summary summary;
  ceres::Solve(so, problem.get(), &summary);
  best.u = Eigen::Map<Eigen::VectorXd>(u.data(), u.size());
  best.shifts = shifts;
  best.cost = summary.IsSolutionUsable() ? summary.final_cost : std::numeric_limits<double>::infinity();
  best.converged = summary.termination_type == ceres::CONVERGENCE || !summary.IsSolutionUsable();
  if (!summary.iterations.empty()) best.radius = summary.iterations.back().trust_region_radius;
  if (want_jacobian) {
    double cost = 0.0;
    std::vector<double> res;
    ceres::CRSMatrix crs;
    ceres::Problem::EvaluateOptions eo;
    eo.parameter_blocks = blocks;
    if (problem->Evaluate(eo, &cost, &res, nullptr, &crs)) {
      best.residuals = Eigen::Map<Eigen::VectorXd>(res.data(), res.size());
      best.jacobian = Eigen::MatrixXd::Zero(crs.num_rows, crs.num_cols);
      for (int r = 0; r < crs.num_rows; ++r)
        for (int k = crs.rows[r]; k < crs.rows[r + 1]; ++k) best.jacobian(r, crs.cols[k]) = crs.values[k];
    }
  }
  return best;
}


namespace {

// Simulated annealing from the best candidate, over the whole box; the
// Jacobian at its optimum (or a Ceres polish from it) for the covariance.
Search anneal_search(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                     const std::vector<Eigen::VectorXd>& cands, std::atomic<long>* evals,
                     std::vector<std::string>* warnings, std::string* used) {
  const int n = space.size();
  *used = "annealing (Corana et al. 1987)";
  Eigen::VectorXd lo(n), hi(n);
  for (int j = 0; j < n; ++j) {
    lo[j] = space.free[j].lower;
    hi[j] = space.free[j].upper;
  }
  auto f = [&](const Eigen::VectorXd& u) { return cost_of(preps, space, o, space.to_mat(u.data()), evals); };
  Eigen::VectorXd x0 = cands.front();
  double f0 = f(x0);
  for (const auto& c : cands) {
    const double fc = f(c);
    if (fc < f0) { f0 = fc; x0 = c; }
  }
  const AnnealResult ar = anneal(f, x0, lo, hi, o.anneal);
  if (!ar.converged) warnings->push_back("annealing stopped at its evaluation limit before converging");
  Search s;
  s.best.u = ar.x;
  s.best.cost = ar.f;
  if (o.polish_annealing) {
    *used += " + Ceres polish";
    Optimum pol = run_ceres(preps, space, o, ar.x, evals, true);
    if (pol.cost <= s.best.cost) {
      s.best = pol;
      return s;
    }
  }
  // Jacobian at the annealing optimum, for the covariance.
  FitOptions one = o;
  one.max_iterations = 0;
  Optimum jac = run_ceres(preps, space, one, s.best.u, evals, true);
  jac.u = s.best.u;
  jac.cost = s.best.cost;
  s.best = jac;
  return s;
}

// The candidates Levenberg-Marquardt runs from (indices into cands), every
// candidate screened by cost: the best of each spring ordering, then the
// best overall up to `starts`; a given start always.
std::vector<int> choose_runs(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                             const std::vector<Eigen::VectorXd>& cands, bool warm_only, std::atomic<long>* evals) {
  std::vector<std::pair<double, int>> ranked;
  for (size_t i = 0; i < cands.size() && !warm_only; ++i)
    ranked.push_back({cost_of(preps, space, o, space.to_mat(cands[i].data()), evals), static_cast<int>(i)});
  std::vector<int> order;
  if (warm_only) {
    order.push_back(0);
    return order;
  }
  std::sort(ranked.begin(), ranked.end());
  std::vector<int> seen_orderings;
  if (o.initial.k1_n_m > 0.0 && !o.every_ordering) order.push_back(0);
  for (const auto& [c, i] : ranked) {  // the best of each ordering
    if (!std::isfinite(c) || !o.every_ordering) break;
    const int ord = ordering_of(space, cands[i]);
    if (std::find(seen_orderings.begin(), seen_orderings.end(), ord) != seen_orderings.end()) continue;
    seen_orderings.push_back(ord);
    order.push_back(i);
  }
  // and the best overall, up to `starts` runs beyond two (at least one
  // run from every ordering whatever `starts` says).
  for (const auto& [c, i] : ranked) {
    const int extra = o.every_ordering ? 2 : 0;
    if (static_cast<int>(order.size()) >= std::max(o.starts, static_cast<int>(seen_orderings.size()) + extra)) break;
    if (std::isfinite(c) && std::find(order.begin(), order.end(), i) == order.end()) order.push_back(i);
  }
  if (o.initial.k1_n_m > 0.0 && std::find(order.begin(), order.end(), 0) == order.end()) order.push_back(0);
  return order;
}

// The Levenberg-Marquardt runs of a multi-start, one per chosen candidate.
struct MultiStart {
  const std::vector<Prepared>& preps;
  const ParamSpace& space;
  const FitOptions& o;
  const std::vector<Eigen::VectorXd>& cands;
  const std::vector<int>& order;
  std::atomic<long>* evals;
  std::vector<Optimum> runs;

  // Runs `which` in parallel with the options `oo`, from their candidates
  // or (from_runs) on from where they stopped, keeping the trust region.
  void in_parallel(const std::vector<size_t>& which, const FitOptions& oo, bool from_runs) {
    const int threads = std::max(1, std::min<int>(o.threads, static_cast<int>(which.size())));
    // The threads the runs leave free go to each run's derivatives (Model 5).
    FitOptions inner = oo;
    inner.threads = std::max(1, o.threads / threads);
    parallel_for(which.size(), threads, [&](size_t q) {
      const size_t k = which[q];
      const Eigen::VectorXd u0 = from_runs ? runs[k].u : cands[order[k]];
      Optimum r = run_ceres(preps, space, inner, u0, evals, false, from_runs ? &runs[k].shifts : nullptr,
                            from_runs ? runs[k].radius : 0.0);
      if (!from_runs || r.cost <= runs[k].cost) runs[k] = std::move(r);
      else runs[k].converged = true;  // no progress from here
    });
  }

  // Two stages: a few iterations from every start, then to convergence
  // from the ones that came within reach of the best (a basin whose start
  // is still follow_factor times worse than the best after the first stage
  // is not followed: from a start inside the right basin
  // Levenberg-Marquardt converges in a handful of iterations, while the
  // far corners cost the most simulation).
  void run(bool warm_only) {
    runs.assign(order.size(), Optimum{});
    std::vector<size_t> all(order.size());
    std::iota(all.begin(), all.end(), 0);
    FitOptions first_stage = o;
    first_stage.max_iterations = std::min(o.max_iterations, o.first_stage_iterations);
    in_parallel(all, first_stage, false);
    // A protected given start (FitOptions::protect_initial) goes on whatever
    // it shows, and does not set the lead that cuts the others.
    const bool protect = o.protect_initial && o.initial.k1_n_m > 0.0 && !warm_only;
    auto is_initial = [&](size_t k) { return protect && order[k] == 0; };
    double lead = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < runs.size(); ++k)
      if (!is_initial(k)) lead = std::min(lead, runs[k].cost);
    std::vector<size_t> follow;
    for (size_t k = 0; k < runs.size(); ++k)
      if (std::isfinite(runs[k].cost) && (runs[k].cost <= o.follow_factor * lead || is_initial(k)))
        follow.push_back(k);
    if (o.max_iterations <= first_stage.max_iterations) follow.clear();
    follow_in_chunks(follow, is_initial);
  }

  // Then in chunks: a run that stays far behind the best while it crawls
  // (gaining little per chunk) is dropped, as is one that could not reach
  // the best at its pace (a lumped model on a foam mat leaves runs within a
  // few times the best cost gaining under 1e-4 of it per chunk, up to the
  // iteration limit); the others go on until Ceres stops them on a
  // tolerance or the iteration limit. Runs in a wrong basin
  // crawl along a bound, gaining a few per cent a chunk; a run that has
  // entered its basin gains orders of magnitude. (The follow stage has
  // max_iterations of its own after the first stage.)
  void follow_in_chunks(std::vector<size_t> active, const std::function<bool(size_t)>& is_protected) {
    int done = 0;
    while (!active.empty() && done < o.max_iterations) {
      FitOptions chunk = o;
      // One run left has nothing to be dropped for: it goes on in one piece.
      chunk.max_iterations = active.size() > 1
                                 ? std::min(std::max(1, o.follow_chunk_iterations), o.max_iterations - done)
                                 : o.max_iterations - done;
      std::vector<double> before;
      for (size_t k : active) before.push_back(runs[k].cost);
      in_parallel(active, chunk, true);
      done += chunk.max_iterations;
      double best_now = std::numeric_limits<double>::infinity();
      for (const auto& r : runs) best_now = std::min(best_now, r.cost);
      // Chunks the runs still have.
      const double left = static_cast<double>(o.max_iterations - done) / std::max(1, o.follow_chunk_iterations);
      std::vector<size_t> next;
      for (size_t i = 0; i < active.size(); ++i) {
        const Optimum& r = runs[active[i]];
        if (r.converged || !std::isfinite(r.cost)) continue;
        const double gain = (before[i] - r.cost) / std::max(r.cost, 1e-300);
        if (r.cost > o.drop_factor * best_now && gain < o.drop_gain) continue;
        // A run behind the best that, gaining what it gained in this chunk in
        // every chunk it has left, would still end behind it: its basin is
        // not the best one (Levenberg-Marquardt's gains shrink as it closes
        // in, so the straight line is the run's best case). A protected
        // given start goes on.
        if (!is_protected(active[i]) && r.cost - left * (before[i] - r.cost) > best_now) continue;
        next.push_back(active[i]);
      }
      active = std::move(next);
    }
  }
};

}  // namespace

// Multi-start: every candidate screened by cost; Levenberg-Marquardt from
// the best candidate of each spring ordering and the best overall, in
// parallel.
Search optimise(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o, double k_eff,
                std::atomic<long>* evals, std::vector<std::string>* warnings, std::string* used) {
  const std::vector<Eigen::VectorXd> cands = candidate_starts(space, o, k_eff, *preps.front().data);
  if (o.optimizer == Optimizer::Annealing) return anneal_search(preps, space, o, cands, evals, warnings, used);

  *used = "ceres (Levenberg-Marquardt, multi-start over spring orderings)";
  // A given start with starts == 1 (a warm start, e.g. Model 5 from Model
  // 4's optimum) runs alone: the other candidates are not screened.
  const bool warm_only = o.initial.k1_n_m > 0.0 && o.starts == 1;
  const std::vector<int> order = choose_runs(preps, space, o, cands, warm_only, evals);
  MultiStart ms{preps, space, o, cands, order, evals, {}};
  ms.run(warm_only);
  const std::vector<Optimum>& runs = ms.runs;

  Search s;
  int failed = 0, best_k = -1;
  for (size_t k = 0; k < runs.size(); ++k) {
    if (!std::isfinite(runs[k].cost)) { ++failed; continue; }
    if (best_k < 0 || runs[k].cost < runs[best_k].cost) best_k = static_cast<int>(k);
  }
  if (best_k < 0) throw Error("fit: every start failed (the simulation did not run)");
  if (failed > 0) warnings->push_back(fmt::format("{} of {} starts failed", failed, runs.size()));
  for (size_t k = 0; k < runs.size(); ++k)
    if (static_cast<int>(k) != best_k && std::isfinite(runs[k].cost)) s.others.push_back(runs[k]);
  FitOptions one = o;
  one.max_iterations = 0;
  s.best = run_ceres(preps, space, one, runs[best_k].u, evals, true, &runs[best_k].shifts);
  s.best.cost = runs[best_k].cost;
  return s;
}

}  // namespace dropfit::fitting::internal
