#pragma once
// Parameter files that simulators load: the canonical fit.json parameters
// (named with their units, docs/formats.md) and a MuJoCo
// MJCF model of the layered mat (Models 3 and 4).
#include <string>
#include <utility>
#include <vector>

#include "fitting/models.h"

namespace dropfit::report {

// The parameters a model uses, named with units ("k1_n_m", "r1_n_s_m",
// "m1_kg", ...), plus any active effect terms ("k1_cubic_n_m3", ...).
std::vector<std::pair<std::string, double>> named_parameters(fitting::ModelKind kind,
                                                             const fitting::MatParams& params);

// Reads back what named_parameters wrote. Unknown names are an error naming
// them (`source` is used in the message).
fitting::MatParams params_from_named(const std::vector<std::pair<std::string, double>>& named,
                                     const std::string& source);

struct FitFile {
  fitting::ModelKind model = fitting::ModelKind::Model4;
  fitting::MatParams params;
  double impactor_mass_kg = 24.0;
};
// Parses a fit.json text (the "model" and "parameters" keys; the optional
// "impactor_mass_kg"). Throws dropfit::InputError naming `path` and the key.
FitFile parse_fit_json(const std::string& text, const std::string& path);

struct MatGeometry {
  double length_m = 0.90;
  double width_m = 0.60;
  double top_thickness_m = 0.055;     // carpet + stiff layer
  double bottom_thickness_m = 0.15;   // soft layer
};

// MuJoCo MJCF (XML) of a Model 3 or Model 4 mat: each layer a body on a
// vertical slide joint whose stiffness and damping are the model's element
// below it, with the layer's mass; Model 4 adds a light "mat_surface" body
// on a slide joint (k1, r1) that a foot or impactor lands on. Throws
// dropfit::Error for Models 1, 2 and 5. The file states, in a comment and
// as custom numeric dropfit_max_stable_timestep_s, the largest timestep at
// which its springs integrate stably (mjcf_max_stable_timestep_s), and as
// WARNING comments `warnings` (e.g. a parameter at its bound) and every
// effect term a linear joint spring leaves out.
std::string mjcf_xml(fitting::ModelKind kind, const fitting::MatParams& params, const MatGeometry& geometry,
                     const std::vector<std::string>& warnings = {});

// 2 / omega_max of the exported chain (its stiffness over its masses,
// Model 4's light surface body included): MuJoCo's Euler integrator is
// unstable above it. NaN for Models 1, 2 and 5.
double mjcf_max_stable_timestep_s(fitting::ModelKind kind, const fitting::MatParams& params);

}  // namespace dropfit::report
