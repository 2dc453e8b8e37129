#pragma once
// The landing-mat models of Mills, Pain & Yeadon (2006), Figure 2, driven
// by an impactor of mass M landing at speed v0 under gravity g.
//
// Coordinates: every position is travel downwards (metres) from where that
// point sat at the instant of first contact, with the mat at rest under its
// own weight; positive = mat compressed. Gravity acts on the impactor in
// full; the mat masses' weights are carried by the static pre-compression
// of the springs below them, so in these deviation coordinates gravity on a
// mat mass cancels, and the ground reaction force (GRF) is the change of the
// plate's reading from static: what a plate zeroed with the mat at rest
// reads. The impactor-mat contact is unilateral: the impactor leaves the
// mat when the contact force would pull, and lands again (re-contact) when
// it catches up with the mat surface.
//
//   Model 1 (Fig. 2a): impactor M on a massless spring-damper (k1, r1) on
//                      the ground. GRF = contact force
//                      = max(k1 x + r1 xdot, 0) while in contact, else 0.
//   Model 2 (Fig. 2b): Model 1 plus the mat's effective mass m_eff, which
//                      moves with the impactor while in contact and sits on
//                      (k1, r1). At first contact impactor and m_eff share
//                      momentum (a perfectly plastic collision). GRF =
//                      k1 x + r1 xdot = contact force + m_eff * (upward
//                      acceleration): the "effective mass times impactor
//                      acceleration" of Pain, Mills & Yeadon (2005).
//   Model 3 (Fig. 2c): impactor resting rigidly on the top layer m1 while in
//                      contact (plastic collision at first contact);
//                      m1 -(k1, r1)- m2 -(k2, r2)- ground.
//                      GRF = k2 x2 + r2 x2dot.
//   Model 4 (Fig. 2d): impactor -(k1, r1)- m1 -(k2, r2)- m2 -(k3, r3)- ground;
//                      element 1 is unilateral (it pushes, never pulls).
//                      GRF = k3 x2 + r3 x2dot.
//   Model 5:           geometric, area-elastic: see fitting/model5.h.
//
// Element 1 (k1, r1) of every model can carry extra effects, all off by
// default: a cubic hardening term, a separate damping while it extends
// (hysteresis) and a Maxwell arm (rate dependence, relaxation):
//   F1 = (k1 d + k1_cubic d^3) a(ddot) + r(ddot) ddot + Fm,
//   a(ddot) = 1 - h (1 - tanh(ddot / v_s)) / 2 (elastic asymmetry, h = 0: off),
//   r(ddot) = r1 while compressing (ddot > 0), r1_unload while extending,
//   dFm/dt = maxwell_k ddot - Fm / maxwell_tau,
// d being element 1's compression. Mat layers are joined bilaterally (the
// frame and the layers' own weight keep them together).
//
// Integration: the linear models (no effects) use the exact discrete form of
// each linear phase (matrix exponential over one output step) with the
// contact/separation instants located inside the step; with effects on, a
// fixed-step RK4 whose step divides the output step. Both are templated on
// the scalar type (fitting/models_impl.h) so Ceres Jets flow through.
// Full derivation: fitting/models.cpp and docs/models.md.
#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

namespace dropfit::fitting {

enum class ModelKind { Model1 = 1, Model2 = 2, Model3 = 3, Model4 = 4, Model5 = 5 };

std::string model_name(ModelKind kind);  // "model1" ... "model5"
// Inverse of model_name; also accepts "1".."5" and "Model4". Throws Error.
ModelKind model_from_name(const std::string& name);

// All parameters, SI. A model uses the subset listed above:
//   Model 1: k1, r1.  Model 2: k1, r1, m_eff.  Model 3: k1, k2, r1, r2, m1, m2.
//   Model 4: k1..k3, r1..r3, m1, m2.
struct MatParams {
  double k1_n_m = 0.0, k2_n_m = 0.0, k3_n_m = 0.0;
  double r1_n_s_m = 0.0, r2_n_s_m = 0.0, r3_n_s_m = 0.0;
  double m_eff_kg = 0.0;          // Model 2
  double m1_kg = 0.0, m2_kg = 0.0;  // Models 3-5: top and bottom layer masses
  // Effects (closing the loop); zero / negative = off.
  double k1_cubic_n_m3 = 0.0;     // stiffening: F1 = k1 x + k1_cubic x^3 + ...
  double r1_unload_n_s_m = -1.0;  // hysteresis: damping of element 1 while it extends
  double maxwell_k_n_m = 0.0;     // rate dependence: Maxwell arm (spring k, time constant tau)
  double maxwell_tau_s = 0.0;     //   in parallel with element 1
  // Elastic asymmetry (a foam's hysteresis loop): element 1's elastic force
  // (k1 d + k1_cubic d^3) times 1 - h (1 - tanh(ddot / v_s)) / 2, i.e.
  // lower by the fraction h while it extends, switching smoothly over the
  // compression rate v_s (a separate unloading curve, not extra damping).
  double k1_unload_ratio = 0.0;        // h in [0, 1)
  double k1_unload_speed_m_s = 0.05;   // v_s

  bool has_effects() const {
    return k1_cubic_n_m3 != 0.0 || r1_unload_n_s_m >= 0.0 || k1_unload_ratio > 0.0 ||
           (maxwell_k_n_m > 0.0 && maxwell_tau_s > 0.0);
  }
};

struct Impact {
  double mass_kg = 24.0;
  double velocity_m_s = 5.0;   // downward, at first contact
  double gravity_m_s2 = 9.81;
  double duration_s = 0.3;     // simulated time from first contact
  double output_dt_s = 1e-3;   // spacing of the returned samples (the plate's)
  double first_output_s = 0.0; // time of the first returned sample, in [0, output_dt_s)
};

struct Simulation {
  Eigen::VectorXd t_s;         // from first contact: first_output_s + i * output_dt_s
  Eigen::VectorXd grf_n;       // ground reaction force on the plate (zeroed with the mat at rest)
  Eigen::VectorXd impactor_m;  // contact-face travel below the undeformed mat top
  // Mat top-surface travel under the impactor: the top of element 1 in
  // Models 1 and 4 (equal to impactor_m while in contact, recovering on its
  // own after separation), the mass under the impactor in Models 2 and 3.
  Eigen::VectorXd surface_m;
  // Travel of the mat masses (Models 2: m_eff; 3, 4: m1, m2), zero if absent.
  Eigen::VectorXd layer1_m, layer2_m;
  double separation_s = std::numeric_limits<double>::quiet_NaN();  // impactor left the mat
};

struct SimulateOptions {
  enum class Method {
    Auto,   // Exact for linear models, RK4 when an effect is on
    Exact,  // matrix-exponential discrete form (linear models only; throws otherwise)
    RK4,    // fixed-step RK4 (the fine-step reference too)
  };
  Method method = Method::Auto;
  // RK4 step: the output step divided evenly, at most this, at most 0.5 / w
  // for the fastest oscillation and 1 / d for the fastest decay (bounds from
  // the stiffnesses, dampings and masses; fitting/models_impl.h). 0.25 ms:
  // against a 1 us reference the force stays within 0.002 % of its peak
  // (0.15 N, a tenth of a plate's noise) on fitted mats with every effect;
  // the w and d bounds set the step on stiff or damped mats (docs/models.md).
  double rk4_max_step_s = 2.5e-4;
};

// Simulates one impact. Throws dropfit::Error for parameters the model cannot
// use (negative stiffness or damping, a missing layer mass, bad timing).
Simulation simulate(ModelKind kind, const MatParams& params, const Impact& impact);
Simulation simulate(ModelKind kind, const MatParams& params, const Impact& impact,
                    const SimulateOptions& options);

// The parameter names a model uses ("k1_n_m", "r1_n_s_m", "m1_kg", ...),
// in a fixed order, and access to them by name (throws Error if unknown).
std::vector<std::string> parameter_names(ModelKind kind, bool with_masses);
double get_parameter(const MatParams& params, const std::string& name);
void set_parameter(MatParams& params, const std::string& name, double value);

// The paper's Table 2 parameters (Models 1-4; Model 5 as published), with
// the manifest layer masses (m1 = 2.44 kg stiff layer incl. carpet, m2 =
// 3.66 kg soft layer). Model 2's m_eff is not published: m_eff_kg is given.
MatParams paper_table2(ModelKind kind, double m_eff_kg = 0.0);

}  // namespace dropfit::fitting
