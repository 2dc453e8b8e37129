// Model 5, the geometric, area-elastic mat: see model5.h for the model, its
// parameter mapping onto Model 4 and the integration scheme.
#include "fitting/model5.h"

#include "core/cpu_dispatch.h"
#include "fitting/model5_impl.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>
#include <string>

#include "core/error.h"

namespace dropfit::fitting {
namespace {

void require(bool ok, const std::string& reason) {
  if (!ok) throw Error("model5: " + reason);
}

bool finite_nonneg(double v) { return std::isfinite(v) && v >= 0.0; }
bool finite_pos(double v) { return std::isfinite(v) && v > 0.0; }

}  // namespace

Model5ParamsT<double> model5_params(const MatParams& p) {
  Model5ParamsT<double> q;
  q.k1_n_m = p.k1_n_m;
  q.k2_n_m = p.k2_n_m;
  q.k3_n_m = p.k3_n_m;
  q.r1_n_s_m = p.r1_n_s_m;
  q.r2_n_s_m = p.r2_n_s_m;
  q.r3_n_s_m = p.r3_n_s_m;
  q.m1_kg = p.m1_kg;
  q.m2_kg = p.m2_kg;
  q.k1_cubic_n_m3 = p.k1_cubic_n_m3;
  q.cubic = p.k1_cubic_n_m3 != 0.0;
  q.hysteresis = p.r1_unload_n_s_m >= 0.0;
  q.r1_unload_n_s_m = q.hysteresis ? p.r1_unload_n_s_m : p.r1_n_s_m;
  require(!(p.maxwell_k_n_m > 0.0), "the Maxwell arm (maxwell_k_n_m > 0) is not carried by Model 5");
  return q;
}

namespace model5_detail {

void validate(const MatParams& p, const Model5Geometry& g, const Impact& im) {
  require(finite_pos(p.m1_kg), fmt::format("top layer mass m1_kg must be > 0 (got {})", p.m1_kg));
  require(finite_pos(p.m2_kg), fmt::format("bottom layer mass m2_kg must be > 0 (got {})", p.m2_kg));
  require(finite_nonneg(p.k1_n_m) && finite_nonneg(p.k2_n_m) && finite_nonneg(p.k3_n_m),
          "stiffnesses k1..k3 must be finite and >= 0");
  require(finite_nonneg(p.r1_n_s_m) && finite_nonneg(p.r2_n_s_m) && finite_nonneg(p.r3_n_s_m),
          "dampings r1..r3 must be finite and >= 0");
  require(finite_nonneg(p.k1_cubic_n_m3), "k1_cubic_n_m3 must be finite and >= 0");
  require(std::isfinite(p.r1_unload_n_s_m), "r1_unload_n_s_m must be finite");
  require(!(p.maxwell_k_n_m > 0.0), "the Maxwell arm (maxwell_k_n_m > 0) is not carried by Model 5");
  require(finite_pos(im.mass_kg), "impactor mass must be > 0");
  require(std::isfinite(im.velocity_m_s) && std::isfinite(im.gravity_m_s2), "impact velocity and gravity must be finite");
  require(finite_pos(im.duration_s), "duration_s must be > 0");
  require(finite_pos(im.output_dt_s) && im.output_dt_s <= im.duration_s,
          "output_dt_s must be > 0 and no longer than duration_s");
  require(finite_pos(g.mat_length_m) && finite_pos(g.mat_width_m), "mat length and width must be > 0");
  require(g.nodes_x >= 1 && g.nodes_y >= 1, "nodes_x and nodes_y must be >= 1");
  require(finite_pos(g.footprint_length_m) && finite_pos(g.footprint_width_m), "footprint sides must be > 0");
  require(finite_nonneg(g.shear1_n_m) && finite_nonneg(g.shear2_n_m) && finite_nonneg(g.shear_damping1_n_s_m) &&
              finite_nonneg(g.shear_damping2_n_s_m),
          "shear rigidities and dampings must be finite and >= 0");
  require(std::isfinite(g.impact_x_m) && std::isfinite(g.impact_y_m) && std::isfinite(g.tilt_x0_rad) &&
              std::isfinite(g.tilt_y0_rad) && std::isfinite(g.tilt_rate_x0_rad_s) &&
              std::isfinite(g.tilt_rate_y0_rad_s),
          "impact point, tilts and tilt rates must be finite");
  require(finite_nonneg(g.impactor_height_m) && std::isfinite(g.inertia_tilt_x_kg_m2) &&
              std::isfinite(g.inertia_tilt_y_kg_m2),
          "impactor height and moments of inertia must be finite (height >= 0)");
  require(finite_pos(g.max_step_s), "max_step_s must be > 0");
  require(finite_pos(g.creep_step) && finite_pos(g.creep_fast_1_s), "creep_step and creep_fast_1_s must be > 0");
  require(std::isfinite(g.creep_slow_load) && g.creep_slow_load >= 0.0, "creep_slow_load must be >= 0");
  require(std::isfinite(g.slow_step_load) && g.slow_step_load >= 0.0, "slow_step_load must be >= 0");
  require(std::isfinite(g.slow_step_factor) && g.slow_step_factor >= 1.0, "slow_step_factor must be >= 1");
  require(std::isfinite(g.slow_step_after_s) && g.slow_step_after_s >= 0.0, "slow_step_after_s must be >= 0");
  require(std::isfinite(g.slow_step_light_rate_1_s) && g.slow_step_light_rate_1_s >= 0.0,
          "slow_step_light_rate_1_s must be >= 0");
  require(g.stability_fraction > 0.0 && g.stability_fraction <= 1.0, "stability_fraction must be in (0, 1]");
}

// Length of the overlap of [a0, a1] and [b0, b1] (0 when disjoint), and its centre.
double overlap(double a0, double a1, double b0, double b1, double* centre) {
  const double lo = std::max(a0, b0), hi = std::min(a1, b1);
  *centre = 0.5 * (lo + hi);
  return std::max(0.0, hi - lo);
}

// Bilinear weights of position p among cell centres c0 + i * d, i = 0..n-1,
// clamped to the outer centres: p lies between centres i0 and i0 + 1 with
// weight (1 - f) and f.
void bracket(double p, double c0, double d, int n, int* i0, double* f) {
  if (n == 1) {
    *i0 = 0;
    *f = 0.0;
    return;
  }
  const double s = std::clamp((p - c0) / d, 0.0, static_cast<double>(n - 1));
  *i0 = std::min(static_cast<int>(std::floor(s)), n - 2);
  *f = s - *i0;
}


int sample_count(const Impact& im) {
  return static_cast<int>(std::floor((im.duration_s - im.first_output_s) / im.output_dt_s + 1e-9)) + 1;
}

// Checks the parameters, geometry and output timing a layout is built from.
static void check_layout_inputs(const Model5ParamsT<double>& q, const Model5Geometry& geo, const Impact& impact) {
  MatParams p;
  p.k1_n_m = q.k1_n_m;
  p.k2_n_m = q.k2_n_m;
  p.k3_n_m = q.k3_n_m;
  p.r1_n_s_m = q.r1_n_s_m;
  p.r2_n_s_m = q.r2_n_s_m;
  p.r3_n_s_m = q.r3_n_s_m;
  p.m1_kg = q.m1_kg;
  p.m2_kg = q.m2_kg;
  p.k1_cubic_n_m3 = q.k1_cubic_n_m3;
  p.r1_unload_n_s_m = q.hysteresis ? q.r1_unload_n_s_m : -1.0;
  validate(p, geo, impact);
  require(q.r1_unload_n_s_m >= 0.0, "r1_unload_n_s_m must be >= 0 when on");
  require(impact.first_output_s >= 0.0 && impact.first_output_s < impact.output_dt_s,
          fmt::format("first output time {} s must lie in [0, output step)", impact.first_output_s));
}

// The node grid: counts, spacing, first centre and node coordinates.
static void place_nodes(const Model5Geometry& geo, Layout& L) {
  const int nx = geo.nodes_x, ny = geo.nodes_y;
  L.nx = nx;
  L.ny = ny;
  L.n = nx * ny;
  L.dx = geo.mat_length_m / nx;
  L.dy = geo.mat_width_m / ny;
  L.x0 = -0.5 * geo.mat_length_m + 0.5 * L.dx;
  L.y0 = -0.5 * geo.mat_width_m + 0.5 * L.dy;
  L.framed = geo.edge == MatEdge::Framed;
  L.node_x_m.resize(nx);
  L.node_y_m.resize(ny);
  for (int ix = 0; ix < nx; ++ix) L.node_x_m(ix) = L.x0 + ix * L.dx;
  for (int iy = 0; iy < ny; ++iy) L.node_y_m(iy) = L.y0 + iy * L.dy;
}

// Contact weights and lever arms per cell under the impactor's face (see model5.h).
static void place_contact(const Model5Geometry& geo, Layout& L) {
  const int nx = L.nx, ny = L.ny;
  const double fx0 = geo.impact_x_m - 0.5 * geo.footprint_length_m, fx1 = geo.impact_x_m + 0.5 * geo.footprint_length_m;
  const double fy0 = geo.impact_y_m - 0.5 * geo.footprint_width_m, fy1 = geo.impact_y_m + 0.5 * geo.footprint_width_m;
  L.face_area = geo.footprint_length_m * geo.footprint_width_m;
  L.w.assign(L.n, 0.0);
  L.lx.assign(L.n, 0.0);
  L.ly.assign(L.n, 0.0);
  double wsum = 0.0;
  for (int ix = 0; ix < nx; ++ix) {
    double mx = 0.0;
    const double ox = overlap(L.node_x_m(ix) - 0.5 * L.dx, L.node_x_m(ix) + 0.5 * L.dx, fx0, fx1, &mx);
    for (int iy = 0; iy < ny; ++iy) {
      double my = 0.0;
      const double oy = overlap(L.node_y_m(iy) - 0.5 * L.dy, L.node_y_m(iy) + 0.5 * L.dy, fy0, fy1, &my);
      if (ox > 0.0 && oy > 0.0) {
        const int j = ix * ny + iy;
        L.w[j] = ox * oy / L.face_area;
        L.lx[j] = mx - geo.impact_x_m;
        L.ly[j] = my - geo.impact_y_m;
        L.face.push_back(j);
        wsum += L.w[j];
      }
    }
  }
  require(wsum > 1e-9, fmt::format("the impactor's face at ({}, {}) m misses the {} x {} m mat", geo.impact_x_m,
                                   geo.impact_y_m, geo.mat_length_m, geo.mat_width_m));
}

// Shear stencil between neighbouring cells and the frame links at the edges.
static void link_cells(Layout& L) {
  const int nx = L.nx, ny = L.ny;
  const double fxp = L.dy / L.dx, fyp = L.dx / L.dy;
  for (int ix = 0; ix < nx; ++ix) {
    for (int iy = 0; iy < ny; ++iy) {
      const int j = ix * ny + iy;
      if (ix + 1 < nx) {
        L.pair_a.push_back(j);
        L.pair_b.push_back(j + ny);
        L.pair_f.push_back(fxp);
      }
      if (iy + 1 < ny) {
        L.pair_a.push_back(j);
        L.pair_b.push_back(j + 1);
        L.pair_f.push_back(fyp);
      }
      if (L.framed) {
        const double f = 2.0 * fxp * ((ix == 0) + (ix == nx - 1)) + 2.0 * fyp * ((iy == 0) + (iy == ny - 1));
        if (f > 0.0) {
          L.frame_cell.push_back(j);
          L.frame_f.push_back(f);
        }
      }
    }
  }

  L.frame_w.assign(L.n, 0.0);
  for (std::size_t e = 0; e < L.frame_cell.size(); ++e) L.frame_w[L.frame_cell[e]] = L.frame_f[e];
}

// The impactor: tilt inertias, initial tilt and rate, clearance and impact-point bracket.
static void place_impactor(const Model5Geometry& geo, const Impact& impact, Layout& L) {
  const int nx = L.nx, ny = L.ny;
  const double fx0 = geo.impact_x_m - 0.5 * geo.footprint_length_m, fx1 = geo.impact_x_m + 0.5 * geo.footprint_length_m;
  const double fy0 = geo.impact_y_m - 0.5 * geo.footprint_width_m, fy1 = geo.impact_y_m + 0.5 * geo.footprint_width_m;
  const double M = impact.mass_kg;
  const double h2 = geo.impactor_height_m * geo.impactor_height_m;
  L.inertia_x = geo.inertia_tilt_x_kg_m2 > 0.0 ? geo.inertia_tilt_x_kg_m2
                                               : M * (geo.footprint_length_m * geo.footprint_length_m + h2) / 12.0;
  L.inertia_y = geo.inertia_tilt_y_kg_m2 > 0.0 ? geo.inertia_tilt_y_kg_m2
                                               : M * (geo.footprint_width_m * geo.footprint_width_m + h2) / 12.0;
  L.tx0 = geo.tilt_x0_rad;
  L.ty0 = geo.tilt_y0_rad;
  L.wx0 = geo.tilt_rate_x0_rad_s;
  L.wy0 = geo.tilt_rate_y0_rad_s;
  const double cx0 = std::max(fx0, -0.5 * geo.mat_length_m) - geo.impact_x_m;
  const double cx1 = std::min(fx1, 0.5 * geo.mat_length_m) - geo.impact_x_m;
  const double cy0 = std::max(fy0, -0.5 * geo.mat_width_m) - geo.impact_y_m;
  const double cy1 = std::min(fy1, 0.5 * geo.mat_width_m) - geo.impact_y_m;
  L.zc0 = -std::max(L.tx0 * cx0, L.tx0 * cx1) - std::max(L.ty0 * cy0, L.ty0 * cy1);

  bracket(geo.impact_x_m, L.x0, L.dx, nx, &L.px, &L.fxw);
  bracket(geo.impact_y_m, L.y0, L.dy, ny, &L.py, &L.fyw);
  L.px1 = std::min(L.px + 1, nx - 1);
  L.py1 = std::min(L.py + 1, ny - 1);
}

// The integration step: shear stability and creep accuracy limits, sub-steps per output.
static void choose_step(const Model5ParamsT<double>& q, const Model5Geometry& geo, const Impact& impact, Layout& L) {
  // Step: the accuracy cap max_step_s, and the explicit part's stability:
  // Gershgorin bounds w^2 on M^-1 K_shear and g on M^-1 C_shear per node,
  // then w^2 dt^2 + 4 g dt = 4 (the kick-drift limit), times
  // stability_fraction. The vertical elements (k, r) are implicit: no bound.
  const double m1n = q.m1_kg / L.n, m2n = q.m2_kg / L.n;
  std::vector<double> row(L.n, 0.0);
  for (std::size_t e = 0; e < L.pair_f.size(); ++e) {
    row[L.pair_a[e]] += 2.0 * L.pair_f[e];
    row[L.pair_b[e]] += 2.0 * L.pair_f[e];
  }
  for (std::size_t e = 0; e < L.frame_f.size(); ++e) row[L.frame_cell[e]] += L.frame_f[e];
  const double rmax = *std::max_element(row.begin(), row.end());
  const double w2 = rmax * std::max(geo.shear1_n_m / m1n, geo.shear2_n_m / m2n);
  const double gam = rmax * std::max(geo.shear_damping1_n_s_m / m1n, geo.shear_damping2_n_s_m / m2n);
  // The shear damping is sub-stepped inside the kicks (Integrator::kick):
  // only the shear stiffness bounds the step, w dt < 2.
  L.shear_gamma = gam;
  const double dt_shear = w2 > 0.0 ? geo.stability_fraction * 2.0 / std::sqrt(w2) : 1e300;
  // The longer step keeps a wider margin to the shear's stability (w dt <=
  // 1, where 1.6 is used otherwise: with stiff shear the splitting went
  // unstable at w dt = 1.48) and is never shorter than the normal one.
  const double dt_normal = std::min(geo.max_step_s, dt_shear);
  const double dt_long = std::max(dt_normal, std::min(geo.slow_step_factor * geo.max_step_s, 0.625 * dt_shear));
  double dt_limit = dt_normal;
  // While the face is clear of the mat every column is linear with constant
  // coefficients and stepped exactly (Integrator::free_propagator): the
  // creep limit below is for the implicit stages of the pressed columns.
  const double dt_limit_free = dt_limit;
  // Accuracy: an overdamped element (r^2 > 4 k m on its node's mass) creeps
  // at the slow root of m s^2 + r s + k, 2 k / (r + sqrt(r^2 - 4 k m)); the
  // implicit stages resolve it to the stated accuracy with lambda dt <=
  // kCreepStep (measured: peak error 0.68 % at lambda dt = 0.12 with all
  // k = 3e7 N/m and r = 3e4 N s/m, 0.16 % at half that). Underdamped
  // elements need no such cap: their fast ringing is damped by the L-stable
  // stages (see model5.h, accuracy).
  {
    const double kCreepStep = geo.creep_step;
    double wmax = 0.0;
    for (double wj : L.w) wmax = std::max(wmax, wj);
    const double fast = geo.creep_fast_1_s;
    auto creep = [fast](double k, double r, double m) {
      const double disc = r * r - 4.0 * k * m;
      const double rate = (k > 0.0 && r > 0.0 && disc > 0.0) ? 2.0 * k / (r + std::sqrt(disc)) : 0.0;
      return rate < fast ? rate : 0.0;
    };
    const double k1w = q.k1_n_m * wmax, r1w = std::max(q.r1_n_s_m, q.hysteresis ? q.r1_unload_n_s_m : 0.0) * wmax;
    const double mu = m1n * m2n / (m1n + m2n);
    const double lambda = std::max({creep(k1w, r1w, m1n), creep(q.k2_n_m / L.n, q.r2_n_s_m / L.n, mu),
                                    creep(q.k3_n_m / L.n, q.r3_n_s_m / L.n, m2n)});
    if (lambda > 0.0 && kCreepStep / lambda < dt_limit) {
      dt_limit = kCreepStep / lambda;
      L.creep_rate_1_s = lambda;
    }
  }
  const double out_dt = impact.output_dt_s;
  const long n_sub = std::max(1L, static_cast<long>(std::ceil(out_dt / dt_limit - 1e-9)));
  const long n_out = sample_count(impact);
  require(static_cast<double>(n_sub) * static_cast<double>(n_out) <= 2e8,
          fmt::format("the shear coupling needs a step of {:.3g} s: too many steps; lower the shear rigidity "
                      "or the shear damping",
                      out_dt / n_sub));
  L.n_sub = static_cast<int>(n_sub);
  L.step_s = out_dt / static_cast<double>(n_sub);
  L.n_sub_free = std::min(L.n_sub, std::max(1, static_cast<int>(std::ceil(out_dt / dt_limit_free - 1e-9))));
  L.step_free_s = out_dt / static_cast<double>(L.n_sub_free);
  // The creep error follows (curvature of the load) / lambda^2: the bound on
  // the second difference over an output interval scales with (lambda dt)^2.
  L.slow_load_bound = geo.creep_slow_load * (L.creep_rate_1_s * out_dt) * (L.creep_rate_1_s * out_dt);
  // The slow-load step: slow_step_factor x max_step_s within the shear's
  // stability (see Integration in model5.h).
  L.n_sub_slow = std::min(L.n_sub_free, std::max(1, static_cast<int>(std::ceil(out_dt / dt_long - 1e-9))));
  // Only from slow_step_after_s on: a typical impact's stepping (contact
  // over by then), and so the fitter's objective and derivatives around
  // it, is left as it was.
  L.slow_after_s = geo.slow_step_after_s;
  L.step_slow_s = out_dt / static_cast<double>(L.n_sub_slow);
  // Where the layers damp lightly (elements 2 and 3 damp their node motion
  // at rates r / m of at most slow_step_light_rate_1_s), the longer step holds after
  // slow_step_after_s whatever the load's curvature and the creep (the
  // errors it moves are the heavily damped layers' splitting at landing
  // and the hard impacts' creep, both over by then): every pressed interval
  // from then on takes it.
  {
    const double mu = m1n * m2n / (m1n + m2n);
    const double rate = std::max(q.r2_n_s_m / L.n / mu, q.r3_n_s_m / L.n / m2n);
    L.slow_any_load = rate <= geo.slow_step_light_rate_1_s;
    L.slow_step_bound = geo.slow_step_load;
  }
  if (impact.first_output_s > 0.0) {
    L.n_first = std::max(1, static_cast<int>(std::ceil(impact.first_output_s / dt_limit - 1e-9)));
    L.first_step_s = impact.first_output_s / L.n_first;
  }
}

Layout make_layout(const Model5ParamsT<double>& q, const Model5Geometry& geo, const Impact& impact) {
  check_layout_inputs(q, geo, impact);
  Layout L;
  place_nodes(geo, L);
  place_contact(geo, L);
  link_cells(L);
  place_impactor(geo, impact, L);
  choose_step(q, geo, impact, L);
  return L;
}

}  // namespace model5_detail

// One copy per CPU kind (core/cpu_dispatch.h): the steps take AVX2/FMA where
// the CPU has them (27 % less time at the scan's dearest points).
DROPFIT_CPU_CLONES
Model5Result simulate_model5_detailed(const MatParams& params, const Model5Geometry& geo, const Impact& impact) {
  const Model5ParamsT<double> q = model5_params(params);
  const model5_detail::Layout L = model5_detail::make_layout(q, geo, impact);
  const int n_out = model5_detail::sample_count(impact);
  require(n_out <= 10'000'000, "more than 1e7 output samples requested");

  Model5Result out;
  out.node_x_m = L.node_x_m;
  out.node_y_m = L.node_y_m;
  out.step_s = L.step_s;
  Simulation& sim = out.sim;
  for (Eigen::VectorXd* v : {&sim.t_s, &sim.grf_n, &sim.impactor_m, &sim.surface_m, &sim.layer1_m, &sim.layer2_m,
                             &out.impactor_velocity_m_s, &out.tilt_x_rad, &out.tilt_y_rad, &out.mat_momentum_n_s})
    v->resize(n_out);
  out.surface_at_peak_m = Eigen::MatrixXd::Zero(L.ny, L.nx);
  out.peak_grf_n = -std::numeric_limits<double>::infinity();

  using It = model5_detail::Integrator<double>;
  It it(q, geo, impact, L);
  struct Rec {
    Model5Result* out;
    const model5_detail::Layout* L;
    const Impact* im;
    bool touched = false;
    long steps = 0;
    double face_dent = 0.0;
    void after_step(const It&, double f, double t) {
      if (t > 0.0) ++steps;
      if (f > 0.0) {
        touched = true;
      } else if (touched && !std::isfinite(out->sim.separation_s)) {
        out->sim.separation_s = t;
      }
    }
    void operator()(int k, const It& s, double) {
      Simulation& sim = out->sim;
      const double grf = s.grf();
      sim.t_s(k) = im->first_output_s + k * im->output_dt_s;
      sim.grf_n(k) = grf;
      sim.impactor_m(k) = s.zc();
      sim.surface_m(k) = s.surface();
      sim.layer1_m(k) = s.probe(s.z1());
      sim.layer2_m(k) = s.probe(s.z2());
      out->impactor_velocity_m_s(k) = s.vc();
      out->tilt_x_rad(k) = s.tilt_x();
      out->tilt_y_rad(k) = s.tilt_y();
      out->mat_momentum_n_s(k) = s.mat_momentum();
      if (grf > out->peak_grf_n) {
        out->peak_grf_n = grf;
        out->peak_time_s = sim.t_s(k);
        for (int ix = 0; ix < L->nx; ++ix)
          for (int iy = 0; iy < L->ny; ++iy) out->surface_at_peak_m(iy, ix) = s.z1()[ix * L->ny + iy];
        face_dent = s.face_dent_m3();
      }
    }
  } rec{&out, &L, &impact};
  model5_detail::run(it, L, impact, n_out, rec);
  out.steps = rec.steps;
  out.layer_volume_at_peak_m3 = out.surface_at_peak_m.sum() * L.dx * L.dy;
  out.deformed_volume_at_peak_m3 = out.layer_volume_at_peak_m3 + rec.face_dent;
  {
    std::vector<double> flat(L.n);
    for (int ix = 0; ix < L.nx; ++ix)
      for (int iy = 0; iy < L.ny; ++iy) flat[ix * L.ny + iy] = out.surface_at_peak_m(iy, ix);
    const double s = it.probe(flat);
    out.layer_dent_area_at_peak_m2 = s > 0.0 ? out.layer_volume_at_peak_m3 / s : 0.0;
  }
  return out;
}

Simulation simulate_model5(const MatParams& params, const Model5Geometry& geometry, const Impact& impact) {
  return simulate_model5_detailed(params, geometry, impact).sim;
}

}  // namespace dropfit::fitting
