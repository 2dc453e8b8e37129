#pragma once
// Model 6: the landing mat as a continuum, a discretised 1-D foam column.
//
// Models 1-4 lump the mat into one to three masses on linear springs. A
// foam mat is a continuum: the impact's stress travels down through the
// thickness (the plate feels it later than the face), each foam stiffens
// in a plateau and then densifies, and its stress remembers the strain
// history (viscoelastic relaxation). Model 6 keeps those three.
//
// Geometry: a column under the impactor's footprint (area_m2) of two foam
// layers, a top layer (top_thickness_m, top_mass_kg) over a base layer
// (base_thickness_m, base_mass_kg), cut into n_top and n_base equal
// elements; each element's mass is lumped half on each of its two nodes.
// Node 0 is the top face, node N = n_top + n_base rests on the plate.
//
// Constitutive law of an element at compressive engineering strain e
// (positive = compressed), one law per layer:
//   elastic   s_e(e) = s_p tanh(E e / s_p) + H e + D (e / (e_d - e))^n
//             E: initial modulus (the linear part up to about s_p / E),
//             s_p: plateau stress, H: plateau hardening modulus,
//             D, e_d, n: densification (the stress diverges as e -> e_d,
//             the strain at which the cells are fully collapsed). Past
//             0.97 e_d the curve continues along its tangent (a finite
//             stiffness for the integrator's Newton steps; a mat is never
//             driven there by a fitted impact).
//   memory    quasi-linear viscoelasticity (Fung): two Prony terms
//             q_i(t) = g_i integral exp(-(t - s) / tau_i) d s_e(s),
//             the instantaneous response (1 + g_1 + g_2) times the
//             equilibrium one, relaxing with the time constants tau_i.
//   viscous   eta de/dt (air and cell-wall damping).
//   total     s = s_e + q_1 + q_2 + eta de/dt;  element force = A s.
// Each layer has its own elastic law; the memory (g_i, tau_i) and eta are
// shared by the two foams. How many of these numbers a fit frees (a base
// law tied to the top one by a stiffness ratio, say) is the fitter's
// choice, not the model's.
//
// Coordinates: node travel downwards from where it rests under the mat's
// own weight (the static strain of each element solved from its law), as
// in models.h; the plate force is the change of the bottom element's force
// from static (a zeroed plate). The impactor (mass M) lands on node 0 at
// speed v0 and they share momentum (a perfectly plastic collision of M
// with node 0's mass); they move together while the contact pushes, and
// the impactor flies freely once it would pull (M g - M a_0 < 0), landing
// again when it catches up with node 0.
//
// Integration: the trapezoidal rule (Newmark, beta 1/4, gamma 1/2),
// implicit, unconditionally stable for the chain whatever the foam's
// tangent stiffness; each step solves the tridiagonal nonlinear system by
// Newton's method (Thomas algorithm) to a relative residual of 1e-10; the
// Prony terms advance by their exact exponential recursion with the
// elastic stress linear over the step. The contact state is that at the
// step's start. Templated on the scalar type (fitting/model6_impl.h) so
// ceres::Jet flows through for the fitter's exact derivatives; branches
// follow scalar parts.
#include <Eigen/Core>

#include "fitting/models.h"

namespace dropfit::fitting {

struct FoamLaw {
  double plateau_pa = 3.0e3;           // s_p
  double modulus_pa = 6.0e4;           // E
  double hardening_pa = 5.0e4;         // H
  double densification_pa = 500.0;     // D
  double densification_strain = 0.85;  // e_d
  double densification_exponent = 2.0;  // n
};

struct Model6Params {
  FoamLaw top;                        // the top layer's law
  FoamLaw base{4.0e4, 8.0e5, 1.0e5, 6.0e3, 0.8, 2.0};  // the base layer's
  double prony_g1 = 0.5, prony_tau1_s = 2e-3;
  double prony_g2 = 0.3, prony_tau2_s = 4e-2;
  double viscosity_pa_s = 50.0;       // eta
  double top_mass_kg = 2.4, base_mass_kg = 3.6;
};

struct Model6Geometry {
  double area_m2 = 0.0625;      // the impactor's footprint
  double top_thickness_m = 0.11;
  double base_thickness_m = 0.08;
  int n_top = 6;                // elements per layer
  int n_base = 4;
  double max_step_s = 1e-4;     // integration step: the output step divided evenly, at most this
};

// The elastic stress of a law at strain e (Pa), public for tests.
double foam_elastic_stress_pa(const FoamLaw& law, double strain);

struct Model6Result {
  Simulation sim;               // grf_n, impactor_m, surface_m (= node 0), layer1_m (layer interface), layer2_m (0)
  Eigen::VectorXd top_strain;   // the top element's strain per sample
  Eigen::VectorXd base_strain;  // the bottom element's
  double max_top_strain = 0.0, max_base_strain = 0.0;  // their largest values
  long steps = 0;
  double step_s = 0.0;
};

// Simulates one impact. Throws dropfit::Error for parameters the model
// cannot use (non-positive moduli, masses or sizes, e_d outside (0, 1]).
Model6Result simulate_model6_detailed(const Model6Params& params, const Model6Geometry& geometry,
                                      const Impact& impact);
Simulation simulate_model6(const Model6Params& params, const Model6Geometry& geometry, const Impact& impact);

}  // namespace dropfit::fitting
