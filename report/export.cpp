#include "report/export.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <Eigen/Dense>
#include <nlohmann/json.hpp>

#include "core/error.h"

namespace dropfit::report {

std::vector<std::pair<std::string, double>> named_parameters(fitting::ModelKind kind,
                                                             const fitting::MatParams& params) {
  std::vector<std::pair<std::string, double>> out;
  for (const auto& name : fitting::parameter_names(kind, true))
    out.emplace_back(name, fitting::get_parameter(params, name));
  if (params.k1_cubic_n_m3 != 0.0) out.emplace_back("k1_cubic_n_m3", params.k1_cubic_n_m3);
  if (params.r1_unload_n_s_m >= 0.0) out.emplace_back("r1_unload_n_s_m", params.r1_unload_n_s_m);
  if (params.maxwell_k_n_m > 0.0 && params.maxwell_tau_s > 0.0) {
    out.emplace_back("maxwell_k_n_m", params.maxwell_k_n_m);
    out.emplace_back("maxwell_tau_s", params.maxwell_tau_s);
  }
  if (params.k1_unload_ratio > 0.0) {
    out.emplace_back("k1_unload_ratio", params.k1_unload_ratio);
    out.emplace_back("k1_unload_speed_m_s", params.k1_unload_speed_m_s);
  }
  return out;
}

fitting::MatParams params_from_named(const std::vector<std::pair<std::string, double>>& named,
                                     const std::string& source) {
  fitting::MatParams params;
  for (const auto& [name, value] : named) {
    try {
      fitting::set_parameter(params, name, value);
    } catch (const Error&) {
      throw InputError(source, 0, 0, "parameters." + name, "unknown parameter name");
    }
    if (!std::isfinite(value)) throw InputError(source, 0, 0, "parameters." + name, "not a finite number");
  }
  return params;
}

FitFile parse_fit_json(const std::string& text, const std::string& path) {
  nlohmann::json doc;
  try {
    doc = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    // Line, column and the key being read, from the byte offset (a number
    // overflow is reported without one: found from the quoted number); the
    // library's own wording without its "[json.exception...]" prefix.
    std::size_t at = 0;
    if (const auto* pe = dynamic_cast<const nlohmann::json::parse_error*>(&e)) {
      at = std::min<std::size_t>(pe->byte > 0 ? pe->byte - 1 : 0, text.size());
    } else {
      const std::string w = e.what();
      const auto q1 = w.find('\''), q2 = q1 == std::string::npos ? q1 : w.find('\'', q1 + 1);
      if (q2 != std::string::npos) {
        const auto found = text.find(w.substr(q1 + 1, q2 - q1 - 1));
        if (found != std::string::npos) at = found;
      }
    }
    int line = 1, column = 1;
    for (std::size_t i = 0; i < at; ++i) text[i] == '\n' ? (++line, column = 1) : ++column;
    std::string field;
    const std::size_t colon = text.rfind(':', at);
    if (colon != std::string::npos) {
      const std::size_t close = text.rfind('"', colon), open = close == std::string::npos || close == 0
                                                                  ? std::string::npos
                                                                  : text.rfind('"', close - 1);
      if (open != std::string::npos && close - open - 1 <= 64) field = text.substr(open + 1, close - open - 1);
    }
    std::string why = e.what();
    if (const auto k = why.find("parse error"); k != std::string::npos) {
      if (const auto c = why.find(": ", k); c != std::string::npos) why = why.substr(c + 2);
    } else if (const auto b = why.find("] "); b != std::string::npos) {
      why = why.substr(b + 2);
    }
    if (why.find("number overflow") != std::string::npos) why = "number too large for a double (" + why + ")";
    throw InputError(path, line, column, field, fmt::format("not valid JSON: {}", why));
  }
  if (!doc.is_object()) throw InputError(path, 0, 0, "", "expected a JSON object");
  FitFile file;
  if (!doc.contains("model") || !doc["model"].is_string()) throw InputError(path, 0, 0, "model", "missing or not a string");
  try {
    file.model = fitting::model_from_name(doc["model"].get<std::string>());
  } catch (const Error& e) {
    throw InputError(path, 0, 0, "model", e.what());
  }
  if (!doc.contains("parameters") || !doc["parameters"].is_object()) {
    throw InputError(path, 0, 0, "parameters", "missing or not an object");
  }
  std::vector<std::pair<std::string, double>> named;
  for (const auto& [key, value] : doc["parameters"].items()) {
    if (!value.is_number()) throw InputError(path, 0, 0, "parameters." + key, "not a number");
    named.emplace_back(key, value.get<double>());
  }
  file.params = params_from_named(named, path);
  if (doc.contains("impactor_mass_kg")) {
    if (!doc["impactor_mass_kg"].is_number()) throw InputError(path, 0, 0, "impactor_mass_kg", "not a number");
    file.impactor_mass_kg = doc["impactor_mass_kg"].get<double>();
  }
  return file;
}

namespace {
// MuJoCo's contacts are soft: a contact's stiffness scales with the
// effective mass of the bodies it joins over solref's time constant
// squared. With the default time constant (0.02 s) the impactor sinks into
// the mat's top (Model 3) or through the light surface body (Model 4). The
// contact is made nearly hard: time constant two timesteps (MuJoCo's floor)
// and impedance 0.99, so that the mat's springs, not the contact, set the
// force; that needs the small timestep.
constexpr double kTimestepS = 1e-5;
constexpr double kSurfaceMassKg = 0.01;  // Model 4's element 1 top: light, not zero (MuJoCo needs mass)
// priority 1: MuJoCo then takes these contact parameters instead of mixing
// them with the other geom's (a foot's or impactor's defaults).
constexpr const char* kContactSolver = "priority=\"1\" solref=\"2e-05 1\" solimp=\"0.99 0.99 0.001\"";

std::string joint(const std::string& indent, const std::string& name, double k, double r, double springref) {
  return fmt::format(
      "{}<joint name=\"{}\" type=\"slide\" axis=\"0 0 1\" stiffness=\"{:.17g}\" damping=\"{:.17g}\" "
      "springref=\"{:.17g}\"/>\n",
      indent, name, k, r, springref);
}
}  // namespace

double mjcf_max_stable_timestep_s(fitting::ModelKind kind, const fitting::MatParams& p) {
  if (kind != fitting::ModelKind::Model3 && kind != fitting::ModelKind::Model4) return NAN;
  const bool four = kind == fitting::ModelKind::Model4;
  // The chain's stiffness and mass matrices, bottom layer first; each spring
  // joins a body to the one below it (the bottom one to the ground).
  std::vector<double> k, m;
  if (four) {
    k = {p.k3_n_m, p.k2_n_m, p.k1_n_m};
    m = {p.m2_kg, p.m1_kg, kSurfaceMassKg};
  } else {
    k = {p.k2_n_m, p.k1_n_m};
    m = {p.m2_kg, p.m1_kg};
  }
  const auto n = static_cast<Eigen::Index>(k.size());
  Eigen::MatrixXd K = Eigen::MatrixXd::Zero(n, n), M = Eigen::MatrixXd::Zero(n, n);
  for (Eigen::Index i = 0; i < n; ++i) {
    M(i, i) = m[i];
    K(i, i) += k[i];
    if (i > 0) {
      K(i - 1, i - 1) += k[i];
      K(i - 1, i) -= k[i];
      K(i, i - 1) -= k[i];
    }
  }
  Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::MatrixXd> eig(K, M, Eigen::EigenvaluesOnly);
  if (eig.info() != Eigen::Success) return NAN;
  const double omega_max = std::sqrt(eig.eigenvalues().maxCoeff());
  // MuJoCo's Euler integrator is semi-implicit in position with the joint
  // damping implicit, so the undamped springs set the limit: omega dt < 2.
  return 2.0 / omega_max;
}

std::string mjcf_xml(fitting::ModelKind kind, const fitting::MatParams& p, const MatGeometry& g,
                     const std::vector<std::string>& warnings) {
  if (kind != fitting::ModelKind::Model3 && kind != fitting::ModelKind::Model4) {
    throw Error(fmt::format("MJCF export is for Models 3 and 4 (layered mats), not {}", fitting::model_name(kind)));
  }
  const bool four = kind == fitting::ModelKind::Model4;
  // Springs: Model 3 joins m1-m2 with (k1, r1) and m2-ground with (k2, r2);
  // Model 4 adds (k1, r1) above m1, so its layer springs are (k2, r2), (k3, r3).
  const double k_top = four ? p.k2_n_m : p.k1_n_m, r_top = four ? p.r2_n_s_m : p.r1_n_s_m;
  const double k_bottom = four ? p.k3_n_m : p.k2_n_m, r_bottom = four ? p.r3_n_s_m : p.r2_n_s_m;
  const double hx = g.length_m / 2, hy = g.width_m / 2;
  const double hb = g.bottom_thickness_m / 2, ht = g.top_thickness_m / 2;
  // The mat starts at rest under gravity: each joint's spring already
  // carries the weight above it at q = 0 (springref = weight / stiffness), so
  // the bottom joint's force minus the mat's weight is the plate force zeroed
  // with the mat on it, the models' GRF.
  const double gravity_m_s2 = 9.81;
  const double surface_kg = four ? kSurfaceMassKg : 0.0;
  const double ref_bottom = (p.m1_kg + p.m2_kg + surface_kg) * gravity_m_s2 / k_bottom;
  const double ref_top = (p.m1_kg + surface_kg) * gravity_m_s2 / k_top;
  const double ref_surface = surface_kg * gravity_m_s2 / p.k1_n_m;
  // The step: the contact's nearly hard setting wants 1e-5 s; a chain whose
  // fastest mode needs less gets a quarter of its stability limit.
  const double max_step_s = mjcf_max_stable_timestep_s(kind, p);
  const double step_s = std::min(kTimestepS, 0.25 * max_step_s);
  // What a MuJoCo joint spring cannot carry: MuJoCo's joint springs are
  // linear, so the fitted effect terms are left out and said so.
  std::vector<std::string> notes = warnings;
  if (p.k1_cubic_n_m3 != 0.0)
    notes.push_back(fmt::format("k1_cubic_n_m3 = {:.6g} (stiffening) is left out: a joint spring is linear",
                                p.k1_cubic_n_m3));
  if (p.r1_unload_n_s_m >= 0.0)
    notes.push_back(fmt::format("r1_unload_n_s_m = {:.6g} (unloading damping) is left out", p.r1_unload_n_s_m));
  if (p.maxwell_k_n_m > 0.0 && p.maxwell_tau_s > 0.0)
    notes.push_back(fmt::format("the Maxwell arm (maxwell_k_n_m = {:.6g}, maxwell_tau_s = {:.6g}) is left out",
                                p.maxwell_k_n_m, p.maxwell_tau_s));
  if (p.k1_unload_ratio > 0.0)
    notes.push_back(fmt::format("k1_unload_ratio = {:.6g} (hysteresis) is left out", p.k1_unload_ratio));
  if (notes.size() > warnings.size())
    notes.push_back("dropfit's co-simulation API (fitting/cosim.h) steps the whole model with these terms");
  std::string xml;
  xml += "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n";
  xml += fmt::format("<!-- dropfit {} landing mat: layers on vertical slide joints; stiffness N/m, damping N s/m, mass kg.\n"
                     "     Each joint's spring is the model element below that body; springref holds the mat's own\n"
                     "     weight at q = 0. The plate force is mat_bottom_z's passive force minus the mat's weight.\n"
                     "     Contacts on mat_contact are nearly hard (solref 2e-5 s): keep the timestep at {:.3g} s.\n"
                     "     Largest stable timestep: {:.3g} s (2 / the fastest mode of the mat's springs and masses;\n"
                     "     also custom numeric dropfit_max_stable_timestep_s). -->\n",
                     fitting::model_name(kind), step_s, max_step_s);
  for (const auto& n : notes) xml += fmt::format("<!-- WARNING: {} -->\n", n);
  xml += "<mujoco model=\"dropfit_mat\">\n";
  xml += fmt::format("  <option timestep=\"{:.6g}\" gravity=\"0 0 -{}\" integrator=\"Euler\"/>\n", step_s,
                     gravity_m_s2);
  xml += fmt::format("  <custom>\n    <numeric name=\"dropfit_max_stable_timestep_s\" data=\"{:.6g}\"/>\n  </custom>\n",
                     max_step_s);
  xml += "  <worldbody>\n";
  xml += fmt::format("    <body name=\"mat_bottom\" pos=\"0 0 {:.6g}\">\n", hb);
  xml += joint("      ", "mat_bottom_z", k_bottom, r_bottom, ref_bottom);
  xml += fmt::format("      <inertial pos=\"0 0 0\" mass=\"{:.17g}\" diaginertia=\"1 1 1\"/>\n", p.m2_kg);
  xml += fmt::format("      <geom type=\"box\" size=\"{:.6g} {:.6g} {:.6g}\" contype=\"0\" conaffinity=\"0\" rgba=\"0.3 0.4 0.8 1\"/>\n",
                     hx, hy, hb);
  xml += fmt::format("      <body name=\"mat_top\" pos=\"0 0 {:.6g}\">\n", hb + ht);
  xml += joint("        ", "mat_top_z", k_top, r_top, ref_top);
  xml += fmt::format("        <inertial pos=\"0 0 0\" mass=\"{:.17g}\" diaginertia=\"1 1 1\"/>\n", p.m1_kg);
  if (four) {
    xml += fmt::format("        <geom type=\"box\" size=\"{:.6g} {:.6g} {:.6g}\" contype=\"0\" conaffinity=\"0\" rgba=\"0.2 0.7 0.3 1\"/>\n",
                       hx, hy, ht);
    xml += fmt::format("        <body name=\"mat_surface\" pos=\"0 0 {:.6g}\">\n", ht);
    xml += joint("          ", "mat_surface_z", p.k1_n_m, p.r1_n_s_m, ref_surface);
    xml += fmt::format("          <inertial pos=\"0 0 0\" mass=\"{}\" diaginertia=\"1e-4 1e-4 1e-4\"/>\n", kSurfaceMassKg);
    xml += fmt::format("          <geom name=\"mat_contact\" type=\"box\" size=\"{:.6g} {:.6g} 0.001\" {} rgba=\"0.9 0.8 0.2 1\"/>\n",
                       hx, hy, kContactSolver);
    xml += "        </body>\n";
  } else {
    xml += fmt::format("        <geom name=\"mat_contact\" type=\"box\" size=\"{:.6g} {:.6g} {:.6g}\" {} rgba=\"0.2 0.7 0.3 1\"/>\n",
                       hx, hy, ht, kContactSolver);
  }
  xml += "      </body>\n    </body>\n  </worldbody>\n</mujoco>\n";
  return xml;
}

}  // namespace dropfit::report
