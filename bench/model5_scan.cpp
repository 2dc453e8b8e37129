// Model 5 over the fitter's bounds: a one-off scan (not a test, not run by
// CTest) of the steps, the CPU time and the error against the fine-step
// reference (the leapfrog at 1 us, as tests/model5_test.cpp) of one 0.3 s
// impact (24 kg at 5.25 m/s, default 9 x 6 grid).
//
//   model5_scan scan [n_random=3000] [seed=7] [n_err=12] [grid=21]
//       A grid of grid x grid points over k 2e3..3e7 N/m, r 3..3e4 N s/m
//       (log-spaced) for all three elements alike and for each element
//       alone (the others at Table 2), then n_random points drawn
//       log-uniformly (each of k1..k3, r1..r3 independently; masses Table
//       2). Prints the dearest points (by steps, then timed again) and the
//       errors against the reference at the n_err dearest and at the worst
//       of the heavily damped grid points.
//   model5_scan point k1 k2 k3 r1 r2 r3 [creep_step] [creep_fast_1_s] [max_step_s]
//       One point: steps, CPU time, errors against the reference.
//
// CPU time: CLOCK_PROCESS_CPUTIME_ID, the least of five runs (the machine
// may be loaded).
#include <time.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "bench/model5_impact.h"
#include "bench/model5_leapfrog.h"
#include "fitting/model5.h"
#include "fitting/models.h"

namespace {

using namespace dropfit::fitting;

using dropfit::bench::model5_trial3;
using dropfit::bench::simulate_model5_leapfrog;

double cpu_now() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

struct Point {
  MatParams p;
  std::string label;
  long steps = 0;
  double ms = 0.0;
};

// The scan's points: a grid x grid log-spaced grid over k 2e3..3e7 N/m and
// r 3..3e4 N s/m for all three elements alike and for each alone (the
// others at Table 2), then n_random points with every k and r drawn
// log-uniformly (seeded; the grid draws nothing, so the random points are
// the same whatever the grid).
std::vector<Point> scan_points(int n_random, unsigned seed, int grid) {
  const MatParams t2 = paper_table2(ModelKind::Model5);
  std::vector<Point> pts;
  auto logspace = [grid](double a, double b, int i) {
    return std::exp(std::log(a) + (std::log(b) - std::log(a)) * i / (grid - 1));
  };
  for (int mode = 0; mode < 4; ++mode)  // 0: all alike; 1..3: element mode alone
    for (int i = 0; i < grid; ++i)
      for (int j = 0; j < grid; ++j) {
        const double k = logspace(2e3, 3e7, i), r = logspace(3.0, 3e4, j);
        MatParams p = t2;
        if (mode == 0 || mode == 1) p.k1_n_m = k, p.r1_n_s_m = r;
        if (mode == 0 || mode == 2) p.k2_n_m = k, p.r2_n_s_m = r;
        if (mode == 0 || mode == 3) p.k3_n_m = k, p.r3_n_s_m = r;
        pts.push_back({p, mode == 0 ? "grid-all" : "grid-e" + std::to_string(mode)});
      }
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  auto draw = [&](double a, double b) { return std::exp(std::log(a) + (std::log(b) - std::log(a)) * u(rng)); };
  for (int i = 0; i < n_random; ++i) {
    MatParams p = t2;
    p.k1_n_m = draw(2e3, 3e7);
    p.k2_n_m = draw(2e3, 3e7);
    p.k3_n_m = draw(2e3, 3e7);
    p.r1_n_s_m = draw(3.0, 3e4);
    p.r2_n_s_m = draw(3.0, 3e4);
    p.r3_n_s_m = draw(3.0, 3e4);
    pts.push_back({p, "random"});
  }
  return pts;
}

double time_ms(const MatParams& p, const Model5Geometry& g, int reps, long* steps) {
  double best = 1e300;
  for (int i = 0; i < reps; ++i) {
    const double t0 = cpu_now();
    const Model5Result r = simulate_model5_detailed(p, g, model5_trial3());
    best = std::min(best, cpu_now() - t0);
    *steps = r.steps;
  }
  return 1e3 * best;
}

struct Err {
  double peak = 0.0, rms = 0.0, max = 0.0, z_rms_mm = 0.0, ref_peak = 0.0;
};

Err error(const MatParams& p, const Model5Geometry& g) {
  Model5Geometry fine;
  fine.max_step_s = 1e-6;
  const Model5Result ref = simulate_model5_leapfrog(p, fine, model5_trial3());
  const Model5Result r = simulate_model5_detailed(p, g, model5_trial3());
  Err e;
  const double peak = ref.sim.grf_n.maxCoeff();
  const double n = static_cast<double>(ref.sim.grf_n.size());
  e.ref_peak = peak;
  e.peak = 100.0 * (r.sim.grf_n.maxCoeff() - peak) / peak;
  e.rms = 100.0 * std::sqrt((r.sim.grf_n - ref.sim.grf_n).squaredNorm() / n) / peak;
  e.max = 100.0 * (r.sim.grf_n - ref.sim.grf_n).cwiseAbs().maxCoeff() / peak;
  e.z_rms_mm = 1e3 * std::sqrt((r.sim.impactor_m - ref.sim.impactor_m).squaredNorm() / n);
  return e;
}

std::string describe(const MatParams& p) {
  char b[200];
  std::snprintf(b, sizeof b, "k %.3g %.3g %.3g  r %.3g %.3g %.3g", p.k1_n_m, p.k2_n_m, p.k3_n_m, p.r1_n_s_m,
                p.r2_n_s_m, p.r3_n_s_m);
  return b;
}

void print_err(const char* what, const MatParams& p, const Model5Geometry& g) {
  long steps = 0;
  const double ms = time_ms(p, g, 5, &steps);
  const Err e = error(p, g);
  std::printf("%-10s %-52s steps %5ld  %.3f ms  peak %+.3f %%  rms %.3f %%  max %.3f %%  z %.3f mm  (peak %.0f N)\n",
              what, describe(p).c_str(), steps, ms, e.peak, e.rms, e.max, e.z_rms_mm, e.ref_peak);
  std::fflush(stdout);
}

int scan(int n_random, unsigned seed, int n_err, int grid) {
  const Model5Geometry geo;
  std::vector<Point> pts = scan_points(n_random, seed, grid);
  const std::size_t n_grid = pts.size() - static_cast<std::size_t>(n_random);
  double total = 0.0;
  for (Point& q : pts) {
    q.ms = time_ms(q.p, geo, 1, &q.steps);
    total += q.ms;
  }
  int over2 = 0, over16 = 0;
  for (const Point& q : pts) over2 += q.ms > 2.0, over16 += q.ms > 1.6;
  std::printf("%zu points (%zu grid, %d random, seed %u): one run each %.1f s CPU; over 2 ms %d, over 1.6 ms %d "
              "(one run each)\n",
              pts.size(), n_grid, n_random, seed, 1e-3 * total, over2, over16);
  // Steps: histogram and the dearest.
  long max_steps = 0;
  for (const Point& q : pts) max_steps = std::max(max_steps, q.steps);
  std::vector<Point> by_steps = pts;
  std::sort(by_steps.begin(), by_steps.end(), [](const Point& a, const Point& b) {
    return a.steps != b.steps ? a.steps > b.steps : a.ms > b.ms;
  });
  std::vector<Point> by_time = pts;
  std::sort(by_time.begin(), by_time.end(), [](const Point& a, const Point& b) { return a.ms > b.ms; });
  // Re-time the 40 dearest by either measure (best of five).
  std::vector<Point> dear;
  for (int i = 0; i < 20 && i < static_cast<int>(pts.size()); ++i) dear.push_back(by_steps[i]), dear.push_back(by_time[i]);
  for (Point& q : dear) q.ms = time_ms(q.p, geo, 5, &q.steps);
  std::sort(dear.begin(), dear.end(), [](const Point& a, const Point& b) { return a.ms > b.ms; });
  dear.erase(std::unique(dear.begin(), dear.end(),
                         [](const Point& a, const Point& b) { return describe(a.p) == describe(b.p); }),
             dear.end());
  std::printf("max steps %ld; dearest (CPU, least of 5):\n", max_steps);
  for (int i = 0; i < 12 && i < static_cast<int>(dear.size()); ++i)
    std::printf("  %-9s %-52s steps %5ld  %.3f ms\n", dear[i].label.c_str(), describe(dear[i].p).c_str(),
                dear[i].steps, dear[i].ms);
  std::printf("most steps:\n");
  for (int i = 0; i < 12 && i < static_cast<int>(by_steps.size()); ++i)
    std::printf("  %-9s %-52s steps %5ld\n", by_steps[i].label.c_str(), describe(by_steps[i].p).c_str(),
                by_steps[i].steps);
  std::fflush(stdout);
  // Errors: the dearest by steps and by time, and the heavily damped grid.
  std::printf("errors against the 1 us reference:\n");
  int shown = 0;
  for (const Point& q : by_steps) {
    if (shown++ >= n_err) break;
    print_err("steps", q.p, geo);
  }
  for (int i = 0; i < 4 && i < static_cast<int>(dear.size()); ++i) print_err("time", dear[i].p, geo);
  return 0;
}

// Errors at a sample of random points (every `every`-th, from the same draw).
int accuracy(int n_random, unsigned seed, int every) {
  const Model5Geometry geo;
  const std::vector<Point> pts = scan_points(n_random, seed, 0);
  Err worst_peak, worst_rms;
  std::string wp, wr;
  int n = 0;
  for (int i = 0; i < n_random; ++i) {
    const MatParams& p = pts[static_cast<std::size_t>(i)].p;
    if (i % every) continue;
    const Err e = error(p, geo);
    ++n;
    if (std::abs(e.peak) > std::abs(worst_peak.peak)) worst_peak = e, wp = describe(p);
    if (e.rms > worst_rms.rms) worst_rms = e, wr = describe(p);
    if (std::abs(e.peak) > 0.3 || e.rms > 0.5)
      std::printf("  #%d %-52s peak %+.3f %%  rms %.3f %%  max %.3f %%\n", i, describe(p).c_str(), e.peak, e.rms,
                  e.max);
    std::fflush(stdout);
  }
  std::printf("%d points: worst peak %+.3f %% (%s), worst rms %.3f %% (%s)\n", n, worst_peak.peak, wp.c_str(),
              worst_rms.rms, wr.c_str());
  return 0;
}

// Every creep-limited point of the scan (more steps than with the creep
// limit off): its error with the given creep_step (1e9: off), one line each.
int creep(int n_random, unsigned seed, int grid, double creep_step, double slow_load) {
  std::vector<MatParams> pts;
  for (const Point& q : scan_points(n_random, seed, grid)) pts.push_back(q.p);
  Model5Geometry off;
  off.creep_step = 1e9;
  Model5Geometry g;
  g.creep_step = creep_step;
  g.creep_slow_load = slow_load;
  Model5Geometry limit;
  limit.creep_slow_load = 0.0;
  for (const MatParams& p : pts) {
    const long base = simulate_model5_detailed(p, limit, model5_trial3()).steps;
    const long free = simulate_model5_detailed(p, off, model5_trial3()).steps;
    if (base <= free) continue;
    const Err e = error(p, g);
    const long now = simulate_model5_detailed(p, g, model5_trial3()).steps;
    std::printf("%g %g %g %g %g %g steps %ld %ld %ld peak %+.4f rms %.4f max %.4f\n", p.k1_n_m, p.k2_n_m, p.k3_n_m,
                p.r1_n_s_m, p.r2_n_s_m, p.r3_n_s_m, base, free, now, e.peak, e.rms, e.max);
    std::fflush(stdout);
  }
  return 0;
}

// Errors at every point of a grid (all elements alike, each alone) and
// n_random random points, one line each, with max_step_s and
// creep_slow_load given.
int errors(int n_random, unsigned seed, int grid, double max_step, double slow_load, double step_load) {
  std::vector<MatParams> pts;
  for (const Point& q : scan_points(n_random, seed, grid)) pts.push_back(q.p);
  Model5Geometry g;
  g.max_step_s = max_step;
  g.creep_slow_load = slow_load;
  g.slow_step_load = step_load;
  for (const MatParams& p : pts) {
    const Err e = error(p, g);
    const long steps = simulate_model5_detailed(p, g, model5_trial3()).steps;
    std::printf("%g %g %g %g %g %g steps %ld peak %+.4f rms %.4f max %.4f\n", p.k1_n_m, p.k2_n_m, p.k3_n_m,
                p.r1_n_s_m, p.r2_n_s_m, p.r3_n_s_m, steps, e.peak, e.rms, e.max);
    std::fflush(stdout);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string mode = argc > 1 ? argv[1] : "scan";
  auto arg = [&](int i, double def) { return argc > i ? std::atof(argv[i]) : def; };
  if (mode == "point") {
    if (argc < 8) {
      std::fprintf(stderr, "usage: model5_scan point k1 k2 k3 r1 r2 r3 [creep_step] [creep_fast_1_s] [max_step_s]\n");
      return 2;
    }
    MatParams p = paper_table2(ModelKind::Model5);
    p.k1_n_m = arg(2, 0);
    p.k2_n_m = arg(3, 0);
    p.k3_n_m = arg(4, 0);
    p.r1_n_s_m = arg(5, 0);
    p.r2_n_s_m = arg(6, 0);
    p.r3_n_s_m = arg(7, 0);
    Model5Geometry g;
    g.creep_step = arg(8, g.creep_step);
    g.creep_fast_1_s = arg(9, g.creep_fast_1_s);
    g.max_step_s = arg(10, g.max_step_s);
    g.creep_slow_load = arg(11, g.creep_slow_load);
    g.slow_step_load = arg(12, g.slow_step_load);
    g.slow_step_factor = arg(13, g.slow_step_factor);
    g.slow_step_after_s = arg(14, g.slow_step_after_s);
    print_err("point", p, g);
    // Against the scheme with the slow-load rules off (creep limit whenever
    // the face presses, max_step_s throughout).
    Model5Geometry old = g;
    old.creep_slow_load = 0.0;
    old.slow_step_load = 0.0;
    old.slow_step_factor = 1.0;
    const Model5Result a = simulate_model5_detailed(p, old, model5_trial3());
    const Model5Result b = simulate_model5_detailed(p, g, model5_trial3());
    std::printf("vs slow-load rules off: %ld -> %ld steps, max |GRF diff| %.4f %% of peak\n", a.steps, b.steps,
                100.0 * (a.sim.grf_n - b.sim.grf_n).cwiseAbs().maxCoeff() / a.sim.grf_n.maxCoeff());
    return 0;
  }
  if (mode == "creep") return creep(static_cast<int>(arg(2, 3000)), static_cast<unsigned>(arg(3, 7)),
                                    static_cast<int>(arg(4, 21)), arg(5, 0.07), arg(6, 1e-3));
  if (mode == "errors") return errors(static_cast<int>(arg(2, 300)), static_cast<unsigned>(arg(3, 7)),
                                      static_cast<int>(arg(4, 11)), arg(5, 1e-4), arg(6, 0.01), arg(7, 1e-3));
  if (mode == "accuracy") return accuracy(static_cast<int>(arg(2, 3000)), static_cast<unsigned>(arg(3, 7)),
                                          static_cast<int>(arg(4, 30)));
  return scan(static_cast<int>(arg(2, 3000)), static_cast<unsigned>(arg(3, 7)), static_cast<int>(arg(4, 12)),
              static_cast<int>(arg(5, 21)));
}
