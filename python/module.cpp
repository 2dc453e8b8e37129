// The Python module dropfit._dropfit (imported by python/dropfit/__init__.py):
// running a session through the pipeline, reading and simulating a fitted
// mat, and the co-simulation contacts (fitting/cosim.h, fitting/model6_cosim.h). Arrays are numpy
// arrays (pybind11/eigen.h); mat parameters are dicts keyed by the names of
// fit.json ("k1_n_m", ...); dropfit::Error and InputError become
// dropfit.Error and dropfit.InputError.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"
#include "core/error.h"
#include "fitting/cosim.h"
#include "fitting/model6_cosim.h"
#include "fitting/models.h"
#include "report/export.h"
#include "report/model6_results.h"
#include "report/output.h"

namespace py = pybind11;

namespace dropfit::python {
namespace {

using ParamDict = std::map<std::string, double>;

fitting::MatParams params_from(const ParamDict& values) {
  fitting::MatParams p;
  for (const auto& [name, value] : values) fitting::set_parameter(p, name, value);
  return p;
}

// The model's own parameters, with the masses, then the effect terms that
// are switched on (fit.json's "parameters").
ParamDict dict_of(fitting::ModelKind kind, const fitting::MatParams& p) {
  ParamDict out;
  for (const auto& [name, value] : report::named_parameters(kind, p)) out[name] = value;
  return out;
}

report::FitFile read_fit(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw Error("cannot read " + path);
  std::stringstream text;
  text << in.rdbuf();
  return report::parse_fit_json(text.str(), path);
}

report::FitFile make_fit(const std::string& model, const ParamDict& parameters, double impactor_mass_kg) {
  report::FitFile fit;
  fit.model = fitting::model_from_name(model);
  fit.params = params_from(parameters);
  fit.impactor_mass_kg = impactor_mass_kg;
  return fit;
}

py::dict simulation_dict(const fitting::Simulation& s) {
  py::dict d;
  d["t_s"] = s.t_s;
  d["grf_n"] = s.grf_n;
  d["impactor_m"] = s.impactor_m;
  d["surface_m"] = s.surface_m;
  d["layer1_m"] = s.layer1_m;
  d["layer2_m"] = s.layer2_m;
  d["separation_s"] = s.separation_s;
  return d;
}

// A drop of the fit's impactor (its mass unless `mass_kg` > 0).
py::dict simulate(const report::FitFile& fit, double velocity_m_s, double mass_kg, double gravity_m_s2,
                  double duration_s, double dt_s, double first_output_s) {
  fitting::Impact impact;
  impact.mass_kg = mass_kg > 0.0 ? mass_kg : fit.impactor_mass_kg;
  impact.velocity_m_s = velocity_m_s;
  impact.gravity_m_s2 = gravity_m_s2;
  impact.duration_s = duration_s;
  impact.output_dt_s = dt_s;
  impact.first_output_s = first_output_s;
  fitting::Simulation s;
  {
    py::gil_scoped_release release;
    s = pipeline::simulate_fitted(fit.model, fit.params, impact);
  }
  return simulation_dict(s);
}

// One session through the whole pipeline, as `dropfit run`: the state built
// through the loop (through the fits when `diagnose` is false), every output
// file in memory, committed to `out_dir` when one is given.
py::dict run(const std::string& session_dir, const std::string& out_dir, bool diagnose, int threads) {
  pipeline::BuildOptions options;
  if (!diagnose) options.upto = pipeline::Stage::Fits;
  options.threads = threads;
  report::OutputSet out;
  pipeline::RunSummary summary;
  {
    py::gil_scoped_release release;
    const pipeline::SessionState state = pipeline::build(session_dir, options);
    pipeline::add_run_outputs(out, state);
    if (!out_dir.empty()) out.commit(out_dir, {session_dir});
    summary = pipeline::summarise(state);
  }
  py::dict files;
  for (const auto& [path, content] : out.files()) files[py::str(path)] = py::bytes(content);
  py::dict d;
  d["session"] = summary.session;
  d["trials"] = summary.trials;
  d["accepted"] = summary.accepted;
  d["failed_fits"] = summary.failed_fits;
  d["final_model"] = summary.final_model;
  d["notes"] = summary.notes;
  d["files"] = files;
  return d;
}

void bind_contact(py::module_& m) {
  py::class_<fitting::ContactForces>(m, "ContactForces", "Forces at the end of one co-simulation step.")
      .def_readonly("foot_n", &fitting::ContactForces::foot_n, "upward force of the mat on the foot (N, >= 0)")
      .def_readonly("grf_n", &fitting::ContactForces::grf_n, "ground reaction force under the mat, zeroed at rest (N)")
      .def_readonly("contact", &fitting::ContactForces::contact, "the foot presses on the mat at the step's end")
      .def("__repr__", [](const fitting::ContactForces& f) {
        return "ContactForces(foot_n=" + std::to_string(f.foot_n) + ", grf_n=" + std::to_string(f.grf_n) +
               ", contact=" + (f.contact ? "True" : "False") + ")";
      });

  py::class_<fitting::MatContact>(m, "MatContact",
                                  "A fitted mat (Models 1-4) stepped by another simulator's foot "
                                  "(fitting/cosim.h): penetration below the undeformed top and velocity, "
                                  "both down positive.")
      .def(py::init([](const report::FitFile& fit) { return fitting::MatContact(fit.model, fit.params); }),
           py::arg("fit"))
      .def(py::init([](const std::string& model, const ParamDict& parameters) {
             return fitting::MatContact(fitting::model_from_name(model), params_from(parameters));
           }),
           py::arg("model"), py::arg("parameters"))
      .def("reset", &fitting::MatContact::reset, py::arg("penetration_m"), py::arg("velocity_m_s"),
           "The mat at rest and the foot at this state now, without advancing time.")
      .def("step", &fitting::MatContact::step, py::arg("penetration_m"), py::arg("velocity_m_s"), py::arg("dt_s"),
           "Advances the mat by dt_s to the foot's new state; returns ContactForces.")
      .def(
          "step_many",
          [](fitting::MatContact& mat, const Eigen::VectorXd& penetration_m, const Eigen::VectorXd& velocity_m_s,
             double dt_s) {
            if (penetration_m.size() != velocity_m_s.size())
              throw Error("step_many: penetration_m and velocity_m_s differ in length");
            Eigen::VectorXd foot(penetration_m.size()), grf(penetration_m.size());
            for (Eigen::Index i = 0; i < penetration_m.size(); ++i) {
              const auto f = mat.step(penetration_m[i], velocity_m_s[i], dt_s);
              foot[i] = f.foot_n;
              grf[i] = f.grf_n;
            }
            return py::make_tuple(foot, grf);
          },
          py::arg("penetration_m"), py::arg("velocity_m_s"), py::arg("dt_s"),
          "Steps through a prescribed foot motion (arrays, one step of dt_s each); returns (foot_n, grf_n).")
      .def_property_readonly("in_contact", &fitting::MatContact::in_contact)
      .def_property_readonly("surface_m", &fitting::MatContact::surface_m)
      .def_property_readonly("layer1_m", &fitting::MatContact::layer1_m)
      .def_property_readonly("layer2_m", &fitting::MatContact::layer2_m)
      .def_property_readonly("model", [](const fitting::MatContact& mat) { return fitting::model_name(mat.kind()); });

  py::class_<fitting::ColumnContact>(m, "ColumnContact",
                                     "A fitted Model 6 foam column stepped by another simulator's foot "
                                     "(fitting/model6_cosim.h); the same steps and forces as MatContact.")
      .def(py::init([](const std::string& path, double gravity_m_s2) {
             std::ifstream in(path, std::ios::binary);
             if (!in) throw Error("cannot read " + path);
             std::stringstream text;
             text << in.rdbuf();
             const auto file = report::parse_model6_fit_json(text.str(), path);
             return fitting::ColumnContact(file.params, file.geometry, gravity_m_s2);
           }),
           py::arg("fit_json_path"), py::arg("gravity_m_s2") = 9.81, "From a Model 6 fit.json.")
      .def("reset", &fitting::ColumnContact::reset, py::arg("penetration_m"), py::arg("velocity_m_s"),
           "The column at rest and the foot at this state now, without advancing time.")
      .def("step", &fitting::ColumnContact::step, py::arg("penetration_m"), py::arg("velocity_m_s"),
           py::arg("dt_s"), "Advances the column by dt_s to the foot's new state; returns ContactForces.")
      .def_property_readonly("in_contact", &fitting::ColumnContact::in_contact)
      .def_property_readonly("surface_m", &fitting::ColumnContact::surface_m)
      .def_property_readonly("interface_m", &fitting::ColumnContact::interface_m);
}

}  // namespace
}  // namespace dropfit::python

PYBIND11_MODULE(_dropfit, m) {
  using namespace dropfit;
  using namespace dropfit::python;
  m.doc() = "dropfit: drop tests on sports surfaces to mat models (C++ core)";

  static py::exception<Error> error(m, "Error", PyExc_RuntimeError);
  static py::exception<InputError> input_error(m, "InputError", error.ptr());
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const InputError& e) {
      input_error(e.what());
    } catch (const Error& e) {
      error(e.what());
    }
  });

  py::class_<report::FitFile>(m, "Fit", "A fitted mat: model, parameters (dict, SI names) and impactor mass.")
      .def(py::init(&make_fit), py::arg("model"), py::arg("parameters"), py::arg("impactor_mass_kg") = 24.0)
      .def_property_readonly("model", [](const report::FitFile& f) { return fitting::model_name(f.model); })
      .def_property_readonly("parameters", [](const report::FitFile& f) { return dict_of(f.model, f.params); })
      .def_readonly("impactor_mass_kg", &report::FitFile::impactor_mass_kg)
      .def("__repr__", [](const report::FitFile& f) {
        return "Fit(model='" + fitting::model_name(f.model) + "', impactor_mass_kg=" +
               std::to_string(f.impactor_mass_kg) + ")";
      });

  m.def("read_fit", &read_fit, py::arg("path"), "Reads a fit.json (model, parameters, impactor mass).");
  m.def("parse_fit", [](const std::string& text) { return report::parse_fit_json(text, "<text>"); },
        py::arg("text"), "Parses the text of a fit.json.");
  m.def("simulate", &simulate, py::arg("fit"), py::arg("velocity_m_s") = 5.0, py::arg("mass_kg") = 0.0,
        py::arg("gravity_m_s2") = 9.81, py::arg("duration_s") = 0.3, py::arg("dt_s") = 1e-3,
        py::arg("first_output_s") = 0.0,
        "A drop on the fitted mat from first contact (Models 1-5; mass_kg 0: the fit's impactor). Returns a dict "
        "of numpy arrays t_s, grf_n, impactor_m, surface_m, layer1_m, layer2_m and separation_s.");
  m.def("run_session", &run, py::arg("session_dir"), py::arg("out_dir") = "", py::arg("diagnose") = true,
        py::arg("threads") = 1,
        "Runs one session as `dropfit run` does; returns the summary and every output file (path -> bytes), "
        "written to out_dir when given.");
  bind_contact(m);
}
