// The fitter's starts (see detail/starts.h).
#include "fitting/detail/starts.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <string>
#include <utility>

namespace dropfit::fitting::internal {

namespace {

// A start from the data: the effective stiffness put into one spring (the
// others much stiffer), light damping.
MatParams data_guess(double k_eff, const FitOptions& o, const TrialData& tr) {
  const double M = tr.impactor_mass_kg;
  const double k = std::isfinite(k_eff) ? k_eff : 1e5;
  const double rc = 2.0 * std::sqrt(k * M);  // critical damping on the impactor
  MatParams g;
  g.m1_kg = o.m1_kg;
  g.m2_kg = o.m2_kg;
  g.m_eff_kg = o.m_eff_kg >= 0.0 ? o.m_eff_kg : 0.3 * (o.m1_kg + o.m2_kg);
  switch (o.model) {
    case ModelKind::Model1:
    case ModelKind::Model2:
      g.k1_n_m = k; g.r1_n_s_m = 0.2 * rc;
      break;
    case ModelKind::Model3:
      g.k1_n_m = 1.1 * k; g.k2_n_m = 11.0 * k; g.r1_n_s_m = 0.1 * rc; g.r2_n_s_m = 0.2 * rc;
      break;
    default:
      g.k1_n_m = 1.2 * k; g.k2_n_m = 15.0 * k; g.k3_n_m = 10.0 * k;
      g.r1_n_s_m = 0.05 * rc; g.r2_n_s_m = 0.2 * rc; g.r3_n_s_m = 0.2 * rc;
      break;
  }
  return g;
}

double halton(int index, int base) {
  double f = 1.0, r = 0.0;
  while (index > 0) {
    f /= base;
    r += f * (index % base);
    index /= base;
  }
  return r;
}

}  // namespace

int ordering_of(const ParamSpace& space, const Eigen::VectorXd& u) {
  std::vector<std::pair<double, int>> ks;
  for (int j = 0; j < space.size(); ++j)
    if (space.free[j].name.size() == 6 && space.free[j].name[0] == 'k' && space.free[j].name.substr(2) == "_n_m")
      ks.push_back({u[j], j});
  std::sort(ks.begin(), ks.end());
  int label = 0;
  for (const auto& [v, j] : ks) label = label * 8 + j + 1;
  return label;
}

std::vector<Eigen::VectorXd> candidate_starts(const ParamSpace& space, const FitOptions& o, double k_eff,
                                              const TrialData& first) {
  const int n = space.size();
  std::vector<Eigen::VectorXd> cands;
  if (o.initial.k1_n_m > 0.0) {
    // A given start (a previous optimum) is never taken from a bound: a
    // coordinate on its bound moves 5 % of its range inside (a corner of
    // the box is also where the simulation is dearest: stiff and damped).
    Eigen::VectorXd u = space.from_mat(o.initial);
    for (int j = 0; j < n; ++j) {
      const FreeParam& f = space.free[j];
      if (f.transform != Transform::Log) continue;
      const double margin = 0.05 * (f.upper - f.lower);
      u[j] = std::clamp(u[j], f.lower + margin, f.upper - margin);
    }
    cands.push_back(u);
  }
  cands.push_back(space.from_mat(data_guess(k_eff, o, first)));
  std::vector<int> kj, rj;
  for (int j = 0; j < n; ++j) {
    const std::string& nm = space.free[j].name;
    if (nm == "k1_n_m" || nm == "k2_n_m" || nm == "k3_n_m") kj.push_back(j);
    if (nm == "r1_n_s_m" || nm == "r2_n_s_m" || nm == "r3_n_s_m") rj.push_back(j);
  }
  const double k = std::isfinite(k_eff) ? k_eff : std::sqrt(o.k_min_n_m * o.k_max_n_m);
  const double M = first.impactor_mass_kg;
  // The effect parameters' present-but-moderate start: a quarter into
  // their start range (log or linear as the parameter is fitted).
  std::vector<std::pair<int, double>> effect_mid;
  for (int j = 0; j < n; ++j) {
    const FreeParam& f = space.free[j];
    const bool effect = std::find(o.free_effects.begin(), o.free_effects.end(), f.name) != o.free_effects.end();
    if (effect) effect_mid.emplace_back(j, f.start_lo + 0.25 * (f.start_hi - f.start_lo));
  }
  if (kj.size() >= 2 && rj.size() == kj.size()) {
    // Multipliers of k_eff for the stiffer springs; the softest makes the
    // series come out at k_eff.
    const std::vector<std::vector<double>> spreads =
        kj.size() == 3 ? std::vector<std::vector<double>>{{8.0, 40.0}, {30.0, 300.0}, {3.0, 12.0}, {15.0, 15.0}}
                       : std::vector<std::vector<double>>{{10.0}, {100.0}, {3.0}};
    std::vector<int> perm(kj.size());
    std::iota(perm.begin(), perm.end(), 0);
    do {
      for (const auto& sp : spreads) {
        std::vector<double> mult(kj.size());
        double inv = 1.0;
        for (size_t a = 1; a < kj.size(); ++a) { mult[a] = sp[a - 1]; inv -= 1.0 / sp[a - 1]; }
        mult[0] = 1.0 / std::max(inv, 0.05);
        for (double zeta : {0.03, 0.2}) {
          MatParams g = data_guess(k_eff, o, first);
          for (size_t a = 0; a < kj.size(); ++a) {
            const double ka = k * mult[perm[a]];
            set_parameter(g, space.free[kj[a]].name, ka);
            set_parameter(g, space.free[rj[a]].name, zeta * 2.0 * std::sqrt(ka * M));
          }
          cands.push_back(space.from_mat(g));
          // With an effect free, the same springs with the effect present
          // too: a start holding it absent sits on its bound, and the run
          // from there can settle in a basin the effect's own parameters
          // never leave (an elastic unloading asymmetry: docs/models.md,
          // "Search settings").
          if (!effect_mid.empty()) {
            Eigen::VectorXd u = space.from_mat(g);
            for (const auto& [j, v] : effect_mid) u[j] = v;
            cands.push_back(u);
          }
        }
      }
    } while (std::next_permutation(perm.begin(), perm.end()));
  }
  const int n_random = std::max(4 * o.starts, 8);
  const int primes[] = {2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43};
  const int skip = static_cast<int>(o.seed % 1000) + 1;
  for (int i = 0; i < n_random; ++i) {
    Eigen::VectorXd u(n);
    for (int j = 0; j < n; ++j) {
      const FreeParam& f = space.free[j];
      u[j] = f.start_lo + halton(i + skip, primes[j % 14]) * (f.start_hi - f.start_lo);
    }
    cands.push_back(u);
  }
  for (auto& c : cands)
    for (int j = 0; j < n; ++j) c[j] = std::clamp(c[j], space.free[j].lower, space.free[j].upper);
  return cands;
}

}  // namespace dropfit::fitting::internal
