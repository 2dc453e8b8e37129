// dropfit fit SESSION --model 1..5|all [--train TRIAL ...] --out DIR
#include <algorithm>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include "cli/command.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"
#include "core/error.h"
#include "report/results.h"

namespace dropfit::cli {
namespace {

std::vector<fitting::ModelKind> models_from(const std::string& text) {
  if (text == "all") {
    return {fitting::ModelKind::Model1, fitting::ModelKind::Model2, fitting::ModelKind::Model3,
            fitting::ModelKind::Model4, fitting::ModelKind::Model5};
  }
  return {fitting::model_from_name(text)};
}

void add_fit(CLI::App& app, CommandContext& /*ctx*/) {
  struct Args {
    std::string session;
    std::string out;
    std::string model = "4";
    std::vector<std::string> train;
    std::string optimizer = "ceres";
    bool leave_one_out = false;
    bool masses_free = false;
    double loading_weight = 1.0;
    std::vector<std::string> effects;
  };
  auto args = std::make_shared<Args>();
  auto* sub = app.add_subcommand("fit", "fit the mat models to the trials; predict every trial");
  sub->add_option("session", args->session, "session folder")->required()->check(CLI::ExistingDirectory);
  sub->add_option("--out", args->out, "output folder")->required();
  sub->add_option("--model", args->model, "1..5 or all")->check(CLI::IsMember({"1", "2", "3", "4", "5", "all"}));
  sub->add_option("--train", args->train, "training trial id(s); default: the median-velocity accepted trial");
  sub->add_option("--optimizer", args->optimizer, "ceres or annealing")->check(CLI::IsMember({"ceres", "annealing"}));
  sub->add_flag("--leave-one-out", args->leave_one_out, "also refit leaving each trial out");
  sub->add_flag("--masses-free", args->masses_free, "fit the layer masses with their total fixed");
  sub->add_option("--loading-weight", args->loading_weight, "extra weight on the loading phase")
      ->check(CLI::PositiveNumber);
  sub->add_option("--effect", args->effects,
                  "also fit an effect parameter: k1_cubic_n_m3, r1_unload_n_s_m, k1_unload_ratio, maxwell_k_n_m, "
                  "maxwell_tau_s")
      ->check(CLI::IsMember({"k1_cubic_n_m3", "r1_unload_n_s_m", "maxwell_k_n_m", "maxwell_tau_s", "k1_unload_ratio"}));
  sub->callback([args] {
    // The trials as every command sees them (the state through the loop,
    // with its baseline), then the models asked, with this command's options.
    pipeline::BuildOptions build;
    build.models = {fitting::ModelKind::Model4};
    const pipeline::SessionState state = pipeline::build(args->session, build);
    if (state.accepted() == 0) throw Error(fmt::format("{}: no accepted trial to fit ({})", args->session,
                                                      fmt::join(state.all_notes(), "; ")));
    report::OutputSet out;
    const auto models = models_from(args->model);
    for (const auto model : models) {
      auto options = pipeline::fit_options(state.session.manifest, model);
      options.train_ids = args->train;
      options.optimizer = args->optimizer == "annealing" ? fitting::Optimizer::Annealing : fitting::Optimizer::Ceres;
      options.leave_one_out = args->leave_one_out;
      options.masses_free = args->masses_free;
      options.loading_weight = args->loading_weight;
      options.free_effects = args->effects;
      if (std::find(args->effects.begin(), args->effects.end(), "maxwell_k_n_m") != args->effects.end() &&
          std::find(args->effects.begin(), args->effects.end(), "maxwell_tau_s") == args->effects.end())
        options.effects.maxwell_tau_s = 0.025;  // a foam's relaxation time when tau is not fitted
      const auto fit = fitting::fit(state.fit_data, options);
      // One model: OUT/fit.json. All: OUT/fits/modelN/fit.json, and Model 4
      // (the paper's choice) also as OUT/fit.json.
      if (models.size() == 1 || model == fitting::ModelKind::Model4) pipeline::add_fit_outputs(out, "", fit, state);
      if (models.size() > 1) pipeline::add_fit_outputs(out, "fits/" + fitting::model_name(model) + "/", fit, state);
      fmt::print("{}", fit.report());
    }
    // The trials the fit saw, as `process` and `run` report them.
    pipeline::add_trial_outputs(out, state);
    out.commit(args->out, {args->session});
    fmt::print("wrote {}\n", args->out);
  });
}

}  // namespace
DROPFIT_COMMAND(40, add_fit);
}  // namespace dropfit::cli
