// dropfit table TABLE.csv --out DIR [--model 1..4] [--train ID ...]
// A mat model from a table of impacts (velocity, deformation, peak force per
// impact: the paper's Table 1): fit, predict each impact, leave each one
// out, close the loop (diagnosis' table stage); fit.json, predictions.csv,
// diagnosis.json and report.html as for a session.
#include <fmt/format.h>

#include <algorithm>
#include <fstream>
#include <sstream>

#include "cli/command.h"
#include "core/error.h"
#include "diagnosis/diagnosis.h"
#include "fitting/table_fit.h"
#include "report/output.h"
#include "report/table.h"

namespace dropfit::cli {
namespace {

void add_table(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string table;
    std::string out;
    std::string model = "1";
    std::vector<std::string> train;
    double impactor_mass_kg = 24.0;
    double m1_kg = 2.44, m2_kg = 3.66;
    bool diagnose = true;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand(
      "table", "fit a mat model to a table of impacts (velocity, deformation, peak force); leave one out; report");
  sub->add_option("table", args->table, "CSV: trial,impact_velocity_m_s,max_deformation_m,peak_force_n")
      ->required()
      ->check(CLI::ExistingFile);
  sub->add_option("--out", args->out, "output folder")->required();
  sub->add_option("--model", args->model, "1..4 (default 1: two numbers per impact pin down two parameters)")
      ->check(CLI::IsMember({"1", "2", "3", "4"}));
  sub->add_option("--train", args->train, "training impact id(s); default: the median-velocity impact");
  sub->add_option("--impactor-mass", args->impactor_mass_kg, "impactor mass, kg (default 24)")->check(CLI::PositiveNumber);
  sub->add_option("--m1", args->m1_kg, "upper layer mass, kg (Models 3, 4; default 2.44)")->check(CLI::PositiveNumber);
  sub->add_option("--m2", args->m2_kg, "lower layer mass, kg (Models 3, 4; default 3.66)")->check(CLI::PositiveNumber);
  sub->add_flag("!--no-diagnose", args->diagnose, "skip closing the loop");
  sub->callback([args] {
    std::ifstream in(args->table, std::ios::binary);
    if (!in) throw InputError(args->table, 0, 0, "", "cannot open");
    std::stringstream text;
    text << in.rdbuf();
    report::TableRun run;
    run.table_path = args->table;
    run.trials = report::parse_impact_table(text.str(), args->table);
    for (const auto& id : args->train) {
      if (std::none_of(run.trials.begin(), run.trials.end(), [&](const auto& t) { return t.id == id; }))
        throw InputError(args->table, 0, 0, "trial", fmt::format("--train {}: no such impact in the table", id));
    }
    run.model = fitting::model_from_name(args->model);
    run.impactor_mass_kg = args->impactor_mass_kg;
    const auto options = fitting::table_options(run.model, args->impactor_mass_kg, args->m1_kg, args->m2_kg);
    run.gravity_m_s2 = options.gravity_m_s2;
    run.free = options.free;

    auto train_options = options;
    train_options.train_ids = args->train;
    run.fit = fitting::fit_table(run.trials, train_options);
    // A fit that is no mat (its peak at contact, its impactor never
    // leaving) is refused: nothing is written, the reason is the error.
    if (!run.fit.refused.empty())
      throw Error(fmt::format("{}: {} refused, no physical optimum: {}; nothing written", args->table,
                              fitting::model_name(run.model), run.fit.refused));
    for (const auto& r : run.fit.trials)
      if (r.train) run.train_ids.push_back(r.id);
    if (run.trials.size() >= 3) {
      run.leave_one_out = fitting::table_leave_one_out(run.trials, options, &run.notes);
    } else {
      run.notes.push_back("2 impacts: leave-one-out needs at least 3");
    }
    // The trained model's peak force over the table's velocity range.
    const fitting::TablePeakCurve curve = fitting::table_peak_curve(run.trials, options, run.fit.params);
    run.curve_velocity_m_s = curve.velocity_m_s;
    run.curve_peak_force_n = curve.peak_force_n;

    report::OutputSet out;
    if (args->diagnose && run.trials.size() >= 3) {
      diagnosis::TableStageOptions d;
      d.model = fitting::ModelKind::Model1;  // the table stage's linear baseline
      d.base = options.base;
      d.impactor_mass_kg = run.impactor_mass_kg;
      d.gravity_m_s2 = run.gravity_m_s2;
      try {
        const diagnosis::TableDiagnosis loop = diagnosis::diagnose_table(run.trials, d);
        diagnosis::DiagnosisResult result;
        result.baseline_model = fitting::model_name(d.model);
        result.effects = loop.effects;
        result.rejected = loop.rejected;
        result.remaining = loop.remaining;
        result.unexplained = !loop.remaining.empty();
        result.notes = loop.notes;
        out.add("diagnosis.json", diagnosis::diagnosis_json(result));
        run.loop_run = true;
        run.loop_baseline_model = result.baseline_model;
        run.loop_unexplained = result.unexplained;
        for (const auto& e : loop.effects)
          run.loop_effects.push_back({e.stage, e.name, e.evidence, e.error_before, e.error_after});
        for (const auto& r : loop.rejected) run.notes.push_back(fmt::format("closing the loop: {} not added: {}", r.name, r.reason));
        for (const auto& n : loop.notes) run.notes.push_back("closing the loop: " + n);
      } catch (const Error& e) {
        run.notes.push_back(fmt::format("closing the loop failed: {}", e.what()));
      }
    }
    out.add("fit.json", report::table_fit_json(run));
    out.add("predictions.csv", report::table_predictions_csv(run));
    out.add("report.html", report::table_report_html(run));
    out.commit(args->out);
    for (const auto& t : run.fit.trials) {
      fmt::print("{:<8} {:>5.2f} m/s  peak {:>6.0f} N  simulated {:>6.0f} N ({:+.1f} %){}\n", t.id,
                 t.impact_velocity_m_s, t.peak_force_n, t.simulated_peak_force_n, t.peak_force_pct_diff,
                 t.train ? "  [train]" : "");
    }
    if (!run.leave_one_out.empty())
      fmt::print("leave one out: largest |peak error| {:.1f} %, RMS {:.1f} %\n", report::heldout_peak_pct_max(run),
                 report::heldout_peak_pct_rms(run));
    for (const auto& e : run.loop_effects) fmt::print("closing the loop: {} added ({})\n", e.name, e.evidence);
    fmt::print("wrote {}\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(45, add_table);
}  // namespace dropfit::cli
