// dropfit simulate --params fit.json --velocity V [--mass M] [--out FILE]
// The force-time curve of any impact with fitted parameters: what a
// simulator author checks first.
#include <fmt/format.h>

#include <fstream>
#include <sstream>

#include "cli/command.h"
#include "cli/pipeline.h"
#include "core/error.h"
#include "report/export.h"
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
  sub->add_option("--out", args->out, "write the CSV here instead of printing it");
  sub->callback([args] {
    std::ifstream in(args->params);
    if (!in) throw InputError(args->params, 0, 0, "", "cannot open");
    std::stringstream text;
    text << in.rdbuf();
    const report::FitFile fit = report::parse_fit_json(text.str(), args->params);
    fitting::Impact impact;
    impact.mass_kg = args->mass_kg > 0.0 ? args->mass_kg : fit.impactor_mass_kg;
    impact.velocity_m_s = args->velocity_m_s;
    impact.duration_s = args->duration_s;
    impact.output_dt_s = args->dt_s;
    const fitting::Simulation sim = pipeline::simulate_fitted(fit, impact);
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
