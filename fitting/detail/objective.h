#pragma once
// The fitter's objective (internal to fitting/): each trial's window and
// residual samples weighted by its channels' measured noise, the simulation
// grid, the contact clock shift profiled out, and the Ceres problem with
// exact derivatives (dual numbers through the simulation) or central
// differences for a custom simulator.
#include <ceres/ceres.h>

#include <Eigen/Core>
#include <atomic>
#include <memory>
#include <string>
#include <vector>

#include "fitting/detail/space.h"
#include "fitting/fit.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting::internal {

// ---------------------------------------------------------------------------
// A trial prepared for the objective: the window, the residual samples and
// their weights, and the simulation grid (from contact, oversampled).
struct Prepared {
  const TrialData* data = nullptr;
  Impact impact;            // the simulation grid: first_output_s 0, output_dt_s h
  double h = 0.0;           // grid step
  int n_grid = 0;
  double dt = 0.0;          // plate sample spacing
  double window_end_s = 0.0;
  double t_peak_s = 0.0, peak_n = 0.0;
  bool fit_shift = false;      // the clock shift is fitted, within [shift_lo_s, shift_hi_s]
  double shift_lo_s = 0.0, shift_hi_s = 0.0;
  std::vector<int> f_idx;   // data indices of the force residuals
  std::vector<double> f_w;  // their weights (1 / noise)
  std::vector<int> k_idx;   // data indices of the impactor residuals (t >= 0, measured)
  double k_w = 0.0;
  int n_residuals() const { return static_cast<int>(f_idx.size() + k_idx.size()); }
  bool shifted() const { return fit_shift; }
};

// Prepares a trial: window, residual samples and weights, simulation grid.
// `cover_all`: the grid reaches the trial's last sample (predictions), not
// only the window. Throws Error for unusable samples.
Prepared prepare(const TrialData& tr, const FitOptions& o, bool cover_all = false);

// A simulated series on the grid (step h from contact) at model time tau:
// Catmull-Rom cubic, so a Jet time carries its derivative. Before contact
// the value is `before` (force: 0).
template <typename T, typename S>
auto on_grid(const std::vector<T>& y, const S& tau, double h, double before) {
  using R = decltype(std::declval<T>() * std::declval<S>());
  const int n = static_cast<int>(y.size());
  if (detail::scalar_of(tau) < 0.0 || n < 2) return R(before);
  const S pos = tau / h;
  int i = static_cast<int>(std::floor(detail::scalar_of(pos)));
  if (i > n - 2) i = n - 2;
  const S s = pos - double(i);
  const T y0 = y[i], y1 = y[i + 1];
  const T ym = i > 0 ? y[i - 1] : T(before);
  const T y2 = i + 2 < n ? y[i + 2] : T(2.0) * y1 - y0;
  const T a = T(0.5) * (T(-1.0) * ym + T(3.0) * y0 - T(3.0) * y1 + y2);
  const T b = T(0.5) * (T(2.0) * ym - T(5.0) * y0 + T(4.0) * y1 - y2);
  const T c = T(0.5) * (y1 - ym);
  return R(((a * s + b) * s + c) * s + y0);
}

// The clock shift that fits a simulated force best (doubles): a scan at a
// quarter grid step over the bound, then golden-section refinement.
double profile_shift(const Prepared& p, const std::vector<double>& grf);

// Simulates a trial's grid in doubles (the callback if given).
detail::Trace<double> simulate_window(const Prepared& p, const ParamSpace& space, const FitOptions& o,
                                      const MatParams& mp, std::atomic<long>* evals);

// One trial's weighted residuals (force, then travel) from a simulated
// window at the given clock shift (doubles); `out` holds p.n_residuals().
void residuals_at(const Prepared& p, const detail::Trace<double>& tr, double shift, double* out);

// Residual vector (doubles) over the prepared trials, shifts profiled.
Eigen::VectorXd residual_vector(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                                const MatParams& mp, std::atomic<long>* evals, std::vector<double>* shifts = nullptr);

// Half the sum of squared residuals (infinity when the model does not run).
double cost_of(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
               const MatParams& mp, std::atomic<long>* evals);

// The effective stiffness the training data show: peak force over the
// largest measured travel (energy balance when travel was not measured).
double effective_stiffness(const std::vector<Prepared>& preps);

// Builds the Ceres problem over the prepared trials; `shifts` holds one
// value per trial (used only where the trial's clock is fitted).
std::unique_ptr<ceres::Problem> make_problem(const std::vector<Prepared>& preps, const ParamSpace& space,
                                             const FitOptions& o, double* u, std::vector<double>& shifts,
                                             std::atomic<long>* evals, std::vector<double*>* blocks);

// Each channel's share of the cost at the optimum.
std::vector<ChannelShare> channel_shares(const std::vector<Prepared>& preps, const Eigen::VectorXd& r,
                                         std::vector<std::string>* warnings);

}  // namespace dropfit::fitting::internal
