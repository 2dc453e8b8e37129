// The fitter's parameter space: free parameters, their coordinates and
// their bounds (see detail/space.h).
#include "fitting/detail/space.h"

#include <fmt/format.h>

#include <algorithm>
#include <utility>

#include "core/error.h"

namespace dropfit::fitting::internal {

namespace {

FreeParam log_param(const std::string& name, double lo, double hi) {
  FreeParam f;
  f.name = name;
  f.transform = Transform::Log;
  f.lower = std::log(lo);
  f.upper = std::log(hi);
  f.start_lo = f.lower;
  f.start_hi = f.upper;
  return f;
}

// Stiffness bounds from physics: no series spring is softer than a fraction
// of the effective stiffness the data show, and one far stiffer than it is
// rigid for this mat (its value no longer changes what is measured).
std::pair<double, double> stiffness_bounds(const FitOptions& o, double k_eff) {
  double lo = o.k_min_n_m, hi = o.k_max_n_m;
  if (std::isfinite(k_eff) && k_eff > 0.0) {
    lo = std::max(lo, o.k_eff_lower_ratio * k_eff);
    hi = std::min(hi, o.k_eff_upper_ratio * k_eff);
    if (!(hi > lo * 1.01)) hi = lo * 10.0;  // absolute limits disagree with the data: keep a range
  }
  return {lo, hi};
}

FreeParam linear_param(const std::string& name, double scale, double lower, double upper, double start_lo,
                       double start_hi) {
  FreeParam f;
  f.name = name;
  f.transform = Transform::Linear;
  f.scale = scale;
  f.lower = lower;
  f.upper = upper;
  f.start_lo = start_lo;
  f.start_hi = start_hi;
  return f;
}

}  // namespace

ParamSpace make_space(const FitOptions& o, double k_eff) {
  ParamSpace s;
  s.model = o.model;
  s.total_mass = o.m1_kg + o.m2_kg;
  s.base = o.effects;
  s.base.k1_n_m = s.base.k2_n_m = s.base.k3_n_m = 0.0;
  s.base.r1_n_s_m = s.base.r2_n_s_m = s.base.r3_n_s_m = 0.0;
  s.base.m1_kg = o.m1_kg;
  s.base.m2_kg = o.m2_kg;
  s.base.m_eff_kg = o.m_eff_kg >= 0.0 ? o.m_eff_kg : 0.0;
  const auto [k_lo, k_hi] = stiffness_bounds(o, k_eff);
  const ModelKind shape = o.model == ModelKind::Model5 ? ModelKind::Model4 : o.model;
  // A stiffening top element (k1 x + k1_cubic x^3) meets the floor with
  // its secant at the largest travel, k1 + k1_cubic x^2, not with its
  // linear part: a mat whose force at depth is mostly the cubic term has a
  // linear k1 below the floor, and holding it at the floor misfits the mat
  // (docs/models.md, "Search settings"). Its linear part keeps the
  // absolute floor; its start range is the series springs'.
  const bool stiffening =
      std::find(o.free_effects.begin(), o.free_effects.end(), "k1_cubic_n_m3") != o.free_effects.end();
  for (const auto& name : parameter_names(shape, false)) {
    if (name[0] == 'k') {
      FreeParam f = log_param(name, k_lo, k_hi);
      if (stiffening && name == "k1_n_m") f.lower = std::log(std::min(o.k_min_n_m, k_lo));
      s.free.push_back(f);
    } else {
      s.free.push_back(log_param(name, o.r_min_n_s_m, o.r_max_n_s_m));
    }
  }
  if (o.model == ModelKind::Model2 && o.m_eff_kg < 0.0)
    s.free.push_back(
        linear_param("m_eff_kg", 1.0, 0.01, std::max(s.total_mass, 0.02), 0.1 * s.total_mass, 0.6 * s.total_mass));
  if (o.masses_free && (shape == ModelKind::Model3 || shape == ModelKind::Model4)) {
    FreeParam f;
    f.name = "m1_fraction";
    f.transform = Transform::Fraction;
    f.lower = 0.05;
    f.upper = 0.95;
    f.start_lo = 0.2;
    f.start_hi = 0.7;
    s.free.push_back(f);
  }
  for (const auto& name : o.free_effects) {
    if (name == "k1_cubic_n_m3") {
      s.free.push_back(linear_param(name, 1e7, 0.0, 1e3, 0.0, 5.0));
    } else if (name == "r1_unload_n_s_m") {
      s.free.push_back(log_param(name, o.r_min_n_s_m, o.r_max_n_s_m));
    } else if (name == "maxwell_k_n_m") {
      // The arm stands beside element 1, not in the series: the series
      // springs' floor (a fraction of the effective stiffness) does not
      // apply, and a weak arm (a few per cent of k1) is what a slightly
      // rate-dependent foam shows. Its floor is the absolute one: with the
      // series floor, such arms sit on the bound and are not named
      // (docs/models.md, "Search settings").
      s.free.push_back(log_param(name, o.k_min_n_m, k_hi));
    } else if (name == "maxwell_tau_s") {
      s.free.push_back(log_param(name, 1e-3, 0.3));
    } else if (name == "k1_unload_ratio") {
      s.free.push_back(linear_param(name, 1.0, 0.0, 0.9, 0.02, 0.4));
    } else {
      throw Error(fmt::format("fit: '{}' is not an effect parameter that can be fitted", name));
    }
  }
  return s;
}

std::string param_display(const FreeParam& f) { return f.transform == Transform::Fraction ? "m1_kg" : f.name; }

}  // namespace dropfit::fitting::internal
