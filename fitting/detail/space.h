#pragma once
// The parameter space the fitter searches (internal to fitting/): which
// model parameters are free, the coordinates the optimiser moves (log
// stiffness and damping, the top layer's mass fraction, linear effect
// parameters) and their bounds, narrowed by physics around the effective
// stiffness the training data show.
#include <Eigen/Core>
#include <cctype>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "fitting/fit.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting::internal {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// RK4 (effects on): the same step as simulate() takes (fitting/models.h).
inline const double kRk4Step = SimulateOptions{}.rk4_max_step_s;

// ---------------------------------------------------------------------------
// Parameter space: what the optimiser moves (u) and how it maps onto the
// model's parameters.
enum class Transform { Log, Fraction, Linear };

struct FreeParam {
  std::string name;       // MatParams field, or "m1_fraction"
  Transform transform = Transform::Log;
  double scale = 1.0;     // Linear: value = scale * u
  double lower = 0.0, upper = 0.0;            // bounds on u
  double start_lo = 0.0, start_hi = 0.0;      // start range on u
};

inline bool is_stiffness_or_damping(const std::string& name) {
  return name.size() >= 2 && (name[0] == 'k' || name[0] == 'r') && std::isdigit(static_cast<unsigned char>(name[1]));
}

struct ParamSpace {
  ModelKind model;
  MatParams base;  // fixed values (masses, effects), free ones overwritten
  std::vector<FreeParam> free;
  double total_mass = 0.0;

  int size() const { return static_cast<int>(free.size()); }

  double value_of(const FreeParam& f, double u) const {
    switch (f.transform) {
      case Transform::Log: return std::exp(u);
      case Transform::Fraction: return total_mass * u;
      default: return f.scale * u;
    }
  }

  MatParams to_mat(const double* u) const {
    MatParams p = base;
    for (int i = 0; i < size(); ++i) {
      const FreeParam& f = free[i];
      if (f.transform == Transform::Fraction) {
        p.m1_kg = total_mass * u[i];
        p.m2_kg = total_mass * (1.0 - u[i]);
      } else {
        set_parameter(p, f.name, value_of(f, u[i]));
      }
    }
    return p;
  }

  Eigen::VectorXd from_mat(const MatParams& p) const {
    Eigen::VectorXd u(size());
    for (int i = 0; i < size(); ++i) {
      const FreeParam& f = free[i];
      double v;
      if (f.transform == Transform::Fraction) v = p.m1_kg / total_mass;
      else if (f.transform == Transform::Log) v = std::log(std::max(get_parameter(p, f.name), 1e-300));
      else v = get_parameter(p, f.name) / f.scale;
      u[i] = std::clamp(v, f.lower, f.upper);
    }
    return u;
  }

  // The templated map for automatic differentiation.
  template <typename T>
  detail::ParamsT<T> to_params(const T* u) const {
    detail::ParamsT<T> p = detail::to_params_t<T>(model == ModelKind::Model5 ? ModelKind::Model4 : model, base);
    for (int i = 0; i < size(); ++i) {
      const FreeParam& f = free[i];
      const std::string& n = f.name;
      T v;
      if (f.transform == Transform::Log) {
        using std::exp;
        v = exp(u[i]);
      } else if (f.transform == Transform::Fraction) {
        p.m1 = T(total_mass) * u[i];
        p.m2 = T(total_mass) * (T(1.0) - u[i]);
        continue;
      } else {
        v = T(f.scale) * u[i];
      }
      if (n == "k1_n_m") p.k[0] = v;
      else if (n == "k2_n_m") p.k[1] = v;
      else if (n == "k3_n_m") p.k[2] = v;
      else if (n == "r1_n_s_m") p.r[0] = v;
      else if (n == "r2_n_s_m") p.r[1] = v;
      else if (n == "r3_n_s_m") p.r[2] = v;
      else if (n == "m_eff_kg") p.m1 = v;
      else if (n == "m1_kg") p.m1 = v;
      else if (n == "m2_kg") p.m2 = v;
      else if (n == "k1_cubic_n_m3") { p.k1_cubic = v; p.cubic = true; }
      else if (n == "r1_unload_n_s_m") { p.r1_unload = v; p.hysteresis = true; }
      else if (n == "maxwell_k_n_m") { p.maxwell_k = v; p.maxwell = true; }
      else if (n == "maxwell_tau_s") { p.maxwell_tau = v; p.maxwell = true; }
      else if (n == "k1_unload_ratio") { p.unload_ratio = v; p.asymmetric = true; }
    }
    return p;
  }

  // Are effects (the nonlinear path) in play?
  bool nonlinear() const {
    if (base.has_effects()) return true;
    for (const auto& f : free)
      if (f.name == "k1_cubic_n_m3" || f.name == "r1_unload_n_s_m" || f.name == "maxwell_k_n_m" ||
          f.name == "maxwell_tau_s" || f.name == "k1_unload_ratio")
        return true;
    return false;
  }
};

// The free parameters of `o.model` (and of its freed effects), bounded by
// physics around the effective stiffness k_eff (NaN: absolute bounds only).
ParamSpace make_space(const FitOptions& o, double k_eff);

// The name a free parameter is reported under ("m1_kg" for the mass fraction).
std::string param_display(const FreeParam& f);

}  // namespace dropfit::fitting::internal
