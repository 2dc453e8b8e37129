#pragma once
// A simulated contact's summary numbers and its force on a trial's samples
// (internal to fitting/): what the prediction intervals of every model
// (Models 1-5 in uncertainty.cpp, Model 6 in model6_predict.cpp) are
// computed on.
#include <Eigen/Core>
#include <limits>

#include "fitting/models.h"

namespace dropfit::fitting::internal {

inline constexpr double kZ95 = 1.959964;  // the normal's two-sided 95 % quantile

// The three summary numbers of a simulated contact: peak force and its time
// (a parabola through the highest sample and its neighbours, so that they
// move smoothly with the parameters) and the largest impactor travel.
struct Summary {
  double peak_n = std::numeric_limits<double>::quiet_NaN();
  double t_peak_s = std::numeric_limits<double>::quiet_NaN();
  double max_travel_m = std::numeric_limits<double>::quiet_NaN();
};

// The top of the parabola through y[i - 1], y[i], y[i + 1]; *offset its
// position from i in samples (0 at an end or where y is not concave).
double parabola_top(const Eigen::VectorXd& y, Eigen::Index i, double* offset);

Summary summarise(const Simulation& s);

// A simulated force on a trial's samples (shifted by its clock shift) from
// the fine output grid (step h from contact), linearly.
Eigen::VectorXd force_on_samples(const Simulation& s, const Eigen::VectorXd& t_s, double shift, double h);

}  // namespace dropfit::fitting::internal
