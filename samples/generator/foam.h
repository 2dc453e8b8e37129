#pragma once
// The generator's foam mat: a continuum, not a chain of lumps. A 1-D column
// of two foams under the impactor's footprint, its own law and its own
// explicit integrator (nothing shared with fitting/, see physics.h).
//
// Each of the n_top + n_base finite elements (masses lumped at the nodes,
// the bottom node on the plate) carries, at compressive strain e:
//   elastic  s_e(e) = s_p (1 - exp(-E e / s_p)) + H e + D ((e_d / (e_d - e))^n - 1)
//            (a Gibson-Ashby-like curve: linear E at small strain, a
//            plateau near s_p rising with H, densification diverging at
//            e_d; in tension E e);
//   memory   two relaxing stresses q_i with dq_i/dt = g_i ds_e/dt - q_i / tau_i;
//   viscous  eta de/dt;
// element force = area (s_e + q_1 + q_2 + eta de/dt). The impactor and the
// top node move together while the contact pushes (a plastic collision at
// first contact and at every landing); the impactor flies freely otherwise.
// Coordinates as physics.h: travel downwards from the mat at rest under its
// own weight (each element's static strain solved from its law); the plate
// reads the bottom element's force less its static value.
//
// Integration: semi-implicit (symplectic) Euler at a fixed 1 us step, the
// memory by its exact exponential update over the step; after the
// impactor is caught (catch_at_apex) and the column has had 50 ms to
// settle, 10 us steps.
#include "samples/generator/physics.h"

namespace dropfit::synth {

struct FoamLayer {
  double thickness_m = 0.11;
  double mass_kg = 2.4;
  double plateau_pa = 3.0e3;       // s_p
  double modulus_pa = 6.0e4;       // E
  double hardening_pa = 4.0e4;     // H
  double densification_pa = 600.0; // D
  double densification_strain = 0.85;  // e_d
  double densification_exponent = 2.0; // n
};

struct FoamColumn {
  FoamLayer top;
  FoamLayer base{0.08, 3.6, 5.0e4, 1.0e6, 1.2e5, 6.0e3, 0.8, 2.0};
  double g1 = 0.5, tau1_s = 2.5e-3;  // the two relaxing stresses
  double g2 = 0.3, tau2_s = 4.0e-2;
  double viscosity_pa_s = 300.0;
  double area_m2 = 0.0625;
  int n_top = 16, n_base = 10;
};

// The elastic stress of a layer at strain e (Pa), public for the tests.
double foam_stress_pa(const FoamLayer& layer, double strain);

// One impact on the column: ChainSimulation as simulate_chain fills it
// (layer1_m: the middle of the top foam, where the mat's markers see its
// dish; layer2_m: the interface between the foams). Throws dropfit::Error
// for an impossible column.
ChainSimulation simulate_foam_column(const FoamColumn& column, const ChainImpact& impact);

}  // namespace dropfit::synth
