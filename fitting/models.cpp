// Models 1-4 of Mills, Pain & Yeadon (2006), J. Appl. Biomech. 22:103,
// Figure 2, as equations. Notation: M impactor mass, g gravity, v0 the
// downward impact speed; y0 impactor travel, y1, y2 mat-mass travel, all
// downward from first contact with the mat at rest; element j (kj, rj)
// exerts Fj = kj dj + rj dj' where dj is its compression (upper node travel
// minus lower node travel; the ground does not move). The mat masses'
// weights are carried by the static pre-compression of the elements below
// them, so in these deviation coordinates gravity acts on the impactor only
// and every GRF below is the change from static: what a plate zeroed with
// the mat at rest reads.
//
// Model 1 (Fig. 2a, "linear spring-damper"): massless element 1 between the
//   impactor and the ground.
//     contact: M y0'' = M g - F1,  F1 = k1 y0 + r1 y0'  (clamped >= 0)
//     GRF = F1 (a massless element passes its force straight down).
//   Separation when F1 would turn negative (the damper would pull). The
//   element's top (the surface) then recovers on its own, k1 e + r1 e' = 0,
//   and the impactor flies ballistically until it catches the surface.
// Model 2 (Fig. 2b, "with accelerated mass"): the mat's effective mass
//   m_eff (Pain, Mills & Yeadon 2005) sits on element 1 and moves with the
//   impactor while they touch:
//     (M + m_eff) y'' = M g - F1,  F1 = k1 y + r1 y',  GRF = F1,
//   so GRF = contact force + m_eff * (upward acceleration): the effective
//   mass times the impactor's acceleration, as the paper adds it, but with
//   the impactor's motion made consistent with it. At first contact the
//   impactor and m_eff (at rest) share momentum: y'(0+) = M v0 / (M + m_eff)
//   (a perfectly plastic collision). The contact force on the impactor is
//   lambda = M (m_eff g + F1) / (M + m_eff); separation when lambda < 0,
//   after which m_eff oscillates on element 1 on its own.
//   m_eff = 0 is Model 1.
// Model 3 (Fig. 2c, "two-layer"): the impactor rides rigidly on the top
//   layer m1 (plastic collision at first contact, as Model 2); element 1
//   joins m1 to the bottom layer m2, element 2 joins m2 to the ground.
//     contact: (M + m1) y1'' = M g - F1,  F1 = k1 (y1 - y2) + r1 (y1' - y2')
//              m2 y2'' = F1 - F2,          F2 = k2 y2 + r2 y2'
//     GRF = F2.
//   Contact force lambda = M (m1 g + F1) / (M + m1); separation when < 0.
// Model 4 (Fig. 2d, "with interface spring-damper"): massless element 1
//   between the impactor and m1 (unilateral, as Model 1), element 2 between
//   m1 and m2, element 3 between m2 and the ground:
//     M y0'' = M g - F1,   F1 = k1 (y0 - y1) + r1 (y0' - y1')  (clamped >= 0)
//     m1 y1'' = F1 - F2,   F2 = k2 (y1 - y2) + r2 (y1' - y2')
//     m2 y2'' = F2 - F3,   F3 = k3 y2 + r3 y2'
//     GRF = F3.
//   Element 1 stands for the carpet and the interface (the paper: "the top
//   layer also includes the foot soft tissue stiffness"), m1 the stiff layer
//   (2.44 kg incl. carpet), m2 the soft layer (3.66 kg).
//
// The paper's "z_i = vertical spring displacement" are the element
// compressions d_j above. Layer masses come from the session manifest.
//
// Surface output ("mat top-surface travel under the impactor"): Models 1
// and 4, the top of element 1 (the impactor face in contact; ground/m1 plus
// the relaxing compression e after separation); Models 2 and 3, the mass
// under the impactor.
//
// Integration (exact discrete form, Models 1-4 without effects): each phase
// is linear, X' = A X with a constant state carrying gravity, so one output
// step h is X(t+h) = exp(A h) X(t) exactly; exp by scaling and squaring.
// The phase switch is located inside the step (Hermite cubic on the contact
// force, then a Newton step on the exact trajectory) and the step finished
// in the new phase. With effects on, RK4 with the contact force clamped
// inside each stage and the phase switched at the step's end.
#include "fitting/models.h"

#include <fmt/format.h>

#include <cctype>
#include <cmath>

#include "core/error.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting {

std::string model_name(ModelKind kind) {
  return "model" + std::to_string(static_cast<int>(kind));
}

ModelKind model_from_name(const std::string& name) {
  std::string s;
  for (char c : name) s += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (s.rfind("model", 0) == 0) s = s.substr(5);
  if (s.size() == 1 && s[0] >= '1' && s[0] <= '5') return static_cast<ModelKind>(s[0] - '0');
  throw Error(fmt::format("unknown mat model '{}' (expected model1 .. model5)", name));
}

namespace {

void check_finite_nonneg(double v, const char* name) {
  if (!std::isfinite(v) || v < 0.0)
    throw Error(fmt::format("mat parameter {} = {} must be finite and >= 0", name, v));
}

void validate(ModelKind kind, const MatParams& p, const Impact& imp) {
  if (kind == ModelKind::Model5)
    throw Error("simulate(): Model 5 is the geometric model, see fitting/model5.h");
  if (!(imp.mass_kg > 0.0) || !std::isfinite(imp.mass_kg))
    throw Error(fmt::format("impactor mass {} kg must be positive", imp.mass_kg));
  if (!std::isfinite(imp.velocity_m_s) || imp.velocity_m_s < 0.0)
    throw Error(fmt::format("impact velocity {} m/s must be >= 0 (downward)", imp.velocity_m_s));
  if (!(imp.output_dt_s > 0.0) || !(imp.duration_s > 0.0) || !std::isfinite(imp.duration_s))
    throw Error(fmt::format("simulation timing: duration {} s and step {} s must be positive",
                            imp.duration_s, imp.output_dt_s));
  if (imp.duration_s / imp.output_dt_s > 1e7)
    throw Error("simulation: more than 1e7 output samples requested");
  if (!std::isfinite(imp.gravity_m_s2)) throw Error("gravity must be finite");
  if (!(imp.first_output_s >= 0.0 && imp.first_output_s < imp.output_dt_s))
    throw Error(fmt::format("first output time {} s must lie in [0, output step)", imp.first_output_s));
  const int n = static_cast<int>(kind);
  check_finite_nonneg(p.k1_n_m, "k1_n_m");
  check_finite_nonneg(p.r1_n_s_m, "r1_n_s_m");
  if (!(p.k1_n_m > 0.0)) throw Error("mat parameter k1_n_m must be positive");
  if (n >= 3) {
    check_finite_nonneg(p.k2_n_m, "k2_n_m");
    check_finite_nonneg(p.r2_n_s_m, "r2_n_s_m");
    if (!(p.k2_n_m > 0.0)) throw Error("mat parameter k2_n_m must be positive");
    if (!(p.m1_kg > 0.0) || !(p.m2_kg > 0.0) || !std::isfinite(p.m1_kg + p.m2_kg))
      throw Error(fmt::format("{} needs positive layer masses (m1 {} kg, m2 {} kg)",
                              model_name(kind), p.m1_kg, p.m2_kg));
  }
  if (n == 4) {
    check_finite_nonneg(p.k3_n_m, "k3_n_m");
    check_finite_nonneg(p.r3_n_s_m, "r3_n_s_m");
    if (!(p.k3_n_m > 0.0)) throw Error("mat parameter k3_n_m must be positive");
  }
  if (n == 2) check_finite_nonneg(p.m_eff_kg, "m_eff_kg");
  if (!std::isfinite(p.k1_cubic_n_m3) || !std::isfinite(p.r1_unload_n_s_m) ||
      !std::isfinite(p.maxwell_k_n_m) || !std::isfinite(p.maxwell_tau_s) || !std::isfinite(p.k1_unload_ratio))
    throw Error("mat effect parameters must be finite");
  if (!(p.k1_unload_ratio >= 0.0 && p.k1_unload_ratio < 1.0) || !(p.k1_unload_speed_m_s > 0.0))
    throw Error("mat parameter k1_unload_ratio must be in [0, 1) and k1_unload_speed_m_s positive");
}

}  // namespace

Simulation simulate(ModelKind kind, const MatParams& params, const Impact& impact) {
  return simulate(kind, params, impact, SimulateOptions{});
}

Simulation simulate(ModelKind kind, const MatParams& params, const Impact& impact,
                    const SimulateOptions& options) {
  validate(kind, params, impact);
  const bool effects = params.has_effects();
  bool exact = !effects;
  if (options.method == SimulateOptions::Method::Exact) {
    if (effects) throw Error("simulate(): the exact integrator handles linear models only (effects are on)");
    exact = true;
  } else if (options.method == SimulateOptions::Method::RK4) {
    exact = false;
  }
  if (!exact && !(options.rk4_max_step_s > 0.0)) throw Error("simulate(): rk4_max_step_s must be positive");
  const int n = static_cast<int>(
                    std::floor((impact.duration_s - impact.first_output_s) / impact.output_dt_s + 1e-9)) + 1;
  const detail::Layout layout = detail::layout_for(kind, params.m_eff_kg <= 0.0);
  const auto p = detail::to_params_t<double>(kind, params);
  detail::Trace<double> tr;
  detail::run_model<double>(layout, p, impact, exact, options.rk4_max_step_s, n, tr);

  Simulation sim;
  sim.t_s.resize(n);
  for (int i = 0; i < n; ++i) sim.t_s[i] = impact.first_output_s + i * impact.output_dt_s;
  sim.grf_n = Eigen::Map<const Eigen::VectorXd>(tr.grf.data(), n);
  sim.impactor_m = Eigen::Map<const Eigen::VectorXd>(tr.impactor.data(), n);
  sim.surface_m = Eigen::Map<const Eigen::VectorXd>(tr.surface.data(), n);
  sim.layer1_m = Eigen::Map<const Eigen::VectorXd>(tr.layer1.data(), n);
  sim.layer2_m = Eigen::Map<const Eigen::VectorXd>(tr.layer2.data(), n);
  if (tr.separated) sim.separation_s = tr.separation_s;
  return sim;
}

std::vector<std::string> parameter_names(ModelKind kind, bool with_masses) {
  switch (kind) {
    case ModelKind::Model1:
      return {"k1_n_m", "r1_n_s_m"};
    case ModelKind::Model2:
      if (with_masses) return {"k1_n_m", "r1_n_s_m", "m_eff_kg"};
      return {"k1_n_m", "r1_n_s_m"};
    case ModelKind::Model3:
      if (with_masses) return {"k1_n_m", "k2_n_m", "r1_n_s_m", "r2_n_s_m", "m1_kg", "m2_kg"};
      return {"k1_n_m", "k2_n_m", "r1_n_s_m", "r2_n_s_m"};
    default:
      if (with_masses)
        return {"k1_n_m", "k2_n_m", "k3_n_m", "r1_n_s_m", "r2_n_s_m", "r3_n_s_m", "m1_kg", "m2_kg"};
      return {"k1_n_m", "k2_n_m", "k3_n_m", "r1_n_s_m", "r2_n_s_m", "r3_n_s_m"};
  }
}

namespace {
double* field(MatParams& p, const std::string& name) {
  if (name == "k1_n_m") return &p.k1_n_m;
  if (name == "k2_n_m") return &p.k2_n_m;
  if (name == "k3_n_m") return &p.k3_n_m;
  if (name == "r1_n_s_m") return &p.r1_n_s_m;
  if (name == "r2_n_s_m") return &p.r2_n_s_m;
  if (name == "r3_n_s_m") return &p.r3_n_s_m;
  if (name == "m_eff_kg") return &p.m_eff_kg;
  if (name == "m1_kg") return &p.m1_kg;
  if (name == "m2_kg") return &p.m2_kg;
  if (name == "k1_cubic_n_m3") return &p.k1_cubic_n_m3;
  if (name == "r1_unload_n_s_m") return &p.r1_unload_n_s_m;
  if (name == "maxwell_k_n_m") return &p.maxwell_k_n_m;
  if (name == "maxwell_tau_s") return &p.maxwell_tau_s;
  if (name == "k1_unload_ratio") return &p.k1_unload_ratio;
  if (name == "k1_unload_speed_m_s") return &p.k1_unload_speed_m_s;
  throw Error(fmt::format("unknown mat parameter '{}'", name));
}
}  // namespace

double get_parameter(const MatParams& params, const std::string& name) {
  MatParams copy = params;
  return *field(copy, name);
}

void set_parameter(MatParams& params, const std::string& name, double value) {
  *field(params, name) = value;
}

MatParams paper_table2(ModelKind kind, double m_eff_kg) {
  MatParams p;
  p.m1_kg = 2.44;
  p.m2_kg = 3.66;
  switch (kind) {
    case ModelKind::Model1:
    case ModelKind::Model2:
      p.k1_n_m = 84183; p.r1_n_s_m = 5700;
      p.m_eff_kg = kind == ModelKind::Model2 ? m_eff_kg : 0.0;
      break;
    case ModelKind::Model3:
      p.k1_n_m = 76700; p.k2_n_m = 807380; p.r1_n_s_m = 490; p.r2_n_s_m = 980;
      break;
    case ModelKind::Model4:
      p.k1_n_m = 72075; p.k2_n_m = 1061532; p.k3_n_m = 748625;
      p.r1_n_s_m = 263; p.r2_n_s_m = 761; p.r3_n_s_m = 1007;
      break;
    case ModelKind::Model5:
      p.k1_n_m = 70880; p.k2_n_m = 787200; p.k3_n_m = 617120;
      p.r1_n_s_m = 260; p.r2_n_s_m = 280; p.r3_n_s_m = 850;
      break;
  }
  return p;
}

}  // namespace dropfit::fitting
