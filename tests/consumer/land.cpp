// A simulator's use of an installed dropfit: read a fitted mat (fit.json),
// land the fit's impactor on it through the co-simulation contact
// (fitting/cosim.h) with this program's own integrator, and check the peak
// ground reaction force and the deepest penetration against dropfit's own
// simulation of the same drop (fitting::simulate, exact for linear models).
// The closed loop's semi-implicit Euler step of 0.1 ms stays within 1 % of
// the exact peak (tests/cosim_test.cpp measures the same bound); exit 1
// beyond it.
//
//   land FIT_JSON [VELOCITY_M_S]
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <sstream>
#include <string>

#include "core/error.h"
#include "fitting/cosim.h"
#include "fitting/models.h"
#include "report/export.h"

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: land FIT_JSON [VELOCITY_M_S]\n");
    return 2;
  }
  try {
    std::ifstream in(argv[1], std::ios::binary);
    if (!in) throw dropfit::Error(std::string("cannot read ") + argv[1]);
    std::stringstream text;
    text << in.rdbuf();
    const auto fit = dropfit::report::parse_fit_json(text.str(), argv[1]);
    const double v0 = argc > 2 ? std::atof(argv[2]) : 5.0;
    const double mass_kg = fit.impactor_mass_kg, g = 9.81, dt = 1e-4, duration_s = 0.3;

    // The caller's loop: a point impactor under gravity, landing at v0.
    dropfit::fitting::MatContact mat(fit.model, fit.params);
    double y = 0.0, v = v0;  // at the undeformed top, moving down
    mat.reset(y, v);
    double peak_grf_n = 0.0, peak_foot_n = 0.0, max_y_m = 0.0, leave_s = NAN;
    bool touched = false;
    for (int n = 1; n * dt <= duration_s; ++n) {
      y += v * dt;
      const auto f = mat.step(y, v, dt);
      v += (g - f.foot_n / mass_kg) * dt;
      peak_grf_n = std::max(peak_grf_n, f.grf_n);
      peak_foot_n = std::max(peak_foot_n, f.foot_n);
      max_y_m = std::max(max_y_m, y);
      touched = touched || f.contact;
      if (touched && !f.contact && std::isnan(leave_s)) leave_s = n * dt;
    }

    // dropfit's own simulation of the same drop.
    dropfit::fitting::Impact impact;
    impact.mass_kg = mass_kg;
    impact.velocity_m_s = v0;
    impact.gravity_m_s2 = g;
    impact.duration_s = duration_s;
    impact.output_dt_s = dt;
    const auto sim = dropfit::fitting::simulate(fit.model, fit.params, impact);
    const double sim_peak_n = sim.grf_n.maxCoeff(), sim_max_y_m = sim.impactor_m.maxCoeff();

    const double peak_diff = (peak_grf_n - sim_peak_n) / sim_peak_n;
    const double depth_diff = (max_y_m - sim_max_y_m) / sim_max_y_m;
    std::printf("%s, %.1f kg at %.2f m/s, co-simulated at %.1f ms steps\n",
                dropfit::fitting::model_name(fit.model).c_str(), mass_kg, v0, dt * 1e3);
    std::printf("peak GRF      %8.1f N   (simulate: %8.1f N, %+.2f %%)\n", peak_grf_n, sim_peak_n, 100 * peak_diff);
    std::printf("peak on foot  %8.1f N\n", peak_foot_n);
    std::printf("max depth     %8.2f mm  (simulate: %8.2f mm, %+.2f %%)\n", 1e3 * max_y_m, 1e3 * sim_max_y_m,
                100 * depth_diff);
    std::printf("leaves the mat at %.1f ms (simulate: %.1f ms)\n", 1e3 * leave_s, 1e3 * sim.separation_s);
    if (!(std::abs(peak_diff) < 0.01 && std::abs(depth_diff) < 0.01)) {
      std::fprintf(stderr, "land: the co-simulation is more than 1 %% from dropfit's simulation\n");
      return 1;
    }
    std::printf("ok\n");
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "land: %s\n", e.what());
    return 1;
  }
}
