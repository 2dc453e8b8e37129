#pragma once
// Model 5: the geometric, area-elastic landing-mat model.
//
// Mills, Pain & Yeadon (2006), J. Appl. Biomech. 22:103, built their Model 5
// in visual Nastran 4D: the mat layers as solid shapes with their real
// dimensions and densities, separated by the same linear springs as Model 4,
// and the impactor a rigid body (28 s per simulation). This is a fast
// stand-in for it (about 1-2 ms per 0.3 s impact) that keeps what the
// geometry adds: the impactor's finite face, off-centre and tilted impacts,
// and a mat that deforms over an area larger than the face.
//
// ---------------------------------------------------------------------------
// Geometry and coordinates
//
//   x along the mat's length (mat_length_m), y along its width (mat_width_m),
//   origin at the mat's centre; vertical coordinates are travel DOWNWARDS
//   from the rest position (positive = mat compressed), as in models.h.
//   Each layer is cut into nodes_x x nodes_y equal cells (default 9 x 6 =
//   0.10 m x 0.10 m cells on the 0.90 m x 0.60 m mat); one lumped node per
//   cell at the cell's centre carries the layer's mass times the cell's
//   share of the mat's area (m1_kg / N and m2_kg / N for N cells).
//
// Vertical elements (per node column; k_i, r_i are TOTALS, as in Model 4)
//
//   impactor face -> top node j   : k1 * w_j, r1 * w_j, unilateral (below)
//   top node j -> bottom node j   : k2 * a_j, r2 * a_j   (a_j = 1 / N)
//   bottom node j -> ground/plate : k3 * a_j, r3 * a_j
//
//   w_j = (area of cell j under the impactor's face) / (face area): the face
//   covers a fixed rectangle footprint_length_m x footprint_width_m centred
//   at (impact_x_m, impact_y_m); weights sum to 1 when the whole face lies
//   on the mat (less when it overhangs an edge). The contact point of cell j
//   is the centroid c_j of that overlap rectangle; the face's travel there is
//       u_j = z_c + tilt_x * (c_jx - impact_x) + tilt_y * (c_jy - impact_y)
//   and element 1 of column j, massless as in Model 4, pushes node j down
//   and the face up with
//       f_j = k1 w_j d_j + r1 w_j d'_j,   d_j = u_j - z1_j,
//   while the face presses it (from the moment the face reaches the
//   element's top, d_j >= e_j, until f_j would pull); then the face leaves
//   that node and the element's top relaxes on its own, k1 e_j + r1 e_j' = 0
//   (Model 4's element 1, node by node). r1 is replaced by r1_unload while
//   d'_j < 0 (and in the relaxation) when that effect is on; k1_cubic adds
//   k1_cubic * w_j * d_j^3. With the face covering the mat, or one cell per
//   layer, and the layers moving as a whole, the sums are exactly Model 4's
//   elements: a uniform compression
//   of this model IS Model 4.
//
// Shear coupling (what makes it area-elastic): a Pasternak foundation
// (Pasternak 1954; Kerr 1964, J. Appl. Mech. 31:491, "Elastic and
// viscoelastic foundation models"): each layer l resists differences of
// vertical travel between neighbouring cells like a membrane,
//       load per area = -S_l * laplacian(z_l) - C_l * laplacian(z'_l),
// S_l [N/m] the layer's shear rigidity (shear modulus x thickness, i.e.
// force per metre of edge per unit slope), C_l [N s/m] its damping analogue.
// Finite differences turn it into a spring-damper between each pair of
// neighbouring cells:
//       along x: S_l * dy / dx  [N/m per pair],  C_l * dy / dx  [N s/m]
//       along y: S_l * dx / dy  [N/m per pair],  C_l * dx / dy  [N s/m]
// (dx, dy the cell size; on square cells the pair stiffness equals S_l), so
// S_l and C_l mean the same whatever the grid. S = 0 leaves every node
// column independent (point-elastic); S -> infinity makes each layer move as
// one flat plate: Model 4 again. Unlike the paper's rigid solids, a layer
// here resists tilting as much as any other unevenness (a membrane, not a
// rigid plate).
//
// Edges: MatEdge::Free leaves the outer cells without neighbours outside;
// MatEdge::Framed ties each edge cell to the surrounding frame (travel 0)
// with the same shear law over half a cell (2 S_l dy/dx per edge link along
// x, 2 S_l dx/dy along y), as the paper's wooden frame, bolted to the plate,
// held its sample mat. The frame's reaction is part of the GRF.
//
// Impactor: a rigid body of mass impact.mass_kg that translates vertically
// and tilts about both horizontal axes through its face centre (small
// angles: tilt_x = dz/dx of the face, i.e. positive when its +x side is
// lower; tilt_y likewise). Moments of inertia: given, or those of a uniform
// block of the footprint's size and impactor_height_m (0 = flat plate:
// I = M a^2 / 12 for side a). Not modelled: horizontal motion of the
// impactor or the mat, the face's projection shrinking with tilt (cos),
// gravity's torque when tilted, layers lifting off each other or the plate
// (elements 2 and 3 stay linear and bilateral, as in Model 4).
//
// Initial state: mat at rest (gravity on the mat balanced by its springs,
// so it is left out and the GRF reads zero at rest, as a zeroed plate
// does); the face's lowest corner over the mat at the mat's top at t = 0,
// the face centre moving down at impact.velocity_m_s, tilting at the given
// rates. Gravity acts on the impactor.
//
// Outputs (fitting::Simulation, as Models 1-4 fill it): grf_n = sum over
// nodes of the element-3 forces plus the frame's reaction; impactor_m = the
// face centre's travel below the undeformed mat top; surface_m = element 1's
// top under the face centre (the face while it presses there, then the
// relaxing top: Model 4's meaning); layer1_m, layer2_m = the top and bottom
// layers' travel under the face centre (bilinear between cell centres,
// clamped at the outer centres); separation_s = first step at which the
// contact force is zero after it was positive (with the force at step
// starts). Sampled at t = impact.first_output_s + i * output_dt_s (as
// Models 1-4). For the fitter with exact derivatives:
// simulate_model5_t<T> in fitting/model5_impl.h (T = double or ceres::Jet).
//
// Default shear: S_1 = S_2 = 7e4 N/m gives the top layer's dent a volume /
// depth of 0.35 m^2 with the paper's Table 2 Model 5 parameters at 5.25 m/s
// (free edges), the ratio Pain, Mills & Yeadon (2005) measured on the mat
// surface (0.030-0.044 m^3 over 0.088-0.118 m); C = 5e-4 s x S. A starting
// value, to be fitted when the data carry the surface's shape.
//
// Integration (fitting/model5_impl.h; accuracy and speed in docs/models.md):
// the forces split in two. (A) The vertical elements 1-3 of every node
// column, the impactor's inertia and gravity: implicit, by a three-stage,
// L-stable, stiffly accurate SDIRK of order 3 (Alexander 1977). Per stage
// the linear system is solved exactly: the columns the face presses are
// eliminated (2 x 2 each) onto the impactor's three coordinates (3 x 3);
// the columns it does not press are independent and linear, and step by
// their exact 4 x 4 exponential. (B) The layers' shear coupling (and
// element 1's cubic term): explicit half kicks before and after each A step
// (Strang splitting; the shear damping sub-stepped inside the kick). The
// contact set holds over a step: a cell joins when the face reaches its
// element's top at the step's start, and a pressed cell whose contact
// impulse over the step would pull is released and the step redone. So
// stiffness and damping k, r set no stability limit: the step is
// output_dt_s / n, n the smallest integer giving dt <= max_step_s, dt <=
// stability_fraction * 2 / w_shear (w_shear a Gershgorin bound on the shear
// stiffness over the node masses: 3 500 rad/s with the default shear, 0.45
// ms), and, for an overdamped element (r^2 > 4 k m on its node) whose creep
// rate 2 k / (r + sqrt(r^2 - 4 k m)) is below creep_fast_1_s (2000 1/s),
// dt <= 0.07 / that rate (a faster creep is left to the stiffly accurate
// stages' quasi-static limit); the creep limit only while the face
// presses and the load is not slow (an output interval the face is sure to
// spend clear of the mat steps every column exactly and takes the step
// without it). Slow load: the stages' error on a stiff, slow creep (order
// reduction) and the shear's splitting error follow the curvature of the
// load, so an output interval whose mean contact force (from the
// impactor's momentum) has a second difference over the last three
// intervals of at most 0.01 (lambda x output_dt)^2 of its largest mean,
// with the same cells pressed, drops the creep limit; and from 0.1 s on
// (long contacts only: a typical impact is over by then, so its stepping,
// and the fitter's derivatives around it, are unaffected), one with at most
// 1e-3 of it steps at twice max_step_s, as does every pressed interval
// where elements 2 and 3 are lightly damped (r / m <= 3000 1/s). The
// decisions use scalar parts (the same steps for a Jet). The first output
// interval is stepped 8 times finer (the face lands at full speed on light
// cells). The explicit shear's splitting error grows where the layers are
// heavily damped (at landing); steps and accuracy against a 1 us reference
// over the fitter's bounds are in docs/models.md. The cubic term (k1_cubic)
// is explicit: keep max_step_s small enough for its tangent stiffness. Every element applies equal and
// opposite forces, so the GRF impulse balances the impactor's and the mat's
// momentum. Nothing is allocated inside the time loop. An independent
// explicit scheme (leapfrog, outside the library: bench/model5_leapfrog.h)
// serves as the reference in tests and benchmarks.
#include <Eigen/Core>

#include "fitting/models.h"

namespace dropfit::fitting {

enum class MatEdge { Free, Framed };

struct Model5Geometry {
  // The mat (the paper's sample: 0.90 m x 0.60 m).
  double mat_length_m = 0.90;  // along x
  double mat_width_m = 0.60;   // along y
  int nodes_x = 9;             // cells along x (>= 1)
  int nodes_y = 6;             // cells along y (>= 1)
  MatEdge edge = MatEdge::Free;

  // Shear coupling per layer (1 = top, 2 = bottom); see the header comment.
  double shear1_n_m = 7.0e4;           // S_1: top layer's shear rigidity
  double shear2_n_m = 7.0e4;           // S_2: bottom layer's
  double shear_damping1_n_s_m = 35.0;  // C_1
  double shear_damping2_n_s_m = 35.0;  // C_2

  // The impactor's face (the paper's: 0.25 m x 0.25 m) and where it lands.
  double footprint_length_m = 0.25;  // along x
  double footprint_width_m = 0.25;   // along y
  double impact_x_m = 0.0;           // face centre, from the mat's centre
  double impact_y_m = 0.0;
  double tilt_x0_rad = 0.0;          // initial dz/dx of the face (+ = +x side lower)
  double tilt_y0_rad = 0.0;          // initial dz/dy of the face
  double tilt_rate_x0_rad_s = 0.0;   // initial d(tilt_x)/dt
  double tilt_rate_y0_rad_s = 0.0;
  // Moments of inertia resisting tilt_x (about the y axis) and tilt_y (about
  // x), through the face centre. <= 0: a uniform block of the footprint and
  // impactor_height_m, M (side^2 + height^2) / 12.
  double impactor_height_m = 0.0;
  double inertia_tilt_x_kg_m2 = 0.0;
  double inertia_tilt_y_kg_m2 = 0.0;

  // Integration: largest step allowed (accuracy), and the fraction of the
  // shear's stability bound used (see the header comment; both may only be
  // lowered safely).
  double max_step_s = 1e-4;
  double stability_fraction = 0.8;
  // Accuracy on an overdamped element's creep (rate lambda, see the header
  // comment): steps with lambda dt <= creep_step, for creeps slower than
  // creep_fast_1_s (faster ones settle within half a millisecond and the
  // stiffly accurate stages give their quasi-static limit unresolved).
  double creep_step = 0.07;
  double creep_fast_1_s = 2000.0;
  // Slow load (see the header comment, Integration): an output interval
  // the face presses, with the same cells pressed at the last three
  // interval starts, whose mean contact force's second difference over the
  // last three intervals is at most creep_slow_load x (lambda x output_dt)^2
  // times its largest mean so far steps without the creep limit; if it is
  // also at most slow_step_load times that, at slow_step_factor x
  // max_step_s (within the shear's stability); where elements 2 and 3 damp
  // their nodes at rates r / m of at most slow_step_light_rate_1_s, every
  // interval the face presses takes that step. 0 (or factor 1): off.
  double creep_slow_load = 0.01;
  double slow_step_load = 1e-3;
  double slow_step_factor = 2.0;
  double slow_step_light_rate_1_s = 3000.0;
  // Slow-load steps (not the creep limit's lifting) only in output
  // intervals starting at or after slow_step_after_s.
  double slow_step_after_s = 0.1;
};

// Everything Model 5 can say about one impact.
struct Model5Result {
  Simulation sim;                        // as every model returns it
  Eigen::VectorXd impactor_velocity_m_s; // face centre, downwards, per sample
  Eigen::VectorXd tilt_x_rad;            // face slope dz/dx per sample
  Eigen::VectorXd tilt_y_rad;            // face slope dz/dy per sample
  Eigen::VectorXd mat_momentum_n_s;      // sum of node masses x velocities (downwards)
  // Top-layer travel field at the sample of peak GRF: row iy, column ix is
  // the cell centred at (node_x_m(ix), node_y_m(iy)).
  Eigen::MatrixXd surface_at_peak_m;
  Eigen::VectorXd node_x_m;              // cell centres along x (nodes_x)
  Eigen::VectorXd node_y_m;              // cell centres along y (nodes_y)
  double peak_grf_n = 0.0;
  double peak_time_s = 0.0;
  // The dent at peak GRF. layer_volume: the top layer's travel summed over
  // the cells (x cell area); deformed_volume: that plus, under the face, the
  // face's travel below the layer (element 1's compression), i.e. the volume
  // below the undeformed top that a camera sees (Pain, Mills & Yeadon 2005
  // measured 0.030-0.044 m^3). layer_dent_area: layer_volume over the
  // layer's travel under the face centre: the area a flat-bottomed dent of
  // the same depth would cover (the footprint's area for a point-elastic
  // layer, the mat's for a rigid one).
  double layer_volume_at_peak_m3 = 0.0;
  double deformed_volume_at_peak_m3 = 0.0;
  double layer_dent_area_at_peak_m2 = 0.0;
  double step_s = 0.0;                   // integration step used
  long steps = 0;                        // steps taken
};

// Simulates one impact. Throws dropfit::Error on impossible input
// (non-positive masses or sizes, negative stiffness or damping, a face that
// misses the mat, a Maxwell arm, which Model 5 does not carry).
Model5Result simulate_model5_detailed(const MatParams& params, const Model5Geometry& geometry,
                                      const Impact& impact);

// The same, as a black box (Simulation as Models 1-4 return it).
Simulation simulate_model5(const MatParams& params, const Model5Geometry& geometry,
                           const Impact& impact);

}  // namespace dropfit::fitting
