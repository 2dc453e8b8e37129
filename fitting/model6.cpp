// Model 6 in doubles (the template is fitting/model6_impl.h).
#include "fitting/model6.h"

#include "fitting/model6_impl.h"

namespace dropfit::fitting {

double foam_elastic_stress_pa(const FoamLaw& law, double strain) {
  const FoamLawT<double> l = foam_law_t<double>(law);
  double s = 0.0, ds = 0.0;
  model6_detail::elastic(l, strain, &s, &ds);
  return s;
}

Model6Result simulate_model6_detailed(const Model6Params& params, const Model6Geometry& geometry,
                                      const Impact& impact) {
  const int n = std::max(1, static_cast<int>(std::floor((impact.duration_s - impact.first_output_s) /
                                                        impact.output_dt_s + 1e-9)) + 1);
  std::vector<double> grf, imp;
  Model6Extras ex;
  simulate_model6_t<double>(model6_params_t<double>(params), geometry, impact, n, &grf, &imp, &ex);
  Model6Result r;
  Simulation& s = r.sim;
  s.t_s.resize(n);
  for (int i = 0; i < n; ++i) s.t_s[i] = impact.first_output_s + i * impact.output_dt_s;
  s.grf_n = Eigen::Map<const Eigen::VectorXd>(grf.data(), n);
  s.impactor_m = Eigen::Map<const Eigen::VectorXd>(imp.data(), n);
  s.surface_m = Eigen::Map<const Eigen::VectorXd>(ex.surface_m.data(), n);
  s.layer1_m = Eigen::Map<const Eigen::VectorXd>(ex.interface_m.data(), n);
  s.layer2_m = Eigen::VectorXd::Zero(n);
  s.separation_s = ex.separation_s;
  r.top_strain = Eigen::Map<const Eigen::VectorXd>(ex.top_strain.data(), n);
  r.base_strain = Eigen::Map<const Eigen::VectorXd>(ex.base_strain.data(), n);
  r.max_top_strain = r.top_strain.maxCoeff();
  r.max_base_strain = r.base_strain.maxCoeff();
  r.steps = ex.steps;
  r.step_s = ex.step_s;
  return r;
}

Simulation simulate_model6(const Model6Params& params, const Model6Geometry& geometry, const Impact& impact) {
  return simulate_model6_detailed(params, geometry, impact).sim;
}

}  // namespace dropfit::fitting
