// The retired explicit Model 5 integrator (leapfrog, every force explicit,
// its step capped by the stiffest element's stability), kept outside the
// library as an independent reference: tests/model5_test.cpp checks the
// library's scheme against it at a 1 us step, and bench/model5_bench.cpp and
// bench/model5_scan.cpp compare steps and time. See bench/model5_leapfrog.h.
#include "bench/model5_leapfrog.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "core/error.h"
#include "fitting/model5_impl.h"

namespace dropfit::bench {

using namespace dropfit::fitting;
using model5_detail::bracket;
using model5_detail::overlap;

namespace {

using Grid = Eigen::ArrayXXd;  // rows = cells along y, columns = cells along x

void require(bool ok, const std::string& reason) {
  if (!ok) throw Error("model5: " + reason);
}

// Shear forces of one layer on its nodes (added into F) for pair stiffness
// and damping kx, cx (along x) and ky, cy (along y); frame links of twice
// that at the edges when framed. Returns the frame's share (downwards
// force on the frame, i.e. on the plate). Dx, Dy are scratch.
double add_shear(const Grid& Z, const Grid& V, double kx, double cx, double ky, double cy, bool framed,
                 Grid& F, Grid& Dx, Grid& Dy) {
  const Eigen::Index ny = Z.rows(), nx = Z.cols();
  if (nx > 1) {
    Dx = kx * (Z.rightCols(nx - 1) - Z.leftCols(nx - 1)) + cx * (V.rightCols(nx - 1) - V.leftCols(nx - 1));
    F.leftCols(nx - 1) += Dx;
    F.rightCols(nx - 1) -= Dx;
  }
  if (ny > 1) {
    Dy = ky * (Z.bottomRows(ny - 1) - Z.topRows(ny - 1)) + cy * (V.bottomRows(ny - 1) - V.topRows(ny - 1));
    F.topRows(ny - 1) += Dy;
    F.bottomRows(ny - 1) -= Dy;
  }
  if (!framed) return 0.0;
  // Links of 2 k over half a cell to the frame at travel 0.
  double to_frame = 0.0;
  const double kxe = 2.0 * kx, cxe = 2.0 * cx, kye = 2.0 * ky, cye = 2.0 * cy;
  for (Eigen::Index c : {Eigen::Index{0}, nx - 1}) {
    for (Eigen::Index r = 0; r < ny; ++r) {
      const double f = kxe * Z(r, c) + cxe * V(r, c);
      F(r, c) -= f;
      to_frame += f;
    }
  }
  for (Eigen::Index r : {Eigen::Index{0}, ny - 1}) {
    for (Eigen::Index c = 0; c < nx; ++c) {
      const double f = kye * Z(r, c) + cye * V(r, c);
      F(r, c) -= f;
      to_frame += f;
    }
  }
  return to_frame;
}

// Contact weights (face area share) W and lever arms Lx, Ly (overlap centroid from the face centre) per cell.
void leapfrog_contact(const Model5Geometry& geo, const Eigen::VectorXd& node_x_m, const Eigen::VectorXd& node_y_m,
                      double dx, double dy, Grid& W, Grid& Lx, Grid& Ly) {
  const int nx = geo.nodes_x, ny = geo.nodes_y;
  const double fx0 = geo.impact_x_m - 0.5 * geo.footprint_length_m, fx1 = geo.impact_x_m + 0.5 * geo.footprint_length_m;
  const double fy0 = geo.impact_y_m - 0.5 * geo.footprint_width_m, fy1 = geo.impact_y_m + 0.5 * geo.footprint_width_m;
  const double face_area = geo.footprint_length_m * geo.footprint_width_m;
  for (int ix = 0; ix < nx; ++ix) {
    const double cx = node_x_m(ix);
    double mx = 0.0;
    const double ox = overlap(cx - 0.5 * dx, cx + 0.5 * dx, fx0, fx1, &mx);
    for (int iy = 0; iy < ny; ++iy) {
      const double cy = node_y_m(iy);
      double my = 0.0;
      const double oy = overlap(cy - 0.5 * dy, cy + 0.5 * dy, fy0, fy1, &my);
      if (ox > 0.0 && oy > 0.0) {
        W(iy, ix) = ox * oy / face_area;
        Lx(iy, ix) = mx - geo.impact_x_m;
        Ly(iy, ix) = my - geo.impact_y_m;
      }
    }
  }
  require(W.sum() > 1e-9, fmt::format("the impactor's face at ({}, {}) m misses the {} x {} m mat", geo.impact_x_m,
                                      geo.impact_y_m, geo.mat_length_m, geo.mat_width_m));
}

// Per-node vertical elements of the leapfrog (see model5.h): k2, r2, k3, r3 and the node masses.
struct LeapfrogNode {
  double k2n, r2n, k3n, r3n, m1n, m2n;
};

// Shear links of the leapfrog along x and y, layer 1 then layer 2.
struct LeapfrogShear {
  double kx1, cx1, ky1, cy1, kx2, cx2, ky2, cy2;
};

// The leapfrog's step: the accuracy cap max_step_s and the explicit scheme's stability limit.
double leapfrog_step_limit(const Model5Geometry& geo, bool framed, const Grid& K1, const Grid& R1, const Grid& R1u,
                           const Grid& Lx, const Grid& Ly, const LeapfrogNode& node, const LeapfrogShear& shear,
                           double M, double I_tilt_x, double I_tilt_y) {
  const int nx = geo.nodes_x, ny = geo.nodes_y;
  const auto [k2n, r2n, k3n, r3n, m1n, m2n] = node;
  const auto [kx1, cx1, ky1, cy1, kx2, cx2, ky2, cy2] = shear;
  // Step: Gershgorin bounds on M^-1 K and M^-1 C (contact closed), then the
  // scheme's stability limit w^2 dt^2 + 4 gam dt = 4, halved.
  auto links = [](int count_x, int count_y, double px, double py) { return count_x * px + count_y * py; };
  double w2 = 0.0, gam = 0.0;
  for (int ix = 0; ix < nx; ++ix) {
    for (int iy = 0; iy < ny; ++iy) {
      const int nbx = (ix > 0) + (ix < nx - 1), nby = (iy > 0) + (iy < ny - 1);  // neighbours
      const int edx = framed ? (ix == 0) + (ix == nx - 1) : 0;                     // frame links
      const int edy = framed ? (iy == 0) + (iy == ny - 1) : 0;
      const double k1 = K1(iy, ix), r1 = std::max(R1(iy, ix), R1u(iy, ix));
      // Row sums |diagonal| + |off-diagonal|: coupled links count twice, frame links once.
      w2 = std::max(w2, (2.0 * (k1 + k2n + links(nbx, nby, kx1, ky1)) + links(edx, edy, 2 * kx1, 2 * ky1)) / m1n);
      gam = std::max(gam, (2.0 * (r1 + r2n + links(nbx, nby, cx1, cy1)) + links(edx, edy, 2 * cx1, 2 * cy1)) / m1n);
      w2 = std::max(w2, (2.0 * (k2n + links(nbx, nby, kx2, ky2)) + k3n + links(edx, edy, 2 * kx2, 2 * ky2)) / m2n);
      gam = std::max(gam, (2.0 * (r2n + links(nbx, nby, cx2, cy2)) + r3n + links(edx, edy, 2 * cx2, 2 * cy2)) / m2n);
    }
  }
  {
    const double ksum = K1.sum(), rsum = std::max(R1.sum(), R1u.sum());
    w2 = std::max(w2, 2.0 * ksum / M);
    gam = std::max(gam, 2.0 * rsum / M);
    const double krx = (K1 * Lx.square()).sum(), kry = (K1 * Ly.square()).sum();
    const double rrx = (R1.max(R1u) * Lx.square()).sum(), rry = (R1.max(R1u) * Ly.square()).sum();
    w2 = std::max({w2, 2.0 * krx / I_tilt_x, 2.0 * kry / I_tilt_y});
    gam = std::max({gam, 2.0 * rrx / I_tilt_x, 2.0 * rry / I_tilt_y});
  }
  double dt_limit = geo.max_step_s;
  if (w2 > 0.0 || gam > 0.0) {
    const double dt_stable = w2 > 0.0 ? 2.0 * (-gam + std::sqrt(gam * gam + w2)) / w2 : 1.0 / gam;
    dt_limit = std::min(dt_limit, geo.stability_fraction * dt_stable);
  }
  return dt_limit;
}

// One leapfrog run: the per-node constants, the state and the scratch (no allocation inside the loop).
struct Leapfrog {
  using Mask = Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic>;
  const MatParams& params;
  const Model5Geometry& geo;
  int nx, ny;
  bool framed;
  double dx, dy, x0, y0, fx0, fx1, fy0, fy1, face_area;
  Grid W, Lx, Ly, K1, R1, K1c, R1u;
  LeapfrogNode node{};
  LeapfrogShear shear{};
  double M, g, I_tilt_x = 0.0, I_tilt_y = 0.0, dt = 0.0, r_ext = 0.0, relax = 0.0;
  int px = 0, py = 0, px1 = 0, py1 = 0;
  double fxw = 0.0, fyw = 0.0;
  // State: V*, vc, wx, wy hold velocities at t_{n-1/2} (at t_0 for n = 0).
  Grid Z1, V1, Z2, V2;
  double tx, ty, wx, wy, zc = 0.0, vc;
  // Scratch, the accelerations of the last evaluation and the velocity estimates at t_n.
  Grid D, Dd, Fr, Surf, Fc, F12, Fg, S1, S2, Dx1, Dy1, A1, A2, E1, E2;
  double ac = 0.0, awx = 0.0, awy = 0.0, ec = 0.0, frame1 = 0.0, frame2 = 0.0;
  double f_contact = 0.0, torque_x = 0.0, torque_y = 0.0;
  // Element 1's compression (its top's travel below the top layer) and contact flags.
  Grid Top;
  Mask Face, In, Was;

  Leapfrog(const MatParams& p, const Model5Geometry& gm, const Impact& impact, Model5Result& out)
      : params(p), geo(gm), nx(gm.nodes_x), ny(gm.nodes_y), framed(gm.edge == MatEdge::Framed),
        dx(gm.mat_length_m / nx), dy(gm.mat_width_m / ny), x0(-0.5 * gm.mat_length_m + 0.5 * dx),
        y0(-0.5 * gm.mat_width_m + 0.5 * dy), fx0(gm.impact_x_m - 0.5 * gm.footprint_length_m),
        fx1(gm.impact_x_m + 0.5 * gm.footprint_length_m), fy0(gm.impact_y_m - 0.5 * gm.footprint_width_m),
        fy1(gm.impact_y_m + 0.5 * gm.footprint_width_m), face_area(gm.footprint_length_m * gm.footprint_width_m),
        M(impact.mass_kg), g(impact.gravity_m_s2), Z1(Grid::Zero(ny, nx)), V1(Grid::Zero(ny, nx)),
        Z2(Grid::Zero(ny, nx)), V2(Grid::Zero(ny, nx)), tx(gm.tilt_x0_rad), ty(gm.tilt_y0_rad),
        wx(gm.tilt_rate_x0_rad_s), wy(gm.tilt_rate_y0_rad_s), vc(impact.velocity_m_s), D(ny, nx), Dd(ny, nx),
        Fr(ny, nx), Surf(ny, nx), Fc(ny, nx), F12(ny, nx), Fg(ny, nx), S1(ny, nx), S2(ny, nx),
        Dx1(ny, std::max(nx - 1, 1)), Dy1(std::max(ny - 1, 1), nx), A1(Grid::Zero(ny, nx)), A2(Grid::Zero(ny, nx)),
        E1(ny, nx), E2(ny, nx), Top(Grid::Zero(ny, nx)), In(Mask::Constant(ny, nx, false)), Was(ny, nx) {
    out.node_x_m = Eigen::VectorXd::LinSpaced(nx, x0, x0 + (nx - 1) * dx);
    out.node_y_m = Eigen::VectorXd::LinSpaced(ny, y0, y0 + (ny - 1) * dy);
    if (nx == 1) out.node_x_m(0) = x0;
    if (ny == 1) out.node_y_m(0) = y0;
    W = Grid::Zero(ny, nx), Lx = Grid::Zero(ny, nx), Ly = Grid::Zero(ny, nx);
    leapfrog_contact(geo, out.node_x_m, out.node_y_m, dx, dy, W, Lx, Ly);
    Face = W > 0.0;
    set_elements(impact);
    // Surface probe under the face centre (bilinear among cell centres).
    bracket(geo.impact_x_m, x0, dx, nx, &px, &fxw);
    bracket(geo.impact_y_m, y0, dy, ny, &py, &fyw);
    px1 = std::min(px + 1, nx - 1), py1 = std::min(py + 1, ny - 1);
    // Lowest corner of the face's part over the mat touches the mat top at t = 0.
    const double cx0 = std::max(fx0, -0.5 * geo.mat_length_m) - geo.impact_x_m;
    const double cx1c = std::min(fx1, 0.5 * geo.mat_length_m) - geo.impact_x_m;
    const double cy0 = std::max(fy0, -0.5 * geo.mat_width_m) - geo.impact_y_m;
    const double cy1c = std::min(fy1, 0.5 * geo.mat_width_m) - geo.impact_y_m;
    zc = -std::max(tx * cx0, tx * cx1c) - std::max(ty * cy0, ty * cy1c);
  }

  // Per-node elements (see model5.h), shear links and the impactor's tilt inertias.
  void set_elements(const Impact& impact) {
    const double n_cells = static_cast<double>(nx) * ny;
    K1 = params.k1_n_m * W, R1 = params.r1_n_s_m * W, K1c = params.k1_cubic_n_m3 * W;
    R1u = (params.r1_unload_n_s_m >= 0.0 ? params.r1_unload_n_s_m : params.r1_n_s_m) * W;
    node = {params.k2_n_m / n_cells,  params.r2_n_s_m / n_cells, params.k3_n_m / n_cells,
            params.r3_n_s_m / n_cells, params.m1_kg / n_cells,    params.m2_kg / n_cells};
    shear = {geo.shear1_n_m * dy / dx, geo.shear_damping1_n_s_m * dy / dx, geo.shear1_n_m * dx / dy,
             geo.shear_damping1_n_s_m * dx / dy, geo.shear2_n_m * dy / dx, geo.shear_damping2_n_s_m * dy / dx,
             geo.shear2_n_m * dx / dy, geo.shear_damping2_n_s_m * dx / dy};
    const double h2 = geo.impactor_height_m * geo.impactor_height_m;
    const double m = impact.mass_kg;
    I_tilt_x = geo.inertia_tilt_x_kg_m2 > 0.0
                 ? geo.inertia_tilt_x_kg_m2
                 : m * (geo.footprint_length_m * geo.footprint_length_m + h2) / 12.0;
    I_tilt_y = geo.inertia_tilt_y_kg_m2 > 0.0
                 ? geo.inertia_tilt_y_kg_m2
                 : m * (geo.footprint_width_m * geo.footprint_width_m + h2) / 12.0;
  }

  // Fixes the step; element 1's top relaxes as Model 4's massless element 1 (see relax_tops).
  void set_step(double step_s) {
    dt = step_s;
    r_ext = params.r1_unload_n_s_m >= 0.0 ? params.r1_unload_n_s_m : params.r1_n_s_m;
    relax = r_ext > 0.0 ? std::exp(-dt * params.k1_n_m / r_ext) : 0.0;
  }

  // Bilinear value of a grid under the face centre.
  double probe(const Grid& Z) const {
    return (1.0 - fyw) * ((1.0 - fxw) * Z(py, px) + fxw * Z(py, px1)) +
           fyw * ((1.0 - fxw) * Z(py1, px) + fxw * Z(py1, px1));
  }

  // Forces at t_n from the state, velocities estimated as E = V + half * A(t_{n-1}); the face pushes, never pulls.
  void forces(double half) {
    E1 = V1 + half * A1;
    E2 = V2 + half * A2;
    ec = vc + half * ac;
    const double ewx = wx + half * awx, ewy = wy + half * awy;
    D = (zc + tx * Lx + ty * Ly) - Z1;
    Dd = (ec + ewx * Lx + ewy * Ly) - E1;
    Fr = K1 * D + K1c * D.cube() + (Dd < 0.0).select(R1u, R1) * Dd;
    Was = In;
    In = (In || (Face && D >= Top)) && Fr >= 0.0;
    Fc = In.select(Fr, 0.0);
    F12 = node.k2n * (Z1 - Z2) + node.r2n * (E1 - E2);
    Fg = node.k3n * Z2 + node.r3n * E2;
    S1.setZero();
    S2.setZero();
    frame1 = add_shear(Z1, E1, shear.kx1, shear.cx1, shear.ky1, shear.cy1, framed, S1, Dx1, Dy1);
    frame2 = add_shear(Z2, E2, shear.kx2, shear.cx2, shear.ky2, shear.cy2, framed, S2, Dx1, Dy1);
    f_contact = Fc.sum();
    torque_x = -(Fc * Lx).sum();  // acts on tilt_x
    torque_y = -(Fc * Ly).sum();
  }

  // Records sample k (time t_s) into out, and the dent if its GRF is the largest so far.
  void record(long k, double t_s, Model5Result& out, double& face_dent_at_peak_m3) {
    Simulation& sim = out.sim;
    const double grf = Fg.sum() + frame1 + frame2;
    sim.t_s(k) = t_s;
    sim.grf_n(k) = grf;
    sim.impactor_m(k) = zc;
    const double layer1 = probe(Z1);
    // The element's top under the centre: the face while it presses there.
    Surf = In.select(D, Top);
    sim.surface_m(k) = layer1 + probe(Surf);
    sim.layer1_m(k) = layer1;
    sim.layer2_m(k) = probe(Z2);
    out.impactor_velocity_m_s(k) = ec;
    out.tilt_x_rad(k) = tx;
    out.tilt_y_rad(k) = ty;
    out.mat_momentum_n_s(k) = node.m1n * E1.sum() + node.m2n * E2.sum();
    if (grf > out.peak_grf_n) {
      out.peak_grf_n = grf;
      out.peak_time_s = sim.t_s(k);
      out.surface_at_peak_m = Z1.matrix();
      face_dent_at_peak_m3 = (W * Surf.max(0.0)).sum() * face_area;
    }
  }

  // Element tops at t_{n+1}: where the face presses (or has just left: the face and the relaxing top move
  // alike at the instant of leaving, so D is the top to second order) start from D, then relax over the
  // step: e <- e exp(-dt (k1 + k1_cubic e^2) / r).
  void relax_tops() {
    Top = (In || Was).select(D.max(0.0), Top);
    if (r_ext > 0.0 && params.k1_cubic_n_m3 > 0.0) {
      Top *= (-(dt / r_ext) * (params.k1_n_m + params.k1_cubic_n_m3 * Top.square())).exp();
    } else {
      Top *= relax;
    }
  }

  // New accelerations; kick the velocities by `kick` (half a step on the first), then drift the positions by dt.
  void kick_drift(double kick) {
    A1 = (Fc - F12 + S1) / node.m1n;
    A2 = (F12 - Fg + S2) / node.m2n;
    ac = g - f_contact / M;
    awx = torque_x / I_tilt_x;
    awy = torque_y / I_tilt_y;
    V1 += kick * A1;
    V2 += kick * A2;
    vc += kick * ac;
    wx += kick * awx;
    wy += kick * awy;
    Z1 += dt * V1;
    Z2 += dt * V2;
    zc += dt * vc;
    tx += dt * wx;
    ty += dt * wy;
  }
};

}  // namespace

Model5Result simulate_model5_leapfrog(const MatParams& params, const Model5Geometry& geo, const Impact& impact) {
  model5_detail::validate(params, geo, impact);
  Model5Result out;
  Leapfrog lf(params, geo, impact, out);
  const double dt_limit = leapfrog_step_limit(geo, lf.framed, lf.K1, lf.R1, lf.R1u, lf.Lx, lf.Ly, lf.node, lf.shear,
                                              lf.M, lf.I_tilt_x, lf.I_tilt_y);
  const double out_dt = impact.output_dt_s;
  const long n_sub = std::max(1L, static_cast<long>(std::ceil(out_dt / dt_limit - 1e-9)));
  const double dt = out_dt / static_cast<double>(n_sub);
  const long n_out = static_cast<long>(std::floor(impact.duration_s / out_dt + 1e-9)) + 1;
  require(n_out <= 10'000'000, "more than 1e7 output samples requested");
  require(static_cast<double>(n_sub) * static_cast<double>(n_out) <= 2e8,
          fmt::format("the stiffest element needs a step of {:.3g} s: too many steps; lower the shear rigidity "
                      "or the shear damping",
                      dt));
  out.step_s = dt;
  lf.set_step(dt);

  Simulation& sim = out.sim;
  for (Eigen::VectorXd* v : {&sim.t_s, &sim.grf_n, &sim.impactor_m, &sim.surface_m, &sim.layer1_m, &sim.layer2_m,
                             &out.impactor_velocity_m_s, &out.tilt_x_rad, &out.tilt_y_rad, &out.mat_momentum_n_s})
    v->resize(n_out);
  out.surface_at_peak_m = Eigen::MatrixXd::Zero(geo.nodes_y, geo.nodes_x);
  out.peak_grf_n = -std::numeric_limits<double>::infinity();
  double face_dent_at_peak_m3 = 0.0;  // extra volume where the face presses below the top layer

  // Leapfrog (see model5.h): forces at t_n, a sample every n_sub steps, element tops, kick and drift.
  bool touched = false;
  long step = 0;
  for (long k = 0; k < n_out; ++k) {
    for (long sub = 0; sub < n_sub; ++sub, ++step) {
      lf.forces(step == 0 ? 0.0 : 0.5 * dt);
      if (sub == 0) {  // record the sample at t = k * out_dt
        lf.record(k, static_cast<double>(k) * out_dt, out, face_dent_at_peak_m3);
        if (k == n_out - 1) break;  // last sample recorded; no step beyond the duration
      }
      if (lf.f_contact > 0.0) {
        touched = true;
      } else if (touched && !std::isfinite(sim.separation_s)) {
        sim.separation_s = static_cast<double>(step) * dt;
      }
      lf.relax_tops();
      lf.kick_drift(step == 0 ? 0.5 * dt : dt);
    }
  }
  out.steps = step;
  // Visible dent at peak: the top layer's travel, plus where the face presses
  // deeper than the layer (element 1 compressed), the face's travel there.
  out.layer_volume_at_peak_m3 = out.surface_at_peak_m.sum() * lf.dx * lf.dy;
  out.deformed_volume_at_peak_m3 = out.layer_volume_at_peak_m3 + face_dent_at_peak_m3;
  const double s = lf.probe(out.surface_at_peak_m.array());
  out.layer_dent_area_at_peak_m2 = s > 0.0 ? out.layer_volume_at_peak_m3 / s : 0.0;
  return out;
}

}  // namespace dropfit::bench
