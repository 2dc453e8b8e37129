#pragma once
// Co-simulation of a fitted Model 6 (the foam column, fitting/model6.h): a
// foot or impactor whose motion another simulator owns steps the column with
// its contact position and velocity and gets back the force on it and the
// plate's reading, as fitting::MatContact does for Models 1-4 (same inputs,
// same outputs, same conventions: penetration_m is the foot's travel below
// the mat top at rest under its own weight, down positive; foot_n >= 0
// upwards on the foot; grf_n the plate's change from static; gravity on the
// foot is the caller's).
//
// While the foot presses, the column's top node follows the foot's travel
// exactly and the foot feels the top element's stress plus the top node's
// inertia (its acceleration from the trapezoidal rule): the column's own
// implicit step (model6_impl.h, the same laws and integrator the fitter
// uses) with node 0 prescribed. The foot separates when that force would
// pull (decided at the step's end); the column then moves on its own, and
// contact resumes when the foot reaches its top node, a plastic landing
// whose impulse m_0 dv is returned as the mean force over that step (the
// rigid-top convention of MatContact's Models 2 and 3).
//
// A caller's step longer than the geometry's max_step_s is cut into equal
// sub-steps with the foot's travel interpolated by the cubic Hermite through
// (travel, velocity) at both ends; the forces returned are the step end's.
//
// Usage (a point foot of mass M landing under gravity):
//
//   const auto file = report::parse_model6_fit_json(text, "fit.json");
//   fitting::ColumnContact mat(file.params, file.geometry);
//   double y = -0.01, v = 5.0;
//   for (int n = 0; n < 300; ++n) {
//     y += v * dt;
//     const fitting::ContactForces f = mat.step(y, v, dt);
//     v += (g - f.foot_n / M) * dt;
//   }
#include <memory>

#include "fitting/cosim.h"
#include "fitting/model6.h"

namespace dropfit::fitting {

class ColumnContact {
 public:
  // Throws dropfit::Error for parameters or a geometry Model 6 cannot use.
  ColumnContact(const Model6Params& params, const Model6Geometry& geometry, double gravity_m_s2 = 9.81);
  ~ColumnContact();
  ColumnContact(ColumnContact&&) noexcept;
  ColumnContact& operator=(ColumnContact&&) noexcept;

  // The column back at rest and the foot at (penetration_m, velocity_m_s)
  // now (a foot already at or below the top lands now).
  void reset(double penetration_m, double velocity_m_s);
  // Advances by dt_s > 0 to the foot's new state. Throws dropfit::Error for
  // a non-finite input or dt_s <= 0.
  ContactForces step(double penetration_m, double velocity_m_s, double dt_s);

  bool in_contact() const;
  double surface_m() const;    // the top node's travel below rest
  double interface_m() const;  // the layer interface's

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace dropfit::fitting
