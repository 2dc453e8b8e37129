#pragma once
// The landing-mat models of Mills, Pain & Yeadon (2006), Figure 2, driven
// by an impactor of known mass landing at a known velocity. Coordinates are
// travel downwards from the position at first contact (positive = mat
// compressed); the impactor leaves the mat when the contact force would
// pull (no sticking).
//
// The mapping of each model onto the paper's Figure 2, its parameters and
// the ground reaction force (GRF = what the zeroed plate reads) is written
// out in detail in fitting/models.cpp's header comment and in
// docs/models.md; in short:
//
//   Model 1 (Fig. 2a): impactor M on a massless spring-damper (k1, r1).
//   Model 2 (Fig. 2b): Model 1 plus the mat's effective mass m_eff moving
//                      with the impactor.
//   Model 3 (Fig. 2c): impactor on the top layer m1; m1 -(k1, r1)- m2;
//                      m2 -(k2, r2)- ground.
//   Model 4 (Fig. 2d): impactor -(k1, r1)- m1 -(k2, r2)- m2 -(k3, r3)- ground.
//   Model 5:           geometric, area-elastic: see fitting/model5.h.
//
// Effects that closing the loop may add (all off by default) act on the
// element under the impactor (k1, r1): a cubic hardening term, a separate
// unloading damping (hysteresis) and a Maxwell arm (rate dependence).
#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

namespace dropfit::fitting {

enum class ModelKind { Model1 = 1, Model2 = 2, Model3 = 3, Model4 = 4, Model5 = 5 };

std::string model_name(ModelKind kind);  // "model1" ... "model5"

// All parameters, SI. A model uses the subset listed above.
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
};

struct Impact {
  double mass_kg = 24.0;
  double velocity_m_s = 5.0;   // downward, at first contact
  double gravity_m_s2 = 9.81;
  double duration_s = 0.3;     // simulated time from first contact
  double output_dt_s = 1e-3;   // spacing of the returned samples (the plate's)
};

struct Simulation {
  Eigen::VectorXd t_s;         // from first contact, output_dt_s apart
  Eigen::VectorXd grf_n;       // ground reaction force on the plate (zeroed with the mat at rest)
  Eigen::VectorXd impactor_m;  // contact-face travel below the undeformed mat top
  Eigen::VectorXd surface_m;   // mat top-surface travel under the impactor
  double separation_s = std::numeric_limits<double>::quiet_NaN();  // impactor left the mat
};

Simulation simulate(ModelKind kind, const MatParams& params, const Impact& impact);

}  // namespace dropfit::fitting
