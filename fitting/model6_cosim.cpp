// Model 6 stepped by another simulator's foot (fitting/model6_cosim.h).
#include "fitting/model6_cosim.h"

#include <cmath>
#include <optional>

#include "core/error.h"
#include "fitting/model6_impl.h"

namespace dropfit::fitting {

struct ColumnContact::Impl {
  Model6ParamsT<double> params;
  Model6Geometry geometry;
  double gravity_m_s2 = 9.81;
  std::optional<model6_detail::Column<double>> column;
  bool contact = false;
  bool started = false;
  double y_prev = 0.0, v_prev = 0.0;

  void rest() { column.emplace(params, geometry, gravity_m_s2); }

  // One sub-step to the foot's travel y (velocity v) at its end: the force on
  // the foot (upwards); a landing's impulse is added to *impulse_n_s.
  double sub_step(double h, double y, double v, double* impulse_n_s) {
    auto& col = *column;
    if (!contact && y >= col.u(0)) {
      // A plastic landing: the top node takes the foot's velocity.
      *impulse_n_s += col.node_mass(0) * (v - col.v(0));
      col.set_top_velocity(v);
      contact = true;
    }
    if (!contact) {
      col.drive(h, nullptr);
      return 0.0;
    }
    const double foot = col.drive(h, &y, v);
    if (foot >= 0.0) return foot;
    contact = false;  // it would pull: the foot leaves, the column goes on alone
    return 0.0;
  }
};

ColumnContact::ColumnContact(const Model6Params& params, const Model6Geometry& geometry, double gravity_m_s2)
    : impl_(std::make_unique<Impl>()) {
  Impact probe;
  probe.mass_kg = 1.0;
  probe.output_dt_s = geometry.max_step_s;
  probe.duration_s = geometry.max_step_s;
  model6_detail::check(geometry, probe);
  impl_->params = model6_params_t<double>(params);
  model6_detail::check(impl_->params);
  if (!(gravity_m_s2 >= 0.0) || !std::isfinite(gravity_m_s2)) throw Error("ColumnContact: gravity must be >= 0");
  impl_->geometry = geometry;
  impl_->gravity_m_s2 = gravity_m_s2;
  impl_->rest();
}

ColumnContact::~ColumnContact() = default;
ColumnContact::ColumnContact(ColumnContact&&) noexcept = default;
ColumnContact& ColumnContact::operator=(ColumnContact&&) noexcept = default;

void ColumnContact::reset(double penetration_m, double velocity_m_s) {
  if (!std::isfinite(penetration_m) || !std::isfinite(velocity_m_s)) throw Error("ColumnContact::reset: non-finite input");
  impl_->rest();
  impl_->contact = false;
  impl_->started = true;
  impl_->y_prev = penetration_m;
  impl_->v_prev = velocity_m_s;
}

ContactForces ColumnContact::step(double penetration_m, double velocity_m_s, double dt_s) {
  if (!std::isfinite(penetration_m) || !std::isfinite(velocity_m_s) || !std::isfinite(dt_s))
    throw Error("ColumnContact::step: non-finite input");
  if (!(dt_s > 0.0)) throw Error("ColumnContact::step: dt_s must be positive");
  Impl& m = *impl_;
  if (!m.started) {  // the foot came at constant velocity
    m.y_prev = penetration_m - velocity_m_s * dt_s;
    m.v_prev = velocity_m_s;
    m.started = true;
  }
  // Equal sub-steps of at most max_step_s; the foot's travel by the cubic
  // Hermite through both ends.
  const int n = std::max(1, static_cast<int>(std::ceil(dt_s / m.geometry.max_step_s - 1e-9)));
  const double h = dt_s / n;
  const double y0 = m.y_prev, w0 = m.v_prev * dt_s, y1 = penetration_m, w1 = velocity_m_s * dt_s;
  double foot = 0.0, impulse_n_s = 0.0;
  for (int k = 1; k <= n; ++k) {
    const double s = static_cast<double>(k) / n;
    const double h00 = (1 + 2 * s) * (1 - s) * (1 - s), h10 = s * (1 - s) * (1 - s), h01 = s * s * (3 - 2 * s),
                 h11 = s * s * (s - 1);
    const double y = h00 * y0 + h10 * w0 + h01 * y1 + h11 * w1;
    const double dy = (6 * s * s - 6 * s) * y0 + (3 * s * s - 4 * s + 1) * w0 + (6 * s - 6 * s * s) * y1 +
                      (3 * s * s - 2 * s) * w1;  // d y / d s
    foot = m.sub_step(h, y, dy / dt_s, &impulse_n_s);
  }
  m.y_prev = penetration_m;
  m.v_prev = velocity_m_s;
  ContactForces out;
  out.foot_n = foot + impulse_n_s / dt_s;
  out.grf_n = m.column->plate_force();
  out.contact = m.contact;
  return out;
}

bool ColumnContact::in_contact() const { return impl_->contact; }
double ColumnContact::surface_m() const { return impl_->column->u(0); }
double ColumnContact::interface_m() const {
  const auto& c = *impl_->column;
  return c.interface_node() < c.nodes() ? c.u(c.interface_node()) : 0.0;
}

}  // namespace dropfit::fitting
