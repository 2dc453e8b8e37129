#pragma once
// Table mode: fitting a mat model when only per-trial summaries exist
// (impact velocity, maximum deformation, peak force: the paper's Table 1).
//
// fit_table matches the simulated peak force and maximum impactor travel of
// the training trials, each over its own scale (peak_noise_n,
// deformation_noise_m), by Levenberg-Marquardt in log parameters from
// several starts. Two numbers a trial rarely pin a model down, so distinct
// optima that fit as well are reported as alternatives.
//
// Bounds and starts come from the data: the effective stiffness k_eff =
// F_peak / x_max of the training trials bounds every series spring to
// [k_eff_lower_ratio, k_eff_upper_ratio] k_eff and the damping to
// damping_ratio_max times the impactor's critical damping 2 sqrt(k_eff M);
// the first start puts k_eff into the top spring with light damping.
//
// Summaries admit a degenerate optimum: a soft spring under a strong damper
// whose force is largest at contact (r v0) and whose impactor sinks into the
// mat and stays, matching a peak force and a deformation no real mat would
// produce that way. Every optimum is gated on the training impacts: its
// simulated peak must come at least contact_peak_s after contact, and the
// impactor must leave the mat within rebound_horizon_s. The best optimum that
// passes is the result; when none does, TableFitResult::refused holds the
// reason (a caller must not report those parameters as the mat's).
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "fitting/models.h"

namespace dropfit::fitting {

struct TableTrial {
  std::string id;
  double impact_velocity_m_s = 0.0;
  double max_deformation_m = std::numeric_limits<double>::quiet_NaN();  // NaN = not used
  double peak_force_n = 0.0;
};

struct TableFitOptions {
  ModelKind model = ModelKind::Model1;
  MatParams base;                    // parameters not fitted (masses, other elements); fitted ones > 0: a start
  std::vector<std::string> free = {"k1_n_m", "r1_n_s_m"};  // fitted (log scale)
  std::vector<std::string> train_ids;  // empty: the median-velocity trial
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double peak_noise_n = 50.0;          // scales of the two residuals
  double deformation_noise_m = 0.002;
  int starts = 6;
  std::uint64_t seed = 1;
  // Bounds around the training trials' effective stiffness (see above).
  double k_eff_lower_ratio = 0.3, k_eff_upper_ratio = 1000.0;
  double damping_ratio_max = 10.0;
  // The gate: a simulated peak sooner than this after contact is the
  // damper's (r v0), not the mat's; the impactor must leave within the horizon.
  double contact_peak_s = 1e-3;
  double rebound_horizon_s = 1.0;
};

struct TableTrialReport {
  std::string id;
  bool train = false;
  double impact_velocity_m_s = 0.0;
  double peak_force_n = 0.0, simulated_peak_force_n = 0.0, peak_force_pct_diff = 0.0;
  double max_deformation_m = 0.0, simulated_max_deformation_m = 0.0;
};

struct TableFitResult {
  MatParams params;                  // the best optimum that is a mat
  std::vector<MatParams> alternatives;  // distinct optima that fit as well (ambiguity)
  std::vector<TableTrialReport> trials;
  std::vector<std::string> warnings;
  std::string refused;               // non-empty: no optimum is a mat (why); params is then not a mat
  double cost = 0.0;
};

// Fits options.model to the training trials' summaries and predicts every
// trial. Throws Error for unusable input (no trials, Model 5, an unknown
// train id or free parameter, every start failing).
TableFitResult fit_table(const std::vector<TableTrial>& trials, const TableFitOptions& options);

// Why `params` is not a mat for an impact at `velocity_m_s` (empty: it is):
// its simulated peak comes at contact, or its impactor never leaves.
std::string table_degenerate(const TableFitOptions& options, const MatParams& params, double velocity_m_s);

// The parameters table mode fits for a model: the springs and dampers (and
// Model 2's effective mass); layer masses stay as given.
std::vector<std::string> table_free(ModelKind model);

// The options a table run uses: the model's free parameters, the paper's
// Table 2 values as a start (a fixed, documented point; Model 2's m_eff
// 2 kg), the given impactor and layer masses.
TableFitOptions table_options(ModelKind model, double impactor_mass_kg, double m1_kg, double m2_kg);

// One impact left out: fitted to every other impact (all trained together),
// the left-out one predicted from its velocity.
struct TableHeldOut {
  std::string id;
  MatParams params;
  double impact_velocity_m_s = 0.0;
  double peak_force_n = 0.0, simulated_peak_force_n = 0.0, peak_force_pct_diff = 0.0;
  double max_deformation_m = 0.0, simulated_max_deformation_m = 0.0;
};

// Each impact left out in turn (table order). A left-out fit with no
// physical optimum is skipped, with a note in `notes` when given.
std::vector<TableHeldOut> table_leave_one_out(const std::vector<TableTrial>& trials, const TableFitOptions& options,
                                              std::vector<std::string>* notes = nullptr);

// A fitted model's peak force over the table's velocity range (0.9 x the
// slowest to 1.1 x the fastest impact, `points` evenly spaced).
struct TablePeakCurve {
  std::vector<double> velocity_m_s, peak_force_n;
};
TablePeakCurve table_peak_curve(const std::vector<TableTrial>& trials, const TableFitOptions& options,
                                const MatParams& params, int points = 41);

}  // namespace dropfit::fitting
