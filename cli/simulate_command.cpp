// dropfit simulate --params fit.json --velocity V [--mass M] [--duration S]
//                  [--dt S] [--first-output S] [--gravity G] [--out FILE]
// The force-time curve of any impact with fitted parameters (Models 1-5,
// or Model 6 with the column its fit.json describes): what a simulator
// author checks first. Samples at t = first_output + i dt from
// first contact; a fit's series/<trial>.csv is sampled on the trial's own
// plate clock, whose first sample after contact falls at its t_s[0] (in
// [0, dt)): pass that as --first-output (with the trial's dt and the
// manifest's gravity) to reproduce the fit's simulated curve exactly.
#include <fmt/format.h>

#include <fstream>
#include <sstream>

#include "cli/command.h"
#include "pipeline/pipeline.h"
#include "core/error.h"
#include "report/export.h"
#include "report/model6_results.h"
#include "report/output.h"
#include "report/results.h"

namespace dropfit::cli {
namespace {

void add_simulate(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string params;
    double velocity_m_s = 0.0;
    double mass_kg = 0.0;
    double duration_s = 0.3;
    double dt_s = 1e-3;
    double first_output_s = 0.0;
    double gravity_m_s2 = 9.81;
    std::string out;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("simulate", "force-time curve of an impact with fitted parameters (CSV)");
  sub->add_option("--params", args->params, "fit.json with the model and its parameters")
      ->required()
      ->check(CLI::ExistingFile);
  sub->add_option("--velocity", args->velocity_m_s, "impact velocity, m/s (downward)")->required()->check(CLI::PositiveNumber);
  sub->add_option("--mass", args->mass_kg, "impactor mass, kg (default: fit.json's, else 24)")->check(CLI::PositiveNumber);
  sub->add_option("--duration", args->duration_s, "simulated time from contact, s")->check(CLI::PositiveNumber);
  sub->add_option("--dt", args->dt_s, "output sample spacing, s")->check(CLI::PositiveNumber);
  sub->add_option("--first-output", args->first_output_s, "time of the first sample after contact, s, in [0, dt)")
      ->check(CLI::NonNegativeNumber);
  sub->add_option("--gravity", args->gravity_m_s2, "gravity, m/s^2 (the session manifest's; default 9.81)")
      ->check(CLI::PositiveNumber);
  sub->add_option("--out", args->out, "write the CSV here instead of printing it");
  sub->callback([args] {
    std::ifstream in(args->params);
    if (!in) throw InputError(args->params, 0, 0, "", "cannot open");
    std::stringstream text;
    text << in.rdbuf();
    const bool model6 = report::is_model6_fit_json(text.str());
    const report::FitFile fit = model6 ? report::FitFile{} : report::parse_fit_json(text.str(), args->params);
    const report::Model6FitFile fit6 =
        model6 ? report::parse_model6_fit_json(text.str(), args->params) : report::Model6FitFile{};
    fitting::Impact impact;
    impact.mass_kg = args->mass_kg > 0.0 ? args->mass_kg : model6 ? fit6.impactor_mass_kg : fit.impactor_mass_kg;
    impact.velocity_m_s = args->velocity_m_s;
    impact.duration_s = args->duration_s;
    impact.output_dt_s = args->dt_s;
    impact.first_output_s = args->first_output_s;
    impact.gravity_m_s2 = args->gravity_m_s2;
    const fitting::Simulation sim = model6 ? pipeline::simulate_fitted(fit6.params, fit6.geometry, impact)
                                           : pipeline::simulate_fitted(fit.model, fit.params, impact);
    const std::string csv = report::simulation_csv(sim);
    if (args->out.empty()) {
      fmt::print("{}", csv);
    } else {
      report::write_file_atomic(args->out, csv);
    }
  });
}

}  // namespace
DROPFIT_COMMAND(60, add_simulate);
}  // namespace dropfit::cli
